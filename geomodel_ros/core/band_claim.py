"""An object's lower part that a support's band took, given back along the viewing rays.

The segmentation gives a support plane every point within its band, a few sigma of the
depth noise either side of it (:func:`~geomodel_ros.core.noise.support_band`), and keeps
an object's wall in the band only where it can tell it from the support around it
(``segmentation._claim_contact_rims``). Under a real sensor's noise the band reaches 10-20
mm up every object at 1-1.4 m: kinect-real clutter seeds 60-99, 66 of 487 objects lost
more than 5 % of their points to the desk, cones most (their widest part lies lowest;
seed 89's cone at 1.36 m 42 %).

Once the objects are modeled their solids say which of those points are theirs: a pixel
sees an object when its viewing ray (from the sensor at the origin) meets the object's
solid near the pixel's depth. The desk around an object is seen on rays that meet the
desk before or beside the object, never its solid (a ray meets the desk in front of an
object's foot and goes on below it, where the solid is not), so a support point is given
to an object when its ray, sampled within ``ransac_threshold`` (at the object's range) of
the point's depth and on the sensor's side of the point's support plane, enters the
object's solid there (:func:`inside_solid`): inside it somewhere in that window and
outside it at the window's near end. A ray already inside the solid in front of the
window passed through it and saw the point past it: the model is wrong there, unless the
ray came in through the open end of a container (a cup's or bowl's floor in the band,
seen over its rim): the end of a cylinder or frustum that faces the sensor is open when
most of the object's own points whose rays cross it lie beyond it, and the object's side
is seen round more than the half turn a closed one shows (:func:`_open_end`).
Only a model larger than its object claims desk points (a ring as wide as the excess round
its foot, within the window). Typed solids only (no planes, no
``unknown``), the supports' points only, each given at most once (to the first object
in the result's order whose solid its ray meets); sizes and models stay as fitted, the
point counts follow. With ``noise_model = fixed`` the window is the fixed threshold.
"""

from __future__ import annotations

import dataclasses

import numpy as np
from numpy.typing import NDArray

from geomodel_ros.core.confidence import VIEW_COVERAGE, round_outline
from geomodel_ros.core.fastmath import row_norms, take_rows
from geomodel_ros.core.noise import NoiseEstimate, object_params
from geomodel_ros.core.params import ModelingParams
from geomodel_ros.core.primitives import DIMENSION_NAMES, ModelingResult, Primitive, PrimitiveType

__all__ = ["inside_solid", "give_back_band_points", "RAY_SAMPLES", "SOLIDS"]

#: Depths sampled along each point's ray over the window of +-``ransac_threshold`` (odd:
#: the point's own depth among them); at the Kinect's 11-16 mm thresholds of 0.7-1.3 m
#: the samples lie 1.4-2 mm apart, finer than the noise.
RAY_SAMPLES = 17
#: The types whose solids claim points.
SOLIDS = (PrimitiveType.CUBOID, PrimitiveType.CYLINDER, PrimitiveType.CONE,
          PrimitiveType.FRUSTUM, PrimitiveType.SPHERE)

#: The types whose end may be open (cups, bowls, pots).
CONTAINERS = (PrimitiveType.CYLINDER, PrimitiveType.FRUSTUM)
#: An end is judged open or closed on at least this many of the object's points whose rays
#: cross it (fewer: the end is seen edge-on or hardly at all, and counts as closed).
MIN_OPEN_POINTS = 10

_CUBOID_SIZES = DIMENSION_NAMES[PrimitiveType.CUBOID]


def inside_solid(p: Primitive, q: NDArray[np.float64], grow: float = 0.0
                 ) -> NDArray[np.bool_]:
    """Tell which points ``q`` (n, 3) [m] lie inside the solid of ``p`` (n,).

    The solid grown by ``grow`` [m] (its sizes, radii and half-heights by that much);
    False for every point of a type without a solid (plane, unknown).
    """
    if p.type == PrimitiveType.SPHERE:
        return row_norms(q - p.center) < p.dimensions["radius"] + grow
    local = (q - p.center) @ p.rotation
    if p.type == PrimitiveType.CUBOID:
        half = 0.5 * np.array([p.dimensions[k] for k in _CUBOID_SIZES])
        return np.all(np.abs(local) < half + grow, axis=1)
    outline = round_outline(p)
    if outline is None:
        return np.zeros(len(q), dtype=bool)
    half_height, radius_at, _ = outline
    z = local[:, 2]
    return (np.abs(z) < half_height + grow) & (
        np.hypot(local[:, 0], local[:, 1])
        < radius_at(np.clip(z, -half_height, half_height)) + grow)


