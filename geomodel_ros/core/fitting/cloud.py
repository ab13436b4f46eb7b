"""An object prepared for fitting: its points, working cloud, faces and support planes."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Callable, Sequence

import numpy as np
from numpy.typing import NDArray

from geomodel_ros.core.faces import (FLAT_SPREAD_SHARE, FaceSet, WorkingCloud,
                                     build_working_cloud, face_plane, faces_from_labels,
                                     split_faces, split_plane_unions)
from geomodel_ros.core.fastmath import centroid, take_rows
from geomodel_ros.core.fitting.orient import toward_sensor
from geomodel_ros.core.fitting.slow_bend import SlowBend, SlowBendNull, bends_beyond
from geomodel_ros.core.model_graph import FaceInfo
from geomodel_ros.core.params import ModelingParams
from geomodel_ros.core.primitives import FaceSummary
from geomodel_ros.core.ransac import PlaneModel
from geomodel_ros.core.surface_type import FaceBend, FaceFeature, face_bend, face_feature
from geomodel_ros.core.view import SceneView

__all__ = ["Plane", "ObjectFace", "ObjectCloud", "build_faces", "build_flat_face", "as_planar",
           "describe_faces", "independent_noise", "central_bend", "bends_beyond_noise",
           "MAX_NOISE_CORRELATION"]

#: A plane n . x + d = 0: (unit normal (3,), offset d [m]).
Plane = tuple[NDArray[np.float64], float]

#: A support plane closes an object's extent at an end when it crosses the object's axis
#: line within this many ``seg_plane_threshold`` of that end (the segmentation's own
#: tolerance for points on the plane, on either side).
SUPPORT_END_FACTOR = 2.0
#: A face that the surface-type test calls curved is planar after all when a plane fits
#: its points with an RMS error of at most this share of ``ransac_threshold`` (well
#: inside the inlier band: noise, not curvature) and it shows no bend beyond the noise
#: (:func:`~geomodel_ros.core.surface_type.face_bend`).
PLANAR_RMSE_SHARE = 0.5

#: The noise counts as independent from point to point (:func:`independent_noise`) while
#: the slow errors' variance is at most the local noise's: the frame's noise across its
#: dominant plane is at most sqrt(2) times its local noise. Measured: synthetic frames
#: with per-pixel noise 1.00-1.11; every real frame 1.6-2.5 (osd_learn Kinect 1.64-2.45,
#: the PCL mug stereo 2.17, the pcl_scenes 2.03 and 2.44), where flat faces of 30-150 mm
#: bend by 45-135 deg within their noise and the F-test would call them curved. Above it
#: a bend is judged against the bends the frame's slow errors give flat patches of its
#: support (:mod:`~.slow_bend`).
MAX_NOISE_CORRELATION = math.sqrt(2.0)
#: Smallest norm of a curved face's mean normal that is divided by (guards a face whose
#: normals cancel, which no real face has).
MIN_MEAN_NORMAL = 1e-12


@dataclass(frozen=True)
class ObjectFace:
    """One face of an object: its model-graph description and its points.

    Attributes
    ----------
    info : FaceInfo
    summary : FaceSummary
    working : (m,) int64, indices into the working cloud
    points : (n,) int64, indices into the object's points
    """

    info: FaceInfo
    summary: FaceSummary
    working: NDArray[np.int64]
    points: NDArray[np.int64]


@dataclass
class ObjectCloud:
    """One segmented object with everything its fitting units need.

    Attributes
    ----------
    oid : int
    points : (N, 3) float64 [m], finite
    wc : WorkingCloud
    faces : list of ObjectFace
    adjacency : (F, F) bool
    spacing : float [m], median point spacing
    params : ModelingParams
    rng : numpy Generator (the object's own stream)
    supports : tuple of Plane, support planes the object may rest on
    view : SceneView or None, the scene's returns (sensor at the origin) for completing
        hidden ends; None when unknown
    correlation : float, the frame's ratio of slow to local depth noise
        (``NoiseEstimate.scale``; 1 without an estimate)
    slow_null : SlowBendNull or None, the bends the frame's slow errors give flat patches
        of its support (:mod:`~.slow_bend`); None without a support or an estimate
    first_look : bool, a thinned copy fitted only to judge whether a model is worth a
        full fit (``strategies.thinned``): round fits skip their refinement on the
        full-resolution points
    center : (3,) float64 [m], centroid of ``points``
    """

    oid: int
    points: NDArray[np.float64]
    wc: WorkingCloud
    faces: list[ObjectFace]
    adjacency: NDArray[np.bool_]
    spacing: float
    params: ModelingParams
    rng: np.random.Generator
    supports: tuple[Plane, ...] = ()
    view: SceneView | None = None
    correlation: float = 1.0
    slow_null: SlowBendNull | None = None
    first_look: bool = False
    center: NDArray[np.float64] = field(init=False)

    def __post_init__(self) -> None:
        """Compute the centroid."""
        self.center = centroid(self.points)

    def support_ends(self, axis: NDArray[np.float64], origin: NDArray[np.float64],
                     vmin: float, vmax: float) -> tuple[float | None, float | None]:
        """Where support planes (desk, floor) close the extent [vmin, vmax] along ``axis``.

        Extents are coordinates ``(x - origin) . axis`` [m]. An object resting on a
        support plane has its hidden end on that plane: when a support plane
        perpendicular to ``axis`` (within ``angle_tolerance``) crosses the object's axis
        line (through its centroid) within SUPPORT_END_FACTOR ``seg_plane_threshold`` of
        an end, that crossing is the end. None where no plane closes an end.
        """
        ref = self.center
        lo = hi = None
        tol = SUPPORT_END_FACTOR * self.params.seg_plane_threshold
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
        """Full-resolution points (n, 3) of ``idx``, a random ``refine_max_points`` at most."""
        cap = self.params.refine_max_points
        if len(idx) > cap:
            idx = idx[self.rng.choice(len(idx), size=cap, replace=False, shuffle=False)]
        return take_rows(self.points, idx)

    def face_points(self, which: list[int]) -> NDArray[np.int64]:
        """Return the indices into ``points`` of the faces ``which``."""
        return np.concatenate([self.faces[i].points for i in which]) if which else \
            np.zeros(0, dtype=np.int64)

    def face_working(self, which: list[int]) -> NDArray[np.int64]:
        """Return the indices into the working cloud of the faces ``which``."""
        return np.concatenate([self.faces[i].working for i in which]) if which else \
            np.zeros(0, dtype=np.int64)

    def curved_and_planar(self) -> tuple[list[int], list[int]]:
        """Return the indices of the curved faces and of the planar faces."""
        curved = [i for i, f in enumerate(self.faces) if not f.info.planar]
        planar = [i for i, f in enumerate(self.faces) if f.info.planar]
        return curved, planar


def _checked_planar(cf_planar: bool, plane_rmse: float, threshold: float,
                    bent: Callable[[], bool]) -> bool:
    """Verify the CF decision by a plane fit (paper 3.2: a fit that fails rejects the type).

    A "planar" face no plane fits within ``threshold`` [m] is curved; a "curved" face a
    plane fits within PLANAR_RMSE_SHARE of it is planar unless ``bent()`` (called only
    then) finds a bend beyond its noise.
    """
    if cf_planar and plane_rmse > threshold:
        return False
    if not cf_planar and plane_rmse <= threshold * PLANAR_RMSE_SHARE:
        return not bent()
    return cf_planar


def independent_noise(params: ModelingParams, correlation: float) -> bool:
    """Whether the frame's noise is measured and mostly independent from point to point.

    ``noise_model = auto`` and ``correlation`` (the frame's ratio of the noise across its
    dominant plane to the local noise, ``NoiseEstimate.scale``) at most
    MAX_NOISE_CORRELATION. The tests that tell a bend or a round patch from noise by its
    significance assume independent noise; slow sensor errors bend flat faces as well.
    """
    return params.noise_model == "auto" and correlation <= MAX_NOISE_CORRELATION


def _bent(points: NDArray[np.float64], mass: NDArray[np.float64], normal: NDArray[np.float64],
          feat: FaceFeature, params: ModelingParams, correlation: float,
          slow_null: SlowBendNull | None = None) -> bool:
    """Whether a face (working points (m, 3), ``mass`` (m,)) bends beyond its noise.

    Significantly and with normals turning across it by more than ``min_arc``, the least
    arc a round side must span to be verified as one (a face that turns less cannot be a
    round side by itself; measured: flat box faces of real Kinect frames (osd_learn) turn
    by up to 38 deg, synthetic ones under Kinect-class noise by up to 12 deg, the sides of
    cylinders, cones, frustums and spheres 60 mm across at 0.5-1.5 m mostly by 45-95
    deg), judged like the CF (paper 3.1) on its points within the largest CF radius of the
    face centre (``feat``): a strip of a neighbouring face or a rounded edge along the
    border does not bend a flat face. Significantly means: where the noise is independent
    (:func:`independent_noise`), by the F-test of
    :func:`~geomodel_ros.core.surface_type.face_bend`; where the frame's noise varies
    slowly across the image (``correlation``, ``NoiseEstimate.scale``, above
    MAX_NOISE_CORRELATION), beyond the bends those errors give flat patches of the frame's
    support of the same size in the image (``slow_null``, :mod:`~.slow_bend`); without
    such a null, or with ``noise_model = fixed`` (which keeps the previous decision
    exactly), never.
    """
    if independent_noise(params, correlation):
        bend = central_bend(points, mass, normal, feat, correlation)
        return bend.significant and bend.turn > params.min_arc
    judged = _slow_face_bend(points, mass, normal, feat, params, slow_null)
    if judged is None or judged[1].turn <= params.min_arc:
        return False   # the limit is min_arc plus the errors' turn: no null needed
    inner, bend = judged
    return bends_beyond(bend, _slow_bound(inner, feat, slow_null), params.min_arc)


def _slow_face_bend(points: NDArray[np.float64], mass: NDArray[np.float64],
                    normal: NDArray[np.float64], feat: FaceFeature, params: ModelingParams,
                    slow_null: SlowBendNull | None
                    ) -> tuple[NDArray[np.float64], FaceBend] | None:
    """Return a face's central points (m, 3) and their bend, or None (slow errors not judged).

    None with ``noise_model = fixed``, without a slow-error null, or without central points.
    """
    if params.noise_model != "auto" or slow_null is None:
        return None
    inner = _central(points, feat)
    if not inner.any():
        return None
    return points[inner], face_bend(points[inner], normal, mass[inner])


def _slow_bound(inner: NDArray[np.float64], feat: FaceFeature, slow_null: SlowBendNull
                ) -> SlowBend:
    """Return the slow-error null's bound for a face's central points ``inner`` (m, 3) [m].

    Patches as large in the image as the face's largest CF radius at the points' median
    range, sampled to their count (:meth:`~.slow_bend.SlowBendNull.bound`).
    """
    depth = float(np.median(np.linalg.norm(inner, axis=1)))
    return slow_null.bound(float(feat.radii[-1]), depth, len(inner))


def _central(points: NDArray[np.float64], feat: FaceFeature) -> NDArray[np.bool_]:
    """Mask (m,) of a face's ``points`` (m, 3) within the largest CF radius of its centre."""
    q = points - feat.center
    return np.einsum("ij,ij->i", q, q) <= feat.radii[-1] ** 2


def central_bend(points: NDArray[np.float64], mass: NDArray[np.float64],
                 normal: NDArray[np.float64], feat: FaceFeature, correlation: float) -> FaceBend:
    """:func:`~geomodel_ros.core.surface_type.face_bend` of a face's central region.

    The working points (m, 3) with ``mass`` (m,) within the largest CF radius of the face
    centre (``feat``, paper 3.1), so that a strip of a neighbouring face or a rounded edge
    along the border does not bend a flat face; ``normal`` is the face plane's.
    """
    inner = _central(points, feat)
    return face_bend(points[inner], normal, mass[inner], correlation=correlation)


def bends_beyond_noise(points: NDArray[np.float64], mass: NDArray[np.float64],
                       normal: NDArray[np.float64], feat: FaceFeature, params: ModelingParams,
                       correlation: float, slow_null: SlowBendNull | None) -> bool:
    """Whether a face's central region bends beyond its noise, whatever its turn.

    The working points (m, 3) with ``mass`` (m,) within the largest CF radius of the
    face centre (``feat``); ``normal`` is the face plane's. Where the noise is independent
    (:func:`independent_noise`), the F-test of
    :func:`~geomodel_ros.core.surface_type.face_bend`; under slow sensor errors
    (``correlation`` above MAX_NOISE_CORRELATION), a bend height above every flat patch's
    of the frame's support as large in the image (``slow_null``,
    :meth:`~.slow_bend.SlowBendNull.bound`); without that null, or with ``noise_model =
    fixed``, never.
    """
    if independent_noise(params, correlation):
        return central_bend(points, mass, normal, feat, correlation).significant
    judged = _slow_face_bend(points, mass, normal, feat, params, slow_null)
    if judged is None:
        return False
    inner, bend = judged
    return bend.height > _slow_bound(inner, feat, slow_null).height


def _describe_face(wc: WorkingCloud, widx: NDArray[np.int64], pidx: NDArray[np.int64],
                   params: ModelingParams, correlation: float = 1.0,
                   slow_null: SlowBendNull | None = None,
                   fitted: tuple[PlaneModel, float] | None = None,
                   planar: bool | None = None) -> ObjectFace:
    """Surface type, normal and plane of the face with working points ``widx``.

    ``correlation``: the frame's ratio of slow to local noise, ``slow_null`` the bends of
    its slow errors (see :func:`_bent`). ``fitted``: the face's
    :func:`~geomodel_ros.core.faces.face_plane` when already known (the same points and
    normals, in the same order, with ``ransac_threshold``). ``planar``: the surface type
    when the caller knows it (not tested).
    """
    # The face's working points (M, 3) [m], their unit normals (M, 3) and counts (M,),
    # gathered once (none of the calls below writes to them).
    points, normals, counts = take_rows(wc.points, widx), take_rows(wc.normals, widx), \
        wc.counts[widx]
    # Eqs. 1-6 on the face's voxel centroids weighted by the points each stands for
    # (the full-resolution covariance at a fraction of the cost).
    feat = face_feature(points, params.cf_weights, params.cf_threshold,
                        params.cf_radius_fraction, counts)
    if planar is None or planar:
        plane, plane_rmse = face_plane(points, normals, params.ransac_threshold) \
            if fitted is None else fitted
    if planar is None:
        planar = _checked_planar(feat.planar, plane_rmse, params.ransac_threshold,
                                 lambda: _bent(points, counts, plane.normal,
                                               feat, params, correlation, slow_null))
    center = counts @ points / max(int(counts.sum()), 1)
    if planar:
        normal = toward_sensor(plane.normal, center)
        offset = float(-normal @ center)
    else:
        mn = normals.mean(axis=0)
        normal = mn / max(np.linalg.norm(mn), MIN_MEAN_NORMAL)
        offset = 0.0
    info = FaceInfo(planar, normal, offset, len(widx), normals, center)
    summary = FaceSummary("planar" if planar else "curved", feat.cf_total, len(pidx), normal)
    return ObjectFace(info, summary, widx, pidx)


def _grouped(labels: NDArray[np.int64], count: int) -> tuple[NDArray[np.int64],
                                                             NDArray[np.int64]]:
    """Return indices sorted by label and the bounds of each label 0..count-1 in them."""
    order = np.argsort(labels, kind="stable")
    return order, np.searchsorted(labels[order], np.arange(count + 1))


def build_faces(points: NDArray[np.float64], params: ModelingParams,
                face_labels: NDArray[np.int64] | None, correlation: float = 1.0,
                slow_null: SlowBendNull | None = None
                ) -> tuple[WorkingCloud, list[ObjectFace], NDArray[np.bool_]]:
    """Working cloud, described faces and face adjacency (F, F) of an object's ``points``.

    Faces come from ``face_labels`` (N,) when given, else from region growing.
    ``correlation`` (>= 1) is the frame's ratio of slow to local depth noise
    (``NoiseEstimate.scale``; 1 without an estimate) and ``slow_null`` the bends its slow
    errors give flat patches (:mod:`~.slow_bend`), which the bend test allows for.
    """
    wc = build_working_cloud(points, params.voxel_size, params.normal_neighbors, face_labels,
                             params.max_working_points)
    planes: dict[int, tuple[PlaneModel, float]] = {}
    if face_labels is not None:
        fs = faces_from_labels(wc, face_labels)
    else:
        fs = split_faces(wc, params.face_angle_threshold, params.edge_variation_threshold,
                         params.min_face_points)
        fs = split_plane_unions(wc, fs, params.ransac_threshold, params.angle_tolerance,
                                params.min_face_points, planes)
    return wc, describe_faces(wc, fs, params, correlation, slow_null, planes), fs.adjacency


def describe_faces(wc: WorkingCloud, fs: FaceSet, params: ModelingParams,
                   correlation: float = 1.0, slow_null: SlowBendNull | None = None,
                   planes: dict[int, tuple[PlaneModel, float]] | None = None,
                   planar: Sequence[bool] | None = None) -> list[ObjectFace]:
    """Describe the faces ``fs`` of the working cloud ``wc`` (planar or curved, normal, points).

    ``planes``: planes already fitted to some faces' working points (ascending) and
    normals, by face, taken instead of fitted again. ``planar``: every face's surface type
    when the caller knows them (they are then not tested).
    """
    planes = {} if planes is None else planes
    kinds = [None] * fs.count if planar is None else list(planar)
    order, bounds = _grouped(fs.labels[wc.point_to_working], fs.count)
    worder, wbounds = _grouped(fs.labels, fs.count)
    return [_describe_face(wc, worder[wbounds[f]:wbounds[f + 1]], order[bounds[f]:bounds[f + 1]],
                           params, correlation, slow_null, planes.get(f), kinds[f])
            for f in range(fs.count)]


def build_flat_face(points: NDArray[np.float64], params: ModelingParams,
                    correlation: float = 1.0, slow_null: SlowBendNull | None = None
                    ) -> tuple[WorkingCloud, list[ObjectFace], NDArray[np.bool_]] | None:
    """:func:`build_faces` of points known to lie on one plane, without a neighbour search.

    For an object the segmentation took as a support plane (its points lie within the
    support band of one plane). The working points are :func:`build_faces`' (the same
    voxels), taken as one face when they lie flat: their robust spread about their
    least-squares plane is at most FLAT_SPREAD_SHARE of ``ransac_threshold``, the spread
    below which :func:`~geomodel_ros.core.faces.face_plane` takes that plane whatever the
    point normals. Every working point gets that plane's normal (towards the sensor) and
    no neighbours; the face is described as :func:`build_faces` describes a face.

    Returns
    -------
    The working cloud, its one face and the (1, 1) adjacency, or None when the working
    points do not lie flat or the face is not described as planar (the faces must then
    be found, :func:`build_faces`).
    """
    # k = 0 neighbours: the voxels of build_faces' working cloud, no normals estimated.
    # Their zero normals have no mean direction, so face_plane returns the least-squares
    # plane and its spread whatever the spread.
    wc = build_working_cloud(points, params.voxel_size, 0, None, params.max_working_points)
    plane, spread = face_plane(wc.points, wc.normals, params.ransac_threshold)
    if len(wc.points) < 3 or spread > FLAT_SPREAD_SHARE * params.ransac_threshold:
        return None
    normal = toward_sensor(plane.normal, centroid(wc.points))
    wc.normals = np.tile(normal, (len(wc.points), 1))
    # face_plane returned the least-squares plane on its first test (the spread is within
    # FLAT_SPREAD_SHARE), which does not read the normals: the face's plane is that one.
    face = _describe_face(wc, np.arange(len(wc.points)), np.arange(len(points)), params,
                          correlation, slow_null, (plane, spread))
    if not face.info.planar:
        return None   # a curved face's tests read the point normals and neighbours
    return wc, [face], np.zeros((1, 1), dtype=bool)


def as_planar(wc: WorkingCloud, face: ObjectFace, threshold: float) -> ObjectFace:
    """Return ``face`` re-described as a plane (:func:`~geomodel_ros.core.faces.face_plane`)."""
    info = face.info
    plane, _ = face_plane(wc.points[face.working], wc.normals[face.working], threshold)
    normal = toward_sensor(plane.normal, info.center)
    flat = FaceInfo(True, normal, float(-normal @ info.center), info.size,
                    info.point_normals, info.center)
    s = face.summary
    return ObjectFace(flat, FaceSummary("planar", s.cf, s.point_count, normal), face.working,
                      face.points)
