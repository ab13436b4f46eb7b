"""Modeling of segmented objects: faces -> surface types -> model graph -> RANSAC -> size.

:func:`model_objects` takes a scene's points with per-point object labels (from the
segmentation or ground truth) and returns one :class:`~geomodel_ros.core.primitives.Primitive`
per object. Degenerate objects (too few points, fits that fail verification, shapes no
rule of the model graph accepts) come out as ``unknown``; this never raises for bad
geometry, only for malformed arguments.
"""

from __future__ import annotations

import math
import os
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from geomodel_ros.core import obb
from geomodel_ros.core.errors import InputError, as_points
from geomodel_ros.core.faces import (WorkingCloud, build_working_cloud, face_plane, faces_from_labels,
                    split_faces, split_plane_unions)
from geomodel_ros.core.geometry import frame_with_z
from geomodel_ros.core.fastmath import centroid, rows_finite, take_rows
from geomodel_ros.core.model_graph import FaceInfo, GraphDecision, curvature_candidates, decide_type
from geomodel_ros.core.params import ModelingParams
from geomodel_ros.core.primitives import FaceSummary, ModelingResult, Primitive
from geomodel_ros.core.ransac import ConeModel, CylinderModel, PlaneModel, SphereModel, ransac, refine
from geomodel_ros.core.surface_type import face_feature, principal_curvatures

__all__ = ["model_objects", "model_object", "model_scene", "InputError"]


def _check_points(points: NDArray) -> NDArray[np.float64]:
    return as_points(points)


def _check_labels(labels: NDArray, n: int, what: str) -> NDArray[np.int64]:
    arr = np.asarray(labels)
    if arr.shape != (n,):
        raise InputError(f"{what} must be an ({n},) integer array aligned with the points, "
                         f"got shape {arr.shape}")
    if not np.issubdtype(arr.dtype, np.integer):
        raise InputError(f"{what} must be integers, got dtype {arr.dtype}")
    return arr.astype(np.int64, copy=False)


@dataclass
class _Face:
    info: FaceInfo
    summary: FaceSummary
    working: NDArray[np.int64]  # indices into the working cloud
    points: NDArray[np.int64]   # indices into the object's points


@dataclass
class _Object:
    oid: int
    points: NDArray[np.float64]
    wc: WorkingCloud
    faces: list[_Face]
    adjacency: NDArray[np.bool_]
    spacing: float
    params: ModelingParams
    rng: np.random.Generator
    supports: tuple[tuple[NDArray[np.float64], float], ...] = ()
    center: NDArray[np.float64] = field(init=False)

    def __post_init__(self) -> None:
        self.center = centroid(self.points)

    def support_ends(self, axis: NDArray[np.float64], origin: NDArray[np.float64],
                     vmin: float, vmax: float) -> tuple[float | None, float | None]:
        """Where support planes (desk, floor) close the extent [vmin, vmax] along ``axis``.

        Extents are coordinates ``(x - origin) . axis``. An object resting on a support
        plane has its hidden end on that plane: when a support plane perpendicular to
        ``axis`` crosses the object's axis line (through its centroid) within twice
        ``seg_plane_threshold`` of an end, that crossing is the end.
        """
        ref = self.center
        lo = hi = None
        tol = 2.0 * self.params.seg_plane_threshold
        for n, d in self.supports:
            c = float(n @ axis)
            if abs(c) < math.cos(self.params.angle_tolerance):
                continue
            t = float((ref - origin) @ axis) - (d + float(n @ ref)) / c
            if abs(t - vmin) <= tol:
                lo = t
            elif abs(t - vmax) <= tol:
                hi = t
        return lo, hi

    def sample(self, idx: NDArray[np.int64]) -> NDArray[np.float64]:
        """Full-resolution points of ``idx``, at most ``refine_max_points`` of them."""
        cap = self.params.refine_max_points
        if len(idx) > cap:
            idx = idx[self.rng.choice(len(idx), size=cap, replace=False, shuffle=False)]
        return take_rows(self.points, idx)

    def face_points(self, which: list[int]) -> NDArray[np.int64]:
        return np.concatenate([self.faces[i].points for i in which]) if which else \
            np.zeros(0, dtype=np.int64)

    def face_working(self, which: list[int]) -> NDArray[np.int64]:
        return np.concatenate([self.faces[i].working for i in which]) if which else \
            np.zeros(0, dtype=np.int64)


def _unknown(oid: int, points: NDArray[np.float64], reason: str,
             faces: tuple[FaceSummary, ...] = ()) -> Primitive:
    center = centroid(points)
    return Primitive(oid, "unknown", center, np.eye(3), {}, len(points), 0.0, faces, reason)


#: Points farther than this many RANSAC thresholds from the fitted surfaces are outliers
#: for sizing.
OUTLIER_FACTOR = 3.0
#: A model on whose surfaces (within OUTLIER_FACTOR thresholds) less than this share of
#: its object's points lie does not describe that object (e.g. a huge cylinder through a
#: small curved sliver of a box) and is rejected.
MIN_COVERAGE = 0.5
#: A cone's points must reach within this share of its height from the apex (a frustum
#: such as a cup is not a cone).
CONE_APEX_REACH = 0.5


#: A cylinder or cone longer than BULK_FACTOR times the extent of the bulk of its
#: object's points along its axis (2nd-98th percentile) plus BULK_MARGIN [m] is rejected.
BULK_FACTOR = 1.5
BULK_MARGIN = 0.02


