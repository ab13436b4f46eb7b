"""Fit step shared by the sphere, cylinder and cone units: RANSAC on the curved faces.

The model is drawn by RANSAC from the curved faces' working points and normals, refined
by least squares (first on the working cloud, then on the full-resolution points, except
on a first look: ``ObjectCloud.first_look``), and verified by its inlier ratio on the
working points. A cone's least squares cannot reverse its opening (the cylinder, half-angle
0, lies between the two), so a cone that refines below the least half-angle is refined
again from the opposite opening, which is kept when it fits better beyond the noise
(:func:`refined`). A cylinder or cone may take a flat end that region growing joined to
its side as an *inner cap* (:func:`inner_cap`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable, Union

import numpy as np
from numpy.typing import NDArray

from geomodel_ros.core.fastmath import centroid, take_rows
from geomodel_ros.core.fitting.cloud import ObjectCloud, Plane
from geomodel_ros.core.fitting.measure import rms
from geomodel_ros.core.fitting.orient import toward_sensor
from geomodel_ros.core.fitting.paired_cost import lower_beyond_noise, spread_blocks
from geomodel_ros.core.fitting.result import FitTask, Rejected
from geomodel_ros.core.fitting.verify import check_inlier_ratio
from geomodel_ros.core.params import ModelingParams
from geomodel_ros.core.primitives import PrimitiveType
from geomodel_ros.core.ransac import ConeModel, CylinderModel, PlaneModel, SphereModel, ransac, \
    refine

__all__ = ["CurvedModel", "CurvedFit", "INNER_CAP_SHARE", "INNER_CAP_CONE_MARGIN",
           "axis_prior", "inner_cap", "reversed_cone", "refined", "fit_curved"]

CurvedModel = Union[SphereModel, CylinderModel, ConeModel]

#: A cap grown into a curved face must hold at least this share of the face's working
#: points (besides ``min_face_points``).
INNER_CAP_SHARE = 0.1
#: No inner cap is looked for on a cone flatter than 90 deg minus this many
#: ``angle_tolerance``: its side's own normals are then within twice the tolerance of the
#: axis, as a cap's are, and the two cannot be told apart.
INNER_CAP_CONE_MARGIN = 2.0
#: Least-squares rounds of a curved model on the working cloud (settles the RANSAC model
#: near the surface) and then on the full-resolution points (which the sizes come from).
WORKING_REFINE_ROUNDS = 1
FULL_REFINE_ROUNDS = 2


@dataclass(frozen=True)
class CurvedFit:
    """A curved model verified on the curved faces of its object.

    Attributes
    ----------
    model : SphereModel, CylinderModel or ConeModel
    planar : list[int], the object's planar faces (caps and base candidates)
    inner_caps : tuple of Plane, flat ends found inside the curved faces
    rmse : float [m], RMS distance of the curved faces' full-resolution sample
    """

    model: CurvedModel
    planar: list[int]
    inner_caps: tuple[Plane, ...]
    rmse: float


def axis_prior(task: FitTask) -> NDArray[np.float64] | None:
    """Direction (3,) the axis must follow: the task's prior, else the main planar face's normal."""
    if task.axis_prior is not None:
        return task.axis_prior
    cloud, main = task.cloud, task.main_face
    return cloud.faces[main].info.normal if main >= 0 and cloud.faces[main].info.planar \
        else None


def _cap_candidates(wp: NDArray[np.float64], wn: NDArray[np.float64], model: CurvedModel,
                    on_model: NDArray[np.bool_], params: ModelingParams
                    ) -> NDArray[np.bool_] | None:
    """Which working points may be an inner cap: off the side, normals along the axis."""
    if isinstance(model, ConeModel) and \
            model.half_angle > math.pi / 2 - INNER_CAP_CONE_MARGIN * params.angle_tolerance:
        return None  # the side's own normals turn nearly along the axis: no telling apart
    along = (np.abs(wn @ model.axis) >= math.cos(params.angle_tolerance)) & ~on_model
    return along if along.sum() >= _cap_need(len(wp), params) else None


def _cap_need(n_working: int, params: ModelingParams) -> float:
    """Fewest working points an inner cap needs."""
    return max(params.min_face_points, INNER_CAP_SHARE * n_working)


def inner_cap(wp: NDArray[np.float64], wn: NDArray[np.float64], model: CurvedModel,
              on_model: NDArray[np.bool_], params: ModelingParams
              ) -> tuple[NDArray[np.float64], float, NDArray[np.bool_]] | None:
    """Find a flat end of a cylinder or cone that region growing joined to its curved side.

    Real lids and bottoms meet the side in a rounded edge, over which the normals turn
    smoothly, so the end is not a face of its own. Its working points (``wp``, ``wn``:
    (m, 3), the curved faces') are off the fitted side (``on_model`` (m,) False) and
    have normals along the axis; when they are enough and a plane perpendicular to the
    axis fits enough of them inside the model (within its radius), that plane is
    returned as (unit normal towards the sensor, offset d of n . x + d = 0 [m], which of
    ``wp`` lie on it inside the model). None otherwise.
    """
    along = _cap_candidates(wp, wn, model, on_model, params)
    if along is None:
        return None
    axis, thr = model.axis, params.ransac_threshold
    cand = take_rows(wp, along)
    # The end seen most (a lid; the bottom of a standing object is hidden), refined.
    plane = refine(PlaneModel(axis.copy(), -float(np.median(cand @ axis))), cand, thr)
    if abs(plane.normal @ axis) < math.cos(params.angle_tolerance):
        return None
    on_cap = (np.abs(plane.distance(wp)) <= thr) & (model.distance(wp) <= thr)
    if (on_cap & along).sum() < _cap_need(len(wp), params):
        return None
    normal = toward_sensor(plane.normal, centroid(cand))
    return normal, float(plane.d) if normal @ plane.normal > 0 else -float(plane.d), on_cap


def reversed_cone(model: ConeModel, points: NDArray[np.float64]) -> ConeModel:
    """Return the cone of the opposite opening through the same side of ``points`` (M, 3).

    Same axis line and half-angle, the apex mirrored through the axis point level with the
    points' centroid: the radius there is unchanged, the taper runs the other way (a side
    whose three RANSAC normals tilted the wrong way by noise gets its other reading).
    """
    mid = float((centroid(points) - model.apex) @ model.axis)
    return ConeModel(model.apex + 2.0 * mid * model.axis, -model.axis, model.half_angle)


def _msac(model: CurvedModel, points: NDArray[np.float64], threshold: float
          ) -> NDArray[np.float64]:
    """Return the truncated squared distances (M,) of ``points`` (M, 3) to ``model``.

    In bands of ``threshold`` [m]: min(|d| / threshold, 1)^2.
    """
    return np.minimum(np.abs(model.distance(points)) / threshold, 1.0) ** 2


def refined(model: CurvedModel, wp: NDArray[np.float64], full: NDArray[np.float64] | None,
            params: ModelingParams) -> CurvedModel:
    """Least-squares refinement of a RANSAC ``model`` on ``wp`` and then on ``full``.

    ``wp`` (M, 3) the working points, ``full`` (K, 3) the full-resolution sample (None: a
    first look, working points only). A cone's least squares moves its apex and half-angle
    continuously and cannot pass through the cylinder (half-angle 0) to the opposite
    opening: a RANSAC cone that opened the wrong way (its three normals tilted by noise)
    refines towards a far apex and a half-angle near 0, and is rejected as too narrow
    although its side tapers. When the refined cone's half-angle is below
    ``min_cone_half_angle``, the cone of the opposite opening (:func:`reversed_cone`) is
    refined as well, and it is kept when it is not below that bound and its truncated
    residuals on the working points (bands of ``ransac_threshold``) are lower beyond the
    noise (:func:`~.paired_cost.lower_beyond_noise`: the mean difference against its
    standard error over blocks of neighbouring points, whose depth errors are
    correlated): a cylinder's side, which either opening fits about as well, stays the
    narrow cone and is rejected as before. The cone, frustum and cylinder units' own
    checks then judge the kept model as any other.
    """
    thr = params.ransac_threshold

    def both(m: CurvedModel) -> CurvedModel:
        m = refine(m, wp, thr, rounds=WORKING_REFINE_ROUNDS)
        return m if full is None else refine(m, full, thr, rounds=FULL_REFINE_ROUNDS)

    first = both(model)
    if not isinstance(first, ConeModel) or first.half_angle >= params.min_cone_half_angle:
        return first
    other = both(reversed_cone(model, wp))
    if other.half_angle < params.min_cone_half_angle:
        return first
    lower, _ = lower_beyond_noise(_msac(other, wp, thr), _msac(first, wp, thr),
                                  spread_blocks(wp))
    return other if lower else first


def fit_curved(cloud: ObjectCloud, kind: PrimitiveType, model_cls: type,
               accept: Callable[[CurvedModel], bool], with_caps: bool) -> CurvedFit | Rejected:
    """Fit ``model_cls`` to the curved faces of ``cloud`` and verify its inlier ratio.

    Parameters
    ----------
    kind : PrimitiveType, the type tried (for reasons)
    model_cls : SphereModel, CylinderModel or ConeModel
    accept : callable
        RANSAC skips hypotheses for which it returns False (size and axis bounds).
    with_caps : bool
        Look for an inner cap (:func:`inner_cap`) among the points off the side.
    """
    params = cloud.params
    curved, planar = cloud.curved_and_planar()
    if not curved:
        return Rejected(kind, f"{kind}: no curved face")
    cw = cloud.face_working(curved)
    wp, wn = cloud.wc.points[cw], cloud.wc.normals[cw]
    fit = ransac(model_cls, wp, wn, params.ransac_threshold, params.ransac_normal_threshold,
                 params.ransac_max_iterations, params.ransac_confidence, cloud.rng, accept=accept)
    if fit is None:
        return Rejected(kind, f"{kind}: no valid RANSAC hypothesis")
    full = cloud.sample(cloud.face_points(curved))
    model = refined(fit.model, wp, None if cloud.first_look else full, params)
    on_model = np.abs(model.distance(wp)) <= params.ransac_threshold
    caps: tuple[Plane, ...] = ()
    if with_caps and not on_model.all():
        cap = inner_cap(wp, wn, model, on_model, params)
        if cap is not None:
            caps = ((cap[0], cap[1]),)
            on_model |= cap[2]
    bad = check_inlier_ratio(float(np.mean(on_model)), params, kind)
    if bad:
        return bad
    return CurvedFit(model, planar, caps, rms(model.distance(full)))
