"""Fitting unit of a frustum (truncated cone: cup, bowl, flower pot, bucket).

The side is a cone fitted as the cone unit fits it (same RANSAC model and hypothesis
bounds, same side verification); the object is a frustum when its points stop well short
of that cone's apex: their extent along the axis, from ``lo`` to ``hi`` measured from the
apex, has ``lo > FRUSTUM_MIN_TOP_RATIO * hi``. Caps, supports and the edge correction
close the ends as for cylinders and cones (:func:`~.axial.axial_extent`).

Taper: the radii must differ by more than a cylinder's could appear to under the frame's
noise (:func:`taper_minimum`). With a measured noise (``noise_model = auto``) the side's
own points decide: their least-squares taper must be significant against its spread over
blocks of the side (:mod:`~.taper_spread`), and under slow sensor errors also exceed the
apparent taper those errors give a cylinder of the same size in the image, measured on
the frame's support (:func:`~.slow_taper.slow_taper`). With fixed noise values (or a side
too small to judge) the minimum is FRUSTUM_MIN_TAPER inlier bands (of the local noise
under slow errors).

Sizes: ``radius`` of the base (the larger circle, at ``hi``), ``top_radius`` of the
smaller circle (at ``lo``, nearer the apex) and ``height = hi - lo``; centre at the
midpoint of the axis segment, rotation z from the base towards the top (towards the apex,
as a cone's z), so a cup standing on its smaller end has z pointing down.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
from numpy.typing import NDArray

from geomodel_ros.core.fitting.cloud import ObjectCloud, independent_noise
from geomodel_ros.core.fitting.completion import complete_axial
from geomodel_ros.core.fitting.cone import fit_cone_side
from geomodel_ros.core.fitting.measure import bulk_reach, side_bulk
from geomodel_ros.core.fitting.result import FitOutcome, FitTask, Fitted, Rejected
from geomodel_ros.core.fitting.slow_taper import slow_taper
from geomodel_ros.core.fitting.taper_spread import least_taper
from geomodel_ros.core.fitting.verify import (CONE_APEX_REACH, check_axial_sunk_in_support,
                                              check_bulk_length, check_bulk_reach, check_radius)
from geomodel_ros.core.geometry import frame_with_z
from geomodel_ros.core.primitives import Primitive, PrimitiveType
from geomodel_ros.core.ransac import ConeModel

__all__ = ["FRUSTUM_MIN_TOP_RATIO", "FRUSTUM_MIN_TAPER", "frustum_sizes", "taper_minimum",
           "fit_frustum"]

FRUSTUM = PrimitiveType.FRUSTUM
#: A frustum's top radius is more than this share of its base radius: its points stop
#: farther from the cone's apex than this share of the base's distance (radius grows
#: linearly from the apex). It is the cone unit's CONE_APEX_REACH, so that a truncated
#: cone is exactly one of the two: a cone when its points reach within a quarter of its
#: height of the apex, a frustum otherwise. A quarter of the height is a clear truncation:
#: noise and the edge lose a cone a few millimetres round its tip (within 4.5 % of the
#: height on the sensor suite), never a quarter of it.
FRUSTUM_MIN_TOP_RATIO = CONE_APEX_REACH
#: Where the noise is not measured (``noise_model = fixed``) or a side has too few points
#: for its own test (:mod:`~.taper_spread`), a frustum's radii differ by more than this
#: many RANSAC thresholds. With a smaller taper a cylinder of the mean radius lies within
#: one threshold of every point of the side: no single point tells the two apart, and the
#: object is left to the cylinder unit (measured on osd_learn: tins the Kinect sees with a
#: 10 mm taper and a tilted axis, real bowls and cups with 24-35 mm).
FRUSTUM_MIN_TAPER = 2.0


def frustum_sizes(model: ConeModel, lo: float, hi: float, threshold: float,
                  min_taper: float | None = None) -> dict[str, float] | Rejected:
    """Sizes [m] of the frustum of ``model`` between ``lo`` and ``hi`` [m] from its apex.

    Returns ``{"radius", "top_radius", "height"}`` (base = the circle at ``hi``), or the
    rejection when the points reach within FRUSTUM_MIN_TOP_RATIO of ``hi`` of the apex
    (a cone) or lie on both sides of it, or when the radii differ by at most
    ``min_taper`` [m] (default FRUSTUM_MIN_TAPER times ``threshold`` [m], the RANSAC
    threshold; see :func:`taper_minimum`): a cylinder.
    """
    if hi <= 0 or lo <= FRUSTUM_MIN_TOP_RATIO * hi:
        return Rejected(FRUSTUM, f"frustum rejected: its points reach {max(lo, 0.0) * 1000:.0f}"
                                 f" mm from the apex of a {max(hi, 0.0) * 1000:.0f} mm cone "
                                 "(a cone)")
    slope = math.tan(model.half_angle)
    taper = (hi - lo) * slope
    least = FRUSTUM_MIN_TAPER * threshold if min_taper is None else min_taper
    if taper <= least:
        return Rejected(FRUSTUM, f"frustum rejected: its radii differ by {taper * 1000:.1f} mm "
                                 f"only, within {least * 1000:.1f} mm (a cylinder)")
    return {"radius": hi * slope, "top_radius": lo * slope, "height": hi - lo}


def _own_stream(cloud: ObjectCloud) -> ObjectCloud:
    """``cloud`` with a child of its random stream (the parent's draws stay as they were).

    The frustum is tried between other candidates; drawing from its own child stream
    leaves the fits after it exactly as they were without it.
    """
    try:
        child = cloud.rng.spawn(1)[0]
    except (TypeError, ValueError):  # a generator without a seed sequence: share it
        return cloud
    return dataclasses.replace(cloud, rng=child)


def taper_minimum(cloud: ObjectCloud, model: ConeModel, lo: float, hi: float,
                  significant: float | None = None) -> float:
    """Least taper [m] of a frustum of ``model`` from ``lo`` to ``hi`` [m] from its apex.

    ``significant`` [m] is the least taper the side's own points make significant
    (:func:`~.taper_spread.least_taper`); without it (a side too small to judge, or
    ``noise_model = fixed``) FRUSTUM_MIN_TAPER RANSAC thresholds stand for it. Where the
    noise is independent (:func:`~.cloud.independent_noise`), with ``noise_model =
    fixed`` or without a measured null of the frame's slow errors, that is the minimum.
    Under slow errors the threshold is inflated by their scale (``cloud.correlation``):
    the bands are then taken of the local noise (the threshold over that scale), and the
    minimum is the larger of that term and the apparent taper the slow errors give a
    cylinder of this size in the image (:func:`~.slow_taper.slow_taper`).
    """
    params = cloud.params
    band = FRUSTUM_MIN_TAPER * params.ransac_threshold
    fixed = params.noise_model != "auto"
    own = band if significant is None or fixed else significant
    if independent_noise(params, cloud.correlation) or fixed or cloud.slow_null is None:
        return own
    if significant is None:
        own = band / cloud.correlation
    ends = model.apex + model.axis * lo, model.apex + model.axis * hi
    radius = (lo + hi) / 2.0 * math.tan(model.half_angle)
    return max(own, slow_taper(cloud.slow_null, *ends, radius))


def _sized(task: FitTask, model: ConeModel, lo: float, hi: float,
           side_points: NDArray[np.float64], profile: NDArray[np.float64]
           ) -> dict[str, float] | Rejected:
    """Sizes [m] of the frustum whose points run from ``lo`` to ``hi`` from the apex, checked.

    With a measured noise the least-squares taper of the side's ``profile`` points (those
    whose normals do not run along the axis, :mod:`~.taper_spread`) must also exceed the
    least taper: the RANSAC cone's slope is only the sizes' estimate, and a flat end's
    points within the side's band draw a taper of their own (a lying can 0.47 m away whose
    end was taken as curved with its side: 11.0 mm with the end's 264 points, 3.2 mm
    without, kinect-real held-out seed 122's can 6).
    """
    points = task.cloud.points
    bad = check_bulk_length(hi - lo, side_bulk(points, side_points, model.axis), FRUSTUM)
    if bad:
        return bad
    judged = None if task.cloud.params.noise_model != "auto" else \
        least_taper(profile, model, lo, hi)
    least = taper_minimum(task.cloud, model, lo, hi, None if judged is None else judged[1])
    dims = frustum_sizes(model, lo, hi, task.cloud.params.ransac_threshold, least)
    if isinstance(dims, Rejected):
        return dims
    if judged is not None and judged[0] <= least:
        return Rejected(FRUSTUM, f"frustum rejected: its side's least-squares taper "
                                 f"{judged[0] * 1000:.1f} mm is within {least * 1000:.1f} mm "
                                 "(a cylinder)")
    bad = check_radius(dims["radius"], task.cloud.params, FRUSTUM) or \
        check_bulk_reach(dims["radius"], bulk_reach(points, model.apex, model.axis), FRUSTUM)
    return bad if bad else dims


def fit_frustum(task: FitTask) -> FitOutcome:
    """Fit a frustum to the curved faces of ``task.cloud``; planar faces may close its ends.

    The axis follows ``task.axis_prior`` or else the main planar face's normal, if any.
    Returns a frustum whose z points from its base (larger circle) to its top, or the
    rejection (also when it would reach into the support its object stands on,
    :func:`~.verify.check_axial_sunk_in_support`).
    """
    cloud = _own_stream(task.cloud)
    task = dataclasses.replace(task, cloud=cloud)
    fitted = fit_cone_side(task, FRUSTUM)
    if not isinstance(fitted, tuple):
        return fitted
    side, lo, hi, side_points, profile = fitted
    model = side.model
    dims = _sized(task, model, lo, hi, side_points, profile)
    if isinstance(dims, Rejected):
        return dims
    lo, hi, dims, completed = _completed(cloud, model, lo, hi, dims)
    center = model.apex + model.axis * (lo + hi) / 2
    bad = check_axial_sunk_in_support(center, model.axis, dims["height"],
                                      (dims["top_radius"], dims["radius"]), cloud, FRUSTUM)
    if bad:
        return bad
    prim = Primitive(cloud.oid, FRUSTUM, center, frame_with_z(-model.axis),
                     {k: float(v) for k, v in dims.items()}, len(cloud.points), side.rmse,
                     completed=completed)
    return Fitted(prim, "frustum verified")


def _completed(cloud: ObjectCloud, model: ConeModel, lo: float, hi: float,
               dims: dict[str, float]
               ) -> tuple[float, float, dict[str, float], tuple[str, ...]]:
    """Return the frustum's extent and sizes with a hidden end completed down to its support.

    Either end may stand on the support (a bowl on its smaller circle, a flower pot on
    its larger one); the hidden part keeps the side's taper
    (:func:`~.completion.complete_axial`). The completion is kept only if the result is
    still a frustum (:func:`frustum_sizes`: no nearer its apex than a frustum's top may
    be) of an accepted radius. Returns ``lo``, ``hi``, the sizes and the names of the
    completed sizes.
    """
    slope = math.tan(model.half_angle)
    new_lo, new_hi, end = complete_axial(cloud, model.apex, model.axis, 0.0, lo, hi, slope)
    if end is None:
        return lo, hi, dims, ()
    grown = frustum_sizes(model, new_lo, new_hi, cloud.params.ransac_threshold, 0.0)
    if isinstance(grown, Rejected) or check_radius(grown["radius"], cloud.params, FRUSTUM):
        return lo, hi, dims, ()
    return new_lo, new_hi, grown, (("top_radius", "radius")[end], "height")