def _bulk_extent(points: NDArray[np.float64], axis: NDArray[np.float64]) -> float:
    """Extent [m] of the bulk (2nd to 98th percentile) of ``points`` along ``axis``."""
    lo, hi = np.percentile(points @ axis, [2.0, 98.0])
    return float(hi - lo)


#: Sizing ignores projections farther than STRAY_PAD times the bulk's extent plus
#: STRAY_MARGIN [m] beyond the bulk (1st-99th percentile) of an object's points. A side
#: must hold more than about 2 % of the points not to be cut (a box seen almost face on
#: whose sides hold less may come out too thin along the view).
STRAY_PAD = 0.25
STRAY_MARGIN = 0.01
#: ... and groups of at most STRAY_GROUP_SHARE of the points beyond an empty gap of
#: STRAY_GAP [m] at either end (an occluded object's parts are larger).
STRAY_GROUP_SHARE = 0.05
STRAY_GAP = 0.03


def _without_strays(vals: NDArray[np.float64]) -> NDArray[np.float64]:
    """``vals`` (a projection of an object's points on one axis) without the strays
    beyond its bulk (STRAY_PAD, STRAY_MARGIN). On depth images these are
    flying pixels along the viewing rays past an edge, which lie close to the extension
    of a side face seen at a grazing angle and would stretch the box."""
    lo, hi = np.percentile(vals[:: max(1, len(vals) // 5000)], [1.0, 99.0])
    pad = STRAY_PAD * (hi - lo) + STRAY_MARGIN
    keep = (vals >= lo - pad) & (vals <= hi + pad)
    vals = vals if keep.all() else vals[keep]
    # Small groups beyond an empty gap (flying pixels between an edge and the far
    # background come in such clusters, a few per cent of a small box's points).
    ordered = np.sort(vals)
    n, k = len(ordered), int(STRAY_GROUP_SHARE * len(ordered))
    if k < 1:
        return vals
    gaps = np.diff(ordered)
    low = np.flatnonzero(gaps[:k] > STRAY_GAP)
    high = np.flatnonzero(gaps[n - 1 - k:] > STRAY_GAP)
    if not low.size and not high.size:
        return vals
    lo = ordered[low[-1] + 1] if low.size else ordered[0]
    hi = ordered[n - 1 - k + high[0]] if high.size else ordered[-1]
    return vals[(vals >= lo) & (vals <= hi)]


def _bulk_reach(points: NDArray[np.float64], origin: NDArray[np.float64],
                axis: NDArray[np.float64]) -> float:
    """Distance [m] from the axis line (``origin``, unit ``axis``) within which the bulk
    (98th percentile) of ``points`` lie."""
    v = points[:: max(1, len(points) // 5000)] - origin
    radial = v - np.outer(v @ axis, axis)
    return float(np.percentile(np.sqrt(np.einsum("ij,ij->i", radial, radial)), 98.0))


def _arc_span(pts: NDArray[np.float64], origin: NDArray[np.float64],
              axis: NDArray[np.float64]) -> float:
    """Angle [rad] that points span around an axis (2 pi minus the largest empty gap)."""
    if len(pts) < 3:
        return 0.0
    frame = frame_with_z(axis)
    v = pts[:: max(1, len(pts) // 20000)] - origin  # a 20k subset finds any real gap
    ang = np.sort(np.arctan2(v @ frame[:, 1], v @ frame[:, 0]))
    gaps = np.diff(np.r_[ang, ang[0] + 2.0 * math.pi])
    return float(2.0 * math.pi - gaps.max())


def _coverage(on_model: NDArray[np.bool_], what: str) -> str | None:
    share = float(np.mean(on_model)) if on_model.size else 0.0
    if share < MIN_COVERAGE:
        return f"{what} rejected: only {share:.0%} of the object's points lie on it"
    return None


def _rms(d: NDArray[np.float64]) -> float:
    return float(np.sqrt(np.mean(d * d))) if d.size else 0.0


def _nearest_surface(dists: list[NDArray[np.float64]]
                     ) -> tuple[NDArray[np.int64], NDArray[np.float64]]:
    """Index of the smallest of several per-point distance arrays, and that distance
    (ties go to the first), without stacking them into an (N, k) array."""
    best = dists[0].copy()
    which = np.zeros(len(best), dtype=np.int64)
    for i, d in enumerate(dists[1:], start=1):
        closer = d < best
        which[closer] = i
        np.minimum(best, d, out=best)
    return which, best


def _toward_sensor(n: NDArray[np.float64], at: NDArray[np.float64]) -> NDArray[np.float64]:
    return -n if n @ at > 0 else n


# ---------------------------------------------------------------------------------------
# Faces and their surface types
# ---------------------------------------------------------------------------------------

def _build_faces(obj_pts: NDArray[np.float64], params: ModelingParams,
                 face_labels: NDArray[np.int64] | None
                 ) -> tuple[WorkingCloud, list[_Face], NDArray[np.bool_]]:
    wc = build_working_cloud(obj_pts, params.voxel_size, params.normal_neighbors, face_labels,
                             params.max_working_points)
    if face_labels is not None:
        fs = faces_from_labels(wc, face_labels)
    else:
        fs = split_faces(wc, params.face_angle_threshold, params.edge_variation_threshold,
                         params.min_face_points)
        fs = split_plane_unions(wc, fs, params.ransac_threshold, params.angle_tolerance,
                                params.min_face_points)
    point_face = fs.labels[wc.point_to_working]
    order = np.argsort(point_face, kind="stable")
    bounds = np.searchsorted(point_face[order], np.arange(fs.count + 1))
    worder = np.argsort(fs.labels, kind="stable")
    wbounds = np.searchsorted(fs.labels[worder], np.arange(fs.count + 1))
    weights = params.cf_weights
    faces: list[_Face] = []
    for f in range(fs.count):
        pidx = order[bounds[f]:bounds[f + 1]]
        widx = worder[wbounds[f]:wbounds[f + 1]]
        # Eqs. 1-6 on the face's voxel centroids weighted by the points each stands for
        # (the full-resolution covariance at a fraction of the cost).
        feat = face_feature(wc.points[widx], weights, params.cf_threshold,
                            params.cf_radius_fraction, wc.counts[widx])
        plane, plane_rmse = face_plane(wc.points[widx], wc.normals[widx],
                                        params.ransac_threshold)
        # RANSAC-style verification of the CF decision (paper 3.2: a fit that fails rejects
        # the type): a "planar" face no plane fits is curved, a "curved" face that a plane
        # fits to well within the inlier threshold is planar.
        planar = feat.planar
        if planar and plane_rmse > params.ransac_threshold:
            planar = False
        elif not planar and plane_rmse <= params.ransac_threshold / 2.0:
            planar = True
        center = wc.counts[widx] @ wc.points[widx] / max(int(wc.counts[widx].sum()), 1)
        if planar:
            normal = _toward_sensor(plane.normal, center)
            offset = float(-normal @ center)
        else:
            mn = wc.normals[widx].mean(axis=0)
            normal = mn / max(np.linalg.norm(mn), 1e-12)
            offset = 0.0
        info = FaceInfo(planar, normal, offset, len(widx), wc.normals[widx], center)
        summary = FaceSummary("planar" if planar else "curved", feat.cf_total, len(pidx), normal)
        faces.append(_Face(info, summary, widx, pidx))
    return wc, faces, fs.adjacency


# ---------------------------------------------------------------------------------------
# Fitting + sizing per type. Each returns (Primitive | None, reason).
# ---------------------------------------------------------------------------------------

def _verify(ratio: float, params: ModelingParams, what: str) -> str | None:
    if ratio < params.min_inlier_ratio:
        return f"{what} fit rejected: {ratio:.0%} inliers < {params.min_inlier_ratio:.0%}"
    return None


def _plane_from_face(face: _Face, w: NDArray[np.float64]) -> PlaneModel:
    """Start for a plane fit to a face's working points ``w``: the face's own normal
    (robust to strays, :func:`~geomodel_ros.core.faces.face_plane`) through their median."""
    n = face.info.normal
    return PlaneModel(n, -float(np.median(w @ n)))


def _fit_plane(o: _Object, main: int) -> tuple[Primitive | None, str]:
    p = o.params
    all_faces = list(range(len(o.faces)))
    widx = o.face_working(all_faces)
    model = _plane_from_face(o.faces[main], o.wc.points[o.faces[main].working])
    model = refine(model, o.wc.points[widx], p.ransac_threshold)
    model = refine(model, o.sample(o.face_points(all_faces)), p.ransac_threshold, rounds=1)
    ratio = float(np.mean(np.abs(model.distance(o.wc.points[widx])) <= p.ransac_threshold))
    bad = _verify(ratio, p, "plane")
    if bad:
        return None, bad
    n = _toward_sensor(model.normal, o.center)
    d = -model.d if n @ model.normal < 0 else model.d
    # Sizing uses the points on the model (flying pixels and strays do not stretch it),
    # in the plane's frame (x, y in the plane, h along the normal: one product).
    frame = frame_with_z(n)
    x, y, h = frame.T @ o.points.T
    on = np.abs(h + d) <= OUTLIER_FACTOR * p.ransac_threshold
    bad = _coverage(on, "plane")
    if bad:
        return None, bad
    x, y, h = x[on], y[on], h[on]
    if p.reproject_along_rays:
        # Moving a point along its ray scales all its coordinates alike.
        scale = obb.ray_scale_to_plane(h, np.sqrt(x * x + y * y + h * h), d,
                                       4 * p.ransac_threshold)
        x *= scale
        y *= scale
    # Rectangle direction from the (re-projected) full-resolution outline.
    direction, _ = obb.min_area_rectangle(np.column_stack([x - x.mean(), y - y.mean()]))
    u = frame[:, :2] @ direction
    v = np.cross(n, u)  # = frame[:, :2] @ (-direction[1], direction[0])
    lo_u, hi_u = obb.interval(x * direction[0] + y * direction[1], o.spacing,
                              correct=p.edge_correction)
    lo_v, hi_v = obb.interval(y * direction[0] - x * direction[1], o.spacing,
                              correct=p.edge_correction)
    if hi_v - lo_v > hi_u - lo_u:  # x along the longer side
        u, v = v, -u
        (lo_u, hi_u), (lo_v, hi_v) = (lo_v, hi_v), (-hi_u, -lo_u)
    plane_off = float(-d)  # n . x = -d
    center = u * (lo_u + hi_u) / 2 + v * (lo_v + hi_v) / 2 + n * plane_off
    rot = np.column_stack([u, v, n])
    rmse = _rms(model.distance(o.sample(np.arange(len(o.points)))))
    prim = Primitive(o.oid, "plane", center, rot,
                     {"length": hi_u - lo_u, "width": hi_v - lo_v}, len(o.points), rmse)
    return prim, "plane verified"


def _fit_cuboid(o: _Object, main: int, assignment: tuple[int, ...]) -> tuple[Primitive | None, str]:
    p = o.params
    # Sliver faces (assignment -1) fit no axis; their points join the nearest real face.
    keep = [i for i, a in enumerate(assignment) if a >= 0]
    faces = [o.faces[i] for i in keep]
    normals, weights, planes, inlier_ok, inlier_all = [], [], [], 0, 0
    for f in faces:
        w = o.wc.points[f.working]
        model = refine(_plane_from_face(f, w), w, p.ransac_threshold)
        model = refine(model, o.sample(f.points), p.ransac_threshold)
        inl = np.abs(model.distance(w)) <= p.ransac_threshold
        inlier_ok += int(inl.sum())
        inlier_all += len(w)
        planes.append(model)
        normals.append(model.normal)
        weights.append(float(len(f.working)))
    bad = _verify(inlier_ok / max(inlier_all, 1), p, "cuboid")
    if bad:
        return None, bad
    assign = np.asarray([assignment[i] for i in keep], dtype=np.int64)
    rot = obb.orthonormalize_axes(np.array(normals), np.array(weights), assign)
    # Every point is re-assigned to its nearest face plane (edge points may sit in the
    # wrong face) and, optionally, moved onto that plane along its viewing ray.
    nearest, nearest_dist = _nearest_surface([np.abs(m.distance(o.points)) for m in planes])
    # Points far from every face (flying pixels, strays) take no part in the sizing.
    nearest[nearest_dist > OUTLIER_FACTOR * p.ransac_threshold] = -1
    bad = _coverage(nearest >= 0, "cuboid")
    if bad:
        return None, bad
    q = o.points.copy()
    proj_faces = []
    for fi, model in enumerate(planes):
        sel = nearest == fi
        if p.reproject_along_rays:
            q[sel] = obb.ray_to_plane(take_rows(o.points, sel), model.normal, model.d,
                                      4 * p.ransac_threshold)
        proj_faces.append(take_rows(q, sel) @ rot)
    proj = take_rows(q, nearest >= 0) @ rot
    lo, hi = np.empty(3), np.empty(3)
    reach = OUTLIER_FACTOR * p.ransac_threshold
    for a in range(3):
        vals = _without_strays(np.ascontiguousarray(proj[:, a]))
        vmin, vmax = float(vals.min()), float(vals.max())
        closed_lo, closed_hi = [], []
        for fi, pf in enumerate(proj_faces):
            if assign[fi] != a or len(pf) == 0:
                continue
            pos = float(np.median(pf[:, a]))
            if not vmin - reach <= pos <= vmax + reach:
                continue  # a face of strays beyond the bulk closes nothing
            (closed_hi if vmax - pos < pos - vmin else closed_lo).append(pos)
        s_lo, s_hi = o.support_ends(rot[:, a], np.zeros(3), vmin, vmax)
        lo[a], hi[a] = obb.interval(vals, o.spacing,
                                    float(np.min(closed_lo)) if closed_lo else s_lo,
                                    float(np.max(closed_hi)) if closed_hi else s_hi,
                                    correct=p.edge_correction)
    center = rot @ ((lo + hi) / 2)
    ext = hi - lo
    prim = Primitive(o.oid, "cuboid", center, rot,
                     {"length": float(ext[0]), "width": float(ext[1]), "height": float(ext[2])},
                     len(o.points), _rms(nearest_dist))
    return prim, "cuboid verified"


def _axis_ok(axis: NDArray[np.float64], prior: NDArray[np.float64] | None, tol: float) -> bool:
    return prior is None or abs(float(axis @ prior)) >= math.cos(tol)


def _curved_and_planar(o: _Object) -> tuple[list[int], list[int]]:
    curved = [i for i, f in enumerate(o.faces) if not f.info.planar]
    planar = [i for i, f in enumerate(o.faces) if f.info.planar]
    return curved, planar


#: RANSAC takes no cone hypothesis flatter than this half-angle [rad] (80 deg).
MAX_CONE_HALF_ANGLE = 1.4
#: A cap grown into a curved face must hold at least this share of the face's working
#: points (besides ``min_face_points``).
INNER_CAP_SHARE = 0.1


def _inner_cap(wp: NDArray[np.float64], wn: NDArray[np.float64], model,
               on_model: NDArray[np.bool_], p: ModelingParams
               ) -> tuple[NDArray[np.float64], float, NDArray[np.bool_]] | None:
    """A flat end of a cylinder or cone that region growing joined to its curved side.

    Real lids and bottoms meet the side in a rounded edge, over which the normals turn
    smoothly, so the end is not a face of its own. Its working points (``wp``, ``wn``:
    the curved faces') are off the fitted side and have normals along the axis; when
    they are enough and a plane perpendicular to the axis fits enough of them inside
    the model (within its radius), that plane is returned as (unit normal towards the
    sensor, offset d of n . x + d = 0, which of ``wp`` lie on it inside the model).
    """
    axis = model.axis
    if isinstance(model, ConeModel) and \
            model.half_angle > math.pi / 2 - 2.0 * p.angle_tolerance:
        return None  # the side's own normals turn nearly along the axis: no telling apart
    cos_tol = math.cos(p.angle_tolerance)
    along = (np.abs(wn @ axis) >= cos_tol) & ~on_model
    need = max(p.min_face_points, INNER_CAP_SHARE * len(wp))
    if along.sum() < need:
        return None
    cand = take_rows(wp, along)
    # The end seen most (a lid; the bottom of a standing object is hidden), refined.
    plane = refine(PlaneModel(axis.copy(), -float(np.median(cand @ axis))), cand,
                   p.ransac_threshold)
    if abs(plane.normal @ axis) < cos_tol:
        return None
    on_cap = (np.abs(plane.distance(wp)) <= p.ransac_threshold) & \
        (model.distance(wp) <= p.ransac_threshold)
    if (on_cap & along).sum() < need:
        return None
    normal = _toward_sensor(plane.normal, centroid(cand))
    return normal, float(plane.d) if normal @ plane.normal > 0 else -float(plane.d), on_cap


def _fit_round(o: _Object, kind: str, main: int,
               axis_prior: NDArray[np.float64] | None = None) -> tuple[Primitive | None, str]:
    """Cylinder, cone or sphere on the curved faces (planar faces: caps / base); the
    axis of a cylinder or cone along ``axis_prior`` or else the main planar face's normal,
    if any."""
    p = o.params
    curved, planar = _curved_and_planar(o)
    if not curved:
        return None, f"{kind}: no curved face"
    cw = o.face_working(curved)
    wp, wn = o.wc.points[cw], o.wc.normals[cw]
    prior = axis_prior if axis_prior is not None else \
        o.faces[main].info.normal if main >= 0 and o.faces[main].info.planar else None
    tol = p.angle_tolerance

    if kind == "sphere":
        cls = SphereModel
        accept = lambda m: p.min_radius <= m.radius <= p.max_radius  # noqa: E731
    elif kind == "cylinder":
        cls = CylinderModel
        accept = lambda m: (p.min_radius <= m.radius <= p.max_radius  # noqa: E731
                            and _axis_ok(m.axis, prior, tol))
    else:
        cls = ConeModel
        accept = lambda m: (  # noqa: E731
            p.min_cone_half_angle <= m.half_angle <= MAX_CONE_HALF_ANGLE
            and _axis_ok(m.axis, prior, tol))
    fit = ransac(cls, wp, wn, p.ransac_threshold, p.ransac_normal_threshold,
                 p.ransac_max_iterations, p.ransac_confidence, o.rng, accept=accept)
    if fit is None:
        return None, f"{kind}: no valid RANSAC hypothesis"
    model = refine(fit.model, wp, p.ransac_threshold, rounds=1)
    full = o.sample(o.face_points(curved))
    model = refine(model, full, p.ransac_threshold, rounds=2)
    on_model = np.abs(model.distance(wp)) <= p.ransac_threshold
    inner_caps: list[tuple[NDArray[np.float64], float]] = []
    if kind != "sphere" and not on_model.all():
        cap = _inner_cap(wp, wn, model, on_model, p)
        if cap is not None:
            normal, offset, on_cap = cap
            inner_caps.append((normal, offset))
            on_model |= on_cap
    ratio = float(np.mean(on_model))
    bad = _verify(ratio, p, kind)
    if bad:
        return None, bad
    rmse = _rms(model.distance(full))
    n_all = len(o.points)
    if kind == "sphere":
        if not p.min_radius <= model.radius <= p.max_radius:
            return None, f"sphere radius {model.radius:.4f} m out of range"
        return Primitive(o.oid, "sphere", model.center.copy(), np.eye(3),
                         {"radius": float(model.radius)}, n_all, rmse), "sphere verified"

    axis = model.axis
    if not _axis_ok(axis, prior, tol):
        return None, f"{kind} axis not aligned with its planar face"
    caps = [(o.faces[i].info.normal, o.faces[i].info.offset) for i in planar
            if abs(o.faces[i].info.normal @ axis) >= math.cos(tol)] + inner_caps
    # Each point goes to its nearest surface: the curved model or one of its caps.
    dists = [np.abs(model.distance(o.points))] + \
        [np.abs(o.points @ normal + offset) for normal, offset in caps]
    nearest, nearest_dist = _nearest_surface(dists)
    nearest[nearest_dist > OUTLIER_FACTOR * p.ransac_threshold] = -1
    bad = _coverage(nearest >= 0, kind)
    if bad:
        return None, bad
    curved_pts = take_rows(o.points, nearest == 0)
    arc = _arc_span(curved_pts, model.point if kind == "cylinder" else model.apex, axis)
    if arc < p.min_arc:
        return None, (f"{kind} rejected: its points span only {math.degrees(arc):.0f} deg "
                      f"around the axis")
    if kind == "cylinder":
        if not p.min_radius <= model.radius <= p.max_radius:
            return None, f"cylinder radius {model.radius:.4f} m out of range"
        if p.reproject_along_rays:
            curved_pts = obb.ray_to_cylinder(curved_pts, model.point, axis, model.radius,
                                             p.ransac_threshold)
        origin = model.point
    else:
        if model.half_angle < p.min_cone_half_angle:
            return None, f"cone half-angle {math.degrees(model.half_angle):.1f} deg too small"
        origin = model.apex
    t_parts, closed = [(curved_pts - origin) @ axis], []
    for ci, (normal, offset) in enumerate(caps, start=1):
        q = take_rows(o.points, nearest == ci)
        if len(q) == 0:
            continue
        if p.reproject_along_rays:
            q = obb.ray_to_plane(q, normal, offset, 4 * p.ransac_threshold)
        t_cap = (q - origin) @ axis
        t_parts.append(t_cap)
        closed.append(float(np.median(t_cap)))
    t_all = np.concatenate(t_parts)
    tmin, tmax = float(t_all.min()), float(t_all.max())
    closed_lo = [c for c in closed if c - tmin < tmax - c]
    closed_hi = [c for c in closed if c - tmin >= tmax - c]
    s_lo, s_hi = o.support_ends(axis, origin, tmin, tmax)
    lo, hi = obb.interval(t_all, o.spacing, min(closed_lo) if closed_lo else s_lo,
                          max(closed_hi) if closed_hi else s_hi, correct=p.edge_correction)
    bulk = _bulk_extent(o.points, axis)
    if hi - lo > BULK_FACTOR * bulk + BULK_MARGIN:
        # Stray points that happen to lie on the model's surface far from the object
        # (flying pixels, another surface) stretched it.
        return None, (f"{kind} rejected: {(hi - lo) * 1000:.0f} mm long, the object's "
                      f"points span {bulk * 1000:.0f} mm along its axis")
    if kind == "cylinder":
        if hi - lo <= 0:
            return None, "cylinder has no height"
        if axis @ (origin + axis * (lo + hi) / 2) > 0:  # point the axis towards the sensor
            axis, lo, hi = -axis, -hi, -lo
        center = origin + axis * (lo + hi) / 2
        return Primitive(o.oid, "cylinder", center, frame_with_z(axis),
                         {"radius": float(model.radius), "height": float(hi - lo)}, n_all, rmse), \
            "cylinder verified"
    # Cone: apex at t = 0, base at the far end.
    height = hi if hi > 0 else 0.0
    if height <= 0 or (lo < -0.2 * height):
        return None, "cone points lie on both sides of the apex"
    if lo > CONE_APEX_REACH * height:
        return None, (f"cone rejected: its points stop {lo * 1000:.0f} mm short of the apex "
                      f"(a frustum)")
    radius = height * math.tan(model.half_angle)
    if not p.min_radius <= radius <= p.max_radius:
        return None, f"cone radius {radius:.4f} m out of range"
    reach = _bulk_reach(o.points, origin, axis)
    if radius > BULK_FACTOR * reach + BULK_MARGIN:
        # A nearly flat cone whose points cover only the region round its apex.
        return None, (f"cone rejected: radius {radius * 1000:.0f} mm, the object's points "
                      f"reach {reach * 1000:.0f} mm from its axis")
    center = origin + axis * height / 2
    return Primitive(o.oid, "cone", center, frame_with_z(-axis),
                     {"radius": float(radius), "height": float(height)}, n_all, rmse), "cone verified"


# ---------------------------------------------------------------------------------------
# Public API
# ---------------------------------------------------------------------------------------

def model_object(points: NDArray[np.float64], object_id: int, params: ModelingParams,
                 rng: np.random.Generator, spacing: float,
                 face_labels: NDArray[np.int64] | None = None,
                 supports: tuple[tuple[NDArray[np.float64], float], ...] = ()) -> Primitive:
    """Model one segmented object.

    Parameters
    ----------
    points : (n, 3) float64 array [m], finite
    object_id : int
    params : ModelingParams
    rng : numpy Generator
    spacing : float [m]
        Median point spacing of the object (for edge corrections).
    face_labels : (n,) int64, optional
        Known faces; when absent faces are found by region growing.
    supports : tuple of (normal (3,), d) planes n . x + d = 0
        Support surfaces the object may rest on (they close its hidden bottom end).
    """
    n = len(points)
    if n < max(params.min_object_points, 4):
        return _unknown(object_id, points, f"{n} points < min_object_points")
    sub = points[:: max(1, n // 5000)]
    sv = np.linalg.svd(sub - centroid(sub), compute_uv=False) if np.all(np.isfinite(sub)) \
        else np.zeros(3)
    if sv[0] <= 1e-9 or sv[1] <= 1e-6 * sv[0]:
        return _unknown(object_id, points, "degenerate point set (collinear or duplicate)")
    wc, faces, adjacency = _build_faces(points, params, face_labels)
    if len(wc.points) < 6 or not faces:
        return _unknown(object_id, points, "too few distinct points after voxelization")
    summaries = tuple(f.summary for f in faces)
    infos = [f.info for f in faces]
    def curvature_of(which: NDArray[np.bool_]) -> tuple[NDArray, NDArray]:
        k_max, k_min = principal_curvatures(wc.points, wc.normals, wc.neighbors)
        smooth = which & (wc.variation <= params.edge_variation_threshold)
        sel = smooth if smooth.sum() >= 10 else which
        return k_max[sel], k_min[sel]

    curvature = None
    if not any(i.planar for i in infos):
        curvature = curvature_of(np.ones(len(wc.points), dtype=bool))
    decision = _decide(infos, adjacency, curvature, params)
    reasons = [decision.reason]
    if not decision.candidates and decision.category == "mixed":
        # The planar faces fit no rule with the curved ones (handles, rims, slivers of
        # noise): judge the curved faces alone, as an all-curved object (no axis prior).
        curved_mask = np.zeros(len(wc.points), dtype=bool)
        for f in faces:
            if not f.info.planar:
                curved_mask[f.working] = True
        cands, why = curvature_candidates(*curvature_of(curved_mask),
                                          params.sphere_curvature_ratio,
                                          params.developable_curvature_ratio,
                                          params.cone_curvature_variation)
        decision = GraphDecision("curved", cands, -1, (), why)
        reasons.append(f"curved faces alone: {why}")
    obj = _Object(object_id, points, wc, faces, adjacency, spacing, params, rng, supports)
    prim = _fit_candidates(obj, decision, reasons)
    if prim is None:
        # Second chance for flat faces that came out curved (a box side bent by sensor
        # noise or depth distortion beyond the plane test): with them taken as planes
        # the object may be a plane or cuboid after all.
        flat = [i for i, f in enumerate(faces) if not f.info.planar and _normals_flat(f.info)]
        if flat:
            faces2 = [_as_planar(wc, f, params.ransac_threshold) if i in flat else f
                      for i, f in enumerate(faces)]
            decision2 = _decide([f.info for f in faces2], adjacency, None, params)
            decision2 = GraphDecision(decision2.category,
                                      tuple(k for k in decision2.candidates
                                            if k in ("plane", "cuboid")),
                                      decision2.main_face, decision2.axis_of_face,
                                      decision2.reason)
            if decision2.candidates:
                reasons.append(f"faces {flat} taken as planar (their normals turn less than "
                               f"{math.degrees(FLAT_FACE_ANGLE):.0f} deg): {decision2.reason}")
                obj2 = _Object(object_id, points, wc, faces2, adjacency, spacing, params, rng,
                               supports)
                prim = _fit_candidates(obj2, decision2, reasons)
                if prim is not None:
                    summaries = tuple(f.summary for f in faces2)
    if prim is None:
        # Upright above its support: a round object standing on the desk (or on another
        # object on it) mostly has its axis along the desk's normal. Without that prior,
        # a large flat lid grown together with the side (over a rounded edge) draws
        # RANSAC to a huge cylinder through the lid.
        kinds = tuple(k for k in decision.candidates if k in ("cylinder", "cone"))
        up = _support_below(obj) if kinds else None
        if up is not None:
            before = len(reasons)
            upright = GraphDecision(decision.category, kinds, decision.main_face,
                                    decision.axis_of_face, decision.reason)
            prim = _fit_candidates(obj, upright, reasons, axis_prior=up)
            reasons[before:] = [f"upright above the support: {r}" for r in reasons[before:]]
    if prim is not None:
        return Primitive(prim.id, prim.type, prim.center, prim.rotation, prim.dimensions,
                         prim.point_count, prim.rmse, summaries, "; ".join(reasons))
    return _unknown(object_id, points, "; ".join(reasons), summaries)


def _support_below(o: _Object) -> NDArray[np.float64] | None:
    """Normal of a support plane that ``o`` stands above (its bulk above the plane by
    more than twice ``seg_plane_threshold`` plus the RANSAC threshold, nothing of it
    below by more than that), or None. Objects stacked on others count too."""
    tol = 2.0 * o.params.seg_plane_threshold + o.params.ransac_threshold
    sub = o.points[:: max(1, len(o.points) // 5000)]
    for n, d in o.supports:
        h = sub @ n + d
        if np.median(h) < 0:
            h = -h
        if float(np.percentile(h, 1.0)) >= -tol and float(np.median(h)) > tol:
            return np.asarray(n, dtype=np.float64)
    return None


def _decide(infos: list[FaceInfo], adjacency: NDArray[np.bool_],
            curvature: tuple[NDArray, NDArray] | None, params: ModelingParams) -> GraphDecision:
    """The model graph's decision with the thresholds of ``params``."""
    return decide_type(infos, adjacency, params.angle_tolerance, 3 * params.ransac_threshold,
                       curvature, params.sphere_curvature_ratio,
                       params.developable_curvature_ratio, params.cone_curvature_variation)


#: A curved face whose point normals stay within this angle [rad] of their mean (90th
#: percentile) may be taken as planar when no model fits it as curved. A round surface's
#: normals turn with its arc (at least ``min_arc`` for an accepted fit).
FLAT_FACE_ANGLE = math.radians(20.0)


def _normals_flat(info: FaceInfo) -> bool:
    n = info.point_normals
    if len(n) < 3:
        return False
    mean = centroid(n)
    norm = float(np.linalg.norm(mean))
    if norm <= 1e-9:
        return False
    cos = np.abs(n @ (mean / norm))
    return float(np.percentile(cos, 10.0)) >= math.cos(FLAT_FACE_ANGLE)


def _as_planar(wc: WorkingCloud, face: _Face, threshold: float) -> _Face:
    """``face`` re-described as a plane (:func:`~geomodel_ros.core.faces.face_plane`)."""
    info = face.info
    plane, _ = face_plane(wc.points[face.working], wc.normals[face.working], threshold)
    normal = _toward_sensor(plane.normal, info.center)
    info2 = FaceInfo(True, normal, float(-normal @ info.center), info.size,
                     info.point_normals, info.center)
    s = face.summary
    return _Face(info2, FaceSummary("planar", s.cf, s.point_count, normal), face.working,
                 face.points)


def _fit_candidates(obj: _Object, decision: GraphDecision, reasons: list[str],
                    axis_prior: NDArray[np.float64] | None = None) -> Primitive | None:
    """The first of the decision's candidate types that fits and verifies (reasons of
    every attempt appended to ``reasons``), or None."""
    for kind in decision.candidates:
        try:
            if kind == "plane":
                prim, why = _fit_plane(obj, decision.main_face)
            elif kind == "cuboid":
                prim, why = _fit_cuboid(obj, decision.main_face, decision.axis_of_face)
            else:
                prim, why = _fit_round(obj, kind, decision.main_face, axis_prior)
        except (np.linalg.LinAlgError, ValueError, FloatingPointError) as exc:
            prim, why = None, f"{kind}: numerical failure ({exc})"
        reasons.append(why)
        if prim is not None and _finite(prim):
            return prim
    return None


def _finite(p: Primitive) -> bool:
    vals = [*p.center.ravel(), *p.rotation.ravel(), *p.dimensions.values(), p.rmse]
    return bool(np.all(np.isfinite(vals))) and all(v > 0 for v in p.dimensions.values())


def _group_by_label(idx: NDArray[np.int64], lab: NDArray[np.int64]
                    ) -> tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.int64],
                               NDArray[np.int64]]:
    """``idx`` grouped by their labels ``lab`` (>= 0): (order, ids, starts, ends) with
    ``order[starts[k]:ends[k]]`` the indices labelled ``ids[k]``, in input order."""
    top = int(lab.max())
    if top < 2 ** 15:
        # Few small labels (the usual case): counting, and numpy's radix sort for int16.
        counts = np.bincount(lab, minlength=top + 1)
        ids = np.flatnonzero(counts)
        ends = np.cumsum(counts)[ids]
        starts = ends - counts[ids]
        order = idx[np.argsort(lab.astype(np.int16), kind="stable")]
    else:
        srt = np.argsort(lab, kind="stable")
        order = idx[srt]
        ids, starts = np.unique(lab[srt], return_index=True)
        ends = np.r_[starts[1:], len(order)]
    return order, ids, starts, ends


def estimate_spacing(points: NDArray[np.float64], rng: np.random.Generator,
                     max_points: int = 2000, queries: int = 500) -> float:
    """Approximate median point spacing [m] of a surface sampled by ``points`` (n, 3).

    Large sets are estimated from a random subset: on a surface the nearest-neighbour
    distance scales with 1 / sqrt(density), so the subset's median is scaled by
    sqrt(subset / n).
    """
    n = len(points)
    if n < 2:
        return 0.0
    sub = points if n <= max_points else points[rng.choice(n, max_points, replace=False)]
    d, _ = cKDTree(sub).query(sub[: min(len(sub), queries)], k=2)
    return float(np.median(d[:, 1]) * math.sqrt(len(sub) / n))


def model_objects(points: NDArray, labels: NDArray, params: ModelingParams | None = None, *,
                  face_labels: NDArray | None = None,
                  rng: np.random.Generator | int | None = None,
                  supports: dict[int, tuple[NDArray[np.float64], float]] | None = None
                  ) -> ModelingResult:
    """Model every labelled object of a scene.

    Parameters
    ----------
    points : (N, 3) float array [m]
        Scene points; non-finite rows are ignored.
    labels : (N,) int array
        Object id per point; negative = no object.
    params : ModelingParams, optional
    face_labels : (N,) int array, optional
        Known face id per point (faces are then not searched).
    rng : Generator, seed or None
        Randomness for RANSAC; defaults to ``params.seed``.
    supports : dict id -> (normal (3,), d), optional
        Support planes found by the segmentation; other objects may rest on them.

    Returns
    -------
    ModelingResult with objects ordered by id and timings [s].

    Raises
    ------
    InputError
        For malformed arrays (never for bad geometry).
    """
    t0 = time.perf_counter()
    params = params if params is not None else ModelingParams()
    pts = _check_points(points)
    lab = _check_labels(labels, len(pts), "labels")
    flab = None if face_labels is None else _check_labels(face_labels, len(pts), "face_labels")
    rng = np.random.default_rng(params.seed if rng is None else rng)
    finite = rows_finite(pts) & (lab >= 0)
    idx_all = np.flatnonzero(finite)
    objects: list[Primitive] = []
    if idx_all.size:
        order, ids, starts, ends = _group_by_label(idx_all, lab[idx_all])
        # One independent generator per object: results do not depend on the order in
        # which the worker threads finish (numpy and scipy release the GIL in the heavy
        # parts, so objects are modeled in parallel).
        streams = rng.spawn(len(ids))

        def one(k: int) -> Primitive:
            sel = order[starts[k]:ends[k]]
            opts = take_rows(pts, sel)
            orng = streams[k]
            oid = int(ids[k])
            planes = tuple(v for key, v in (supports or {}).items() if key != oid)
            return model_object(opts, oid, params, orng, estimate_spacing(opts, orng),
                                None if flab is None else flab[sel], planes)

        workers = min(len(ids), os.cpu_count() or 1)
        if workers > 1:
            with ThreadPoolExecutor(max_workers=workers) as pool:
                # Largest objects first so that the pool stays balanced.
                order_k = np.argsort(-(ends - starts), kind="stable").tolist()
                done = dict(zip(order_k, pool.map(one, order_k)))
            objects = [done[k] for k in range(len(ids))]
        else:
            objects = [one(k) for k in range(len(ids))]
    return ModelingResult(objects, {"modeling_s": time.perf_counter() - t0})


def model_scene(points: NDArray, params: ModelingParams | None = None, *,
                organized_shape: tuple[int, int] | None = None,
                rng: np.random.Generator | int | None = None
                ) -> tuple[NDArray[np.int64], ModelingResult]:
    """Segment a raw scene cloud, then model every segment.

    Parameters
    ----------
    points : (N, 3) float array [m]
        Scene cloud in the sensor frame (non-finite rows allowed, labelled -1).
    params : ModelingParams, optional
    organized_shape : (H, W), optional
        Image shape when ``points`` are the rows of an organized cloud (N = H * W).
    rng : Generator, seed or None

    Returns
    -------
    labels : (N,) int64
        Object id per input row (-1 = invalid or noise).
    result : ModelingResult
        Objects by id; timing has ``segmentation_s`` and ``modeling_s``.
    """
    from geomodel_ros.core.segmentation import segment_scene

    params = params if params is not None else ModelingParams()
    pts = _check_points(points)
    if organized_shape is not None and organized_shape[0] * organized_shape[1] != len(pts):
        raise InputError(f"organized_shape {organized_shape} does not match {len(pts)} points")
    rng = np.random.default_rng(params.seed if rng is None else rng)
    seg = segment_scene(pts, params, rng=rng)
    result = model_objects(pts, seg.labels, params, rng=rng, supports=seg.support_planes)
    result.timing.update(seg.timing)
    result.timing["total_s"] = result.timing["modeling_s"] + seg.timing["segmentation_s"]
    return seg.labels, result