def _reach(p: Primitive) -> float:
    """Radius [m] of a ball about ``p.center`` that holds the solid of ``p``."""
    if p.type == PrimitiveType.SPHERE:
        return p.dimensions["radius"]
    if p.type == PrimitiveType.CUBOID:
        return 0.5 * float(np.linalg.norm([p.dimensions[k] for k in _CUBOID_SIZES]))
    outline = round_outline(p)
    return 0.0 if outline is None else float(np.hypot(outline[0], outline[2]))


def give_back_band_points(pts: NDArray[np.float64], labels: NDArray[np.int64],
                          result: ModelingResult,
                          supports: dict[int, tuple[NDArray[np.float64], float]],
                          params: ModelingParams, noise: NoiseEstimate | None
                          ) -> NDArray[np.int64]:
    """Return the labels (N,) of ``pts`` (N, 3) [m] with support points given to solids.

    See the module docstring. ``supports``: the support planes (normal towards the
    sensor, d) by label; the ``point_count`` of ``result``'s objects follows, in place
    (the solids gain what the supports lose). ``noise``: the frame's estimate, which sets
    the threshold at each object's range (None: ``params.ransac_threshold``). ``labels``
    itself is not changed.
    """
    if not supports:
        return labels
    solids = [o for o in result.objects if o.id not in supports and o.type in SOLIDS]
    if not solids:
        return labels
    top = max(int(labels.max()), max(supports), max(o.id for o in solids))
    is_support = np.zeros(top + 2, dtype=bool)
    is_support[np.fromiter(supports, dtype=np.int64) + 1] = True
    sup_rows = np.flatnonzero(is_support[labels + 1])
    if not len(sup_rows):
        return labels
    # Two coordinates of them, contiguous, for the box round each object.
    xz = [np.take(pts[:, k], sup_rows).astype(np.float32) for k in (0, 2)]
    plane_normal = np.zeros((len(is_support) - 1, 3))
    plane_d = np.zeros(len(is_support) - 1)
    for sid, (normal, d) in supports.items():
        plane_normal[sid], plane_d[sid] = normal, d
    # The points of the round solids whose end may be open, found in one pass.
    is_container = np.zeros(len(is_support), dtype=bool)
    is_container[[o.id + 1 for o in solids if o.type in CONTAINERS]] = True
    container_rows = np.flatnonzero(is_container[labels + 1])
    container_label = labels[container_rows]
    free = np.ones(len(sup_rows), dtype=bool)
    out = labels.copy()
    gained: dict[int, int] = {}
    for o in solids:
        depth = float(np.linalg.norm(o.center))
        w = (params if noise is None else object_params(params, noise, depth)
             ).ransac_threshold
        near = _near(pts, sup_rows, xz, free, o.center, _reach(o) + w)
        q = take_rows(pts, sup_rows[near])
        # A ray that meets the solid within w of the point passes within w of it.
        inner = inside_solid(o, q, w)
        near, q = near[inner], q[inner]
        if not len(near):
            continue
        which = labels[sup_rows[near]]
        cap = _open_end(o, take_rows(pts, container_rows[container_label == o.id]), w) \
            if o.type in CONTAINERS else None
        given = near[_rays_entering(o, q, plane_normal[which], plane_d[which], w, cap)]
        if len(given):
            out[sup_rows[given]] = o.id
            free[given] = False
            gained[o.id] = len(given)
    if gained:
        lost = np.bincount(labels[sup_rows[~free]], minlength=len(is_support) - 1)
        change = {**gained, **{int(i): -int(lost[i]) for i in supports}}
        result.objects = [dataclasses.replace(o, point_count=o.point_count + change[o.id])
                          if change.get(o.id) else o for o in result.objects]
    return out


def _rays_entering(o: Primitive, q: NDArray[np.float64], normals: NDArray[np.float64],
                   offsets: NDArray[np.float64], w: float,
                   cap: tuple[NDArray[np.float64], NDArray[np.float64], float] | None
                   ) -> NDArray[np.bool_]:
    """Tell which points ``q`` (n, 3) [m] the rays to which enter ``o``'s solid near them (n,).

    Each ray is sampled at RAY_SAMPLES depths within ``w`` [m] of its point's, kept on the
    sensor's side of the point's support plane (``normals`` (n, 3), ``offsets`` (n,)). It
    enters there when some sample lies inside the solid and the nearest does not: a ray
    already inside the solid in front of the window passed through it and saw the point
    past it, but for one through the open end ``cap`` of a container (:func:`_open_end`).
    """
    ray = q / row_norms(q)[:, None]
    shift = w * np.linspace(-1.0, 1.0, RAY_SAMPLES)
    s = (q[:, None, :] + ray[:, None, :] * shift[None, :, None]).reshape(-1, 3)
    height = np.einsum("ij,ij->i", q, normals) + offsets
    rate = np.einsum("ij,ij->i", ray, normals)
    above = height[:, None] + rate[:, None] * shift[None, :] > 0.0
    inside = inside_solid(o, s).reshape(len(q), RAY_SAMPLES)
    entered = ~inside[:, 0]
    if cap is not None:
        entered |= _through_end(q, ray, *cap)
    return entered & (inside & above).any(axis=1)


def _end_facing(p: Primitive) -> tuple[NDArray[np.float64], NDArray[np.float64], float] | None:
    """Return the end of a round solid that faces the sensor (at the origin), or None.

    As its centre (3,) [m], outward normal (3,) and radius [m].
    """
    outline = round_outline(p)
    if outline is None:
        return None
    half_height, radius_at, _ = outline
    axis = p.rotation[:, 2]
    for sign in (1.0, -1.0):
        centre = p.center + sign * half_height * axis
        if float(sign * axis @ centre) < 0.0:
            return centre, sign * axis, float(radius_at(np.array([sign * half_height]))[0])
    return None


def _through_end(q: NDArray[np.float64], ray: NDArray[np.float64], centre: NDArray[np.float64],
                 normal: NDArray[np.float64], radius: float) -> NDArray[np.bool_]:
    """Tell which rays (unit ``ray`` (n, 3) to points ``q``) cross the end disc before them."""
    along = ray @ normal
    with np.errstate(divide="ignore", invalid="ignore"):
        t = float(centre @ normal) / along
    hit = ray * t[:, None]
    return (along < 0.0) & (t > 0.0) & (t < row_norms(q)) & \
        (row_norms(hit - centre) < radius)


def _open_end(p: Primitive, own: NDArray[np.float64], w: float
              ) -> tuple[NDArray[np.float64], NDArray[np.float64], float] | None:
    """Return the end of ``p`` facing the sensor when it is open, or None.

    Of the object's own points ``own`` (n, 3) [m] whose rays cross that end's disc (its
    radius less ``w`` [m]), at least :data:`MIN_OPEN_POINTS`, most lie beyond it by more
    than ``w``: the sensor sees through that end (a cup's or bowl's inner wall and
    floor), where a closed end (a can's lid) holds them. And the side's points span more
    than :data:`~geomodel_ros.core.confidence.VIEW_COVERAGE` of the turn round the axis
    (``Primitive.confidence``): looking into a container the sensor sees its wall round
    further than a closed body's side, the near wall outside and the far wall inside. A
    wrong model of a few facets shows neither: two boxes side by side fitted as a
    cylinder 279 mm in radius, 15 % of its turn covered, took 78,000 points of the desk
    below its top as its floor (kinect-real; the containers whose floors the clutter
    scenes show cover 59-100 %).
    """
    if p.type not in CONTAINERS or not len(own) or p.confidence is None or \
            not (p.confidence.coverage or 0.0) > VIEW_COVERAGE:
        return None
    end = _end_facing(p)
    if end is None or end[2] <= w:
        return None
    centre, normal, radius = end
    ray = own / row_norms(own)[:, None]
    through = _through_end(own, ray, centre, normal, radius - w)
    if np.count_nonzero(through) < MIN_OPEN_POINTS:
        return None
    beyond = row_norms(own[through]) - float(centre @ normal) / (ray[through] @ normal) > w
    return end if np.mean(beyond) > 0.5 else None


def _near(pts: NDArray[np.float64], rows: NDArray[np.int64], xz: list[NDArray[np.float32]],
          free: NDArray[np.bool_], center: NDArray[np.float64], reach: float
          ) -> NDArray[np.int64]:
    """Return the indices into ``rows`` of the free points within ``reach`` [m] of ``center``.

    ``rows`` (m,): rows of ``pts`` (N, 3) [m]; ``xz``: their x and z coordinates (m,)
    each; ``free`` (m,): those not given yet.
    """
    box = (np.abs(xz[0] - np.float32(center[0])) < reach) & \
        (np.abs(xz[1] - np.float32(center[2])) < reach)
    near = np.flatnonzero(box & free)
    d = take_rows(pts, rows[near]) - center
    return near[np.einsum("ij,ij->i", d, d) < reach * reach]
