"""Modeling of segmented objects: faces -> surface types -> model graph -> RANSAC -> size.

:func:`model_objects` takes a scene's points with per-point object labels (from the
segmentation or ground truth) and returns one :class:`~geomodel_ros.core.primitives.Primitive`
per object. Degenerate objects (too few points, fits that fail verification, shapes no
rule of the model graph accepts) come out as ``unknown``; this never raises for bad
geometry, only for malformed arguments. The fitting itself is in
:mod:`geomodel_ros.core.fitting`.
"""

from __future__ import annotations

import copy
import dataclasses
import math
import os
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from functools import partial
from typing import Callable, NamedTuple, TypeVar

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from geomodel_ros.core.band_claim import give_back_band_points
from geomodel_ros.core.confidence import UNKNOWN_CONFIDENCE, with_confidence
from geomodel_ros.core.decimation import decimate, spread_labels
from geomodel_ros.core.errors import InputError, as_points
from geomodel_ros.core.fastmath import centroid, group_by_label, single_threaded_blas, take_rows
from geomodel_ros.core.faces import WorkingCloud
from geomodel_ros.core.fitting.cloud import (SUPPORT_END_FACTOR, ObjectCloud, ObjectFace, Plane,
                                             build_faces, build_flat_face, independent_noise)
from geomodel_ros.core.fitting.slow_bend import SlowBendNull, slow_bend_null
from geomodel_ros.core.fitting.measure import every_kth
from geomodel_ros.core.fitting.levels import object_levels
from geomodel_ros.core.fitting.top_face import solid_below_top
from geomodel_ros.core.fitting.strategies import (Situation, box_of_plane, decide, round_of_plane,
                                                  run_strategies)
from geomodel_ros.core.input import downsample, in_range, working_params
from geomodel_ros.core.noise import (NoiseEstimate, frame_noise, is_fragment, object_params,
                                     support_band)
from geomodel_ros.core.params import ModelingParams
from geomodel_ros.core.primitives import FaceSummary, ModelingResult, Primitive, PrimitiveType
from geomodel_ros.core.resting import resting_objects
from geomodel_ros.core.view import SceneView
from geomodel_ros.core.viewpoint import SensorPose, grid_sensor_pose

__all__ = ["model_objects", "model_object", "model_scene", "estimate_spacing", "InputError"]

#: Fewest points of an object that can be modeled at all, whatever ``min_object_points``
#: says (three determine a plane; a fourth is needed to verify anything).
MIN_MODEL_POINTS = 4
#: An object whose largest singular value (spread) is at most this [m] is one repeated
#: point; one whose second is at most COLLINEAR_RATIO times the first is a line.
MIN_SPREAD = 1e-9
COLLINEAR_RATIO = 1e-6
#: Fewest distinct working points (voxels) an object needs for normals and faces.
MIN_WORKING_POINTS = 6
#: Median point spacing is estimated on a random subset of at most SPACING_SAMPLE points,
#: from the nearest neighbours of SPACING_QUERIES of them.
SPACING_SAMPLE = 2000
SPACING_QUERIES = 500
#: Exact duplicates of a point that :func:`estimate_spacing` looks past to its nearest
#: other position.
SPACING_DUPLICATES = 8
#: An object's range (for its noise-dependent tolerances) is the median over about this
#: many of its points.
OBJECT_RANGE_SAMPLE = 1000
#: A uniform distribution of length L has standard deviation L / sqrt(12).
UNIFORM_SPAN = math.sqrt(12.0)


T = TypeVar("T")
R = TypeVar("R")

_pool_lock = threading.Lock()
_pool: ThreadPoolExecutor | None = None


def _forget_pool() -> None:
    """Drop the worker pool (in a forked child, whose copy has no threads behind it)."""
    global _pool
    _pool = None


if hasattr(os, "register_at_fork"):
    os.register_at_fork(after_in_child=_forget_pool)


def _worker_pool() -> ThreadPoolExecutor:
    """Return the process's modeling worker threads, one per core, started on first use.

    Kept from frame to frame: starting a thread waits until the new thread runs, several
    milliseconds per thread on a loaded machine (measured: 4.5 ms per start at load
    average 5 on 2 cores, two starts per frame).
    """
    global _pool
    with _pool_lock:
        if _pool is None:
            _pool = ThreadPoolExecutor(max_workers=os.cpu_count() or 1,
                                       thread_name_prefix="geomodel-modeling")
        return _pool


class _Setting(NamedTuple):
    """What :func:`model_object` knows of an object's scene besides its points."""

    spacing: float  #: median point spacing [m]
    supports: tuple[Plane, ...]  #: support planes the object may rest on
    view: SceneView | None  #: the scene's returns, sensor at the origin
    correlation: float  #: the frame's ratio of slow to local depth noise (>= 1)
    slow_null: SlowBendNull | None  #: the bends of the frame's slow errors


def _check_labels(labels: NDArray, n: int, what: str) -> NDArray[np.int64]:
    """``labels`` as an (n,) int64 array, or InputError naming ``what``."""
    arr = np.asarray(labels)
    if arr.shape != (n,):
        raise InputError(f"{what} must be an ({n},) integer array aligned with the points, "
                         f"got shape {arr.shape}")
    if not np.issubdtype(arr.dtype, np.integer):
        raise InputError(f"{what} must be integers, got dtype {arr.dtype}")
    return arr.astype(np.int64, copy=False)


def _unknown(oid: int, points: NDArray[np.float64], reason: str,
             faces: tuple[FaceSummary, ...] = ()) -> Primitive:
    """Return an ``unknown`` object at the centroid of its ``points`` (n, 3)."""
    return Primitive(oid, PrimitiveType.UNKNOWN, centroid(points), np.eye(3), {}, len(points),
                     0.0, faces, reason, confidence=UNKNOWN_CONFIDENCE)


def _degenerate(points: NDArray[np.float64], params: ModelingParams) -> str | None:
    """Why ``points`` (n, 3) cannot be modeled at all, or None."""
    n = len(points)
    if n < max(params.min_object_points, MIN_MODEL_POINTS):
        return f"{n} points < min_object_points"
    sub = every_kth(points)
    sv = np.linalg.svd(sub - centroid(sub), compute_uv=False) if np.all(np.isfinite(sub)) \
        else np.zeros(3)
    if sv[0] <= MIN_SPREAD or sv[1] <= COLLINEAR_RATIO * sv[0]:
        return "degenerate point set (collinear or duplicate)"
    return None


def model_object(points: NDArray[np.float64], object_id: int, params: ModelingParams,
                 rng: np.random.Generator, spacing: float,
                 face_labels: NDArray[np.int64] | None = None,
                 supports: tuple[Plane, ...] = (), view: SceneView | None = None,
                 correlation: float = 1.0, slow_null: SlowBendNull | None = None,
                 support: bool = False) -> Primitive:
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
    view : SceneView, optional
        The scene's returns, sensor at the origin: with it, an end hidden from the sensor
        is completed down to the support beyond it (``Primitive.completed``).
    correlation : float, >= 1
        The frame's ratio of slow to local depth noise (``NoiseEstimate.scale``), which the
        surface-type bend test allows for; 1 without an estimate.
    slow_null : SlowBendNull, optional
        The bends the frame's slow errors give flat patches of its support, against which
        the bend test judges faces where ``correlation`` is high.
    support : bool
        Whether the segmentation found the object as a support plane: when its working
        points lie flat they are one face and their normals are not estimated
        (:func:`_as_support_plane`).

    The result's ``confidence`` is measured with ``ransac_threshold`` as the noise scale.
    """
    why = _degenerate(points, params)
    if why:
        return _unknown(object_id, points, why)
    setting = _Setting(spacing, supports, view, correlation, slow_null)
    if support and face_labels is None:
        plane = _as_support_plane(points, object_id, params, rng, setting)
        if plane is not None:
            return plane
    built = build_faces(points, params, face_labels, correlation, slow_null)
    return _fitted(points, object_id, params, rng, built, setting)


def _fitted(points: NDArray[np.float64], object_id: int, params: ModelingParams,
            rng: np.random.Generator,
            built: tuple[WorkingCloud, list[ObjectFace], NDArray[np.bool_]],
            setting: _Setting, alternatives: bool = True) -> Primitive:
    """Fit the object of ``points`` (n, 3) [m] with its ``built`` faces (:func:`build_faces`).

    A plane (with ``noise_model = auto``) carries the judge of its round alternative
    (``Primitive.round_alternative``: :func:`_round_alternative`), which
    :func:`_settle_planes` calls once the segmentation is done; not with ``alternatives``
    False (a support plane's modeling).
    """
    wc, faces, adjacency = built
    if len(wc.points) < MIN_WORKING_POINTS or not faces:
        return _unknown(object_id, points, "too few distinct points after voxelization")
    cloud = ObjectCloud(object_id, points, wc, faces, adjacency, setting.spacing, params, rng,
                        setting.supports, setting.view, setting.correlation, setting.slow_null)
    situation = Situation(cloud, decide(cloud))
    prim, summaries, reasons = run_strategies(situation)
    if prim is None:
        return _unknown(object_id, points, "; ".join(reasons), summaries)
    prim = with_confidence(prim, points, params.ransac_threshold)
    # A strategy may fit a part of the points (a container's wall seen from outside); the
    # object holds all of them.
    prim = dataclasses.replace(prim, faces=summaries, reason="; ".join(reasons),
                               point_count=len(points))
    if prim.type is not PrimitiveType.PLANE:
        prim = dataclasses.replace(prim, levels=object_levels(
            points, cloud.faces, setting.supports, params,
            None if setting.view is None else (setting.view, object_id, setting.spacing)))
    if not alternatives or prim.type is not PrimitiveType.PLANE or \
            params.noise_model != "auto":
        return prim
    # Judged once the segmentation is done, for the planes that remain (:func:`_settle_planes`),
    # from a copy of the object's stream: the plane's own results stay as they are.
    plane_situation = dataclasses.replace(
        situation, cloud=dataclasses.replace(cloud, rng=copy.deepcopy(rng)))
    return dataclasses.replace(prim, round_alternative=partial(
        _round_alternative, plane_situation, prim, list(reasons)))


def _round_alternative(situation: Situation, plane: Primitive, reasons: list[str]
                       ) -> Primitive | None:
    """Return the model that replaces the ``plane`` of ``situation``, or None.

    :func:`~.strategies.round_of_plane`, else the solid a lone top face stands for
    (:func:`~.top_face.solid_below_top`), else the box of a plane folded over two sides
    (:func:`~.strategies.box_of_plane`), with its confidence, faces and ``reasons`` (the
    plane's, then the comparisons or the completion). A top face parallel to its support
    whose space below is hidden is a solid's top: its normals may show a strip of the
    side, whose box would lie across the solid.
    """
    cloud = situation.cloud
    found = round_of_plane(situation, plane, reasons)
    if found is None:
        solid = solid_below_top(cloud, plane, reasons)
        found = (solid, plane.faces) if solid is not None else \
            box_of_plane(situation, plane, reasons)
    if found is None:
        return None
    rnd, faces = found
    rnd = with_confidence(rnd, cloud.points, cloud.params.ransac_threshold)
    return dataclasses.replace(rnd, faces=faces, reason="; ".join(reasons))


def _as_support_plane(points: NDArray[np.float64], object_id: int, params: ModelingParams,
                      rng: np.random.Generator, setting: _Setting) -> Primitive | None:
    """Model a support plane's ``points`` (n, 3) [m] as one flat face, or None.

    The segmentation found these points in the band of one plane: when their working
    points lie flat (:func:`~geomodel_ros.core.fitting.cloud.build_flat_face`) they are
    one planar face (as region growing over estimated normals finds them, unless the
    support lies in pieces) and the model graph's plane is fitted to it. None (the object
    is then modeled as any other, from the state ``rng`` had on entry) when they do not
    lie flat or no verified plane results.
    """
    built = build_flat_face(points, params, setting.correlation, setting.slow_null)
    if built is None:
        return None
    fresh = copy.deepcopy(rng)
    prim = _fitted(points, object_id, params, fresh, built, setting, alternatives=False)
    if prim.type is not PrimitiveType.PLANE:
        return None
    rng.bit_generator.state = fresh.bit_generator.state
    return prim


def estimate_spacing(points: NDArray[np.float64], rng: np.random.Generator,
                     max_points: int = SPACING_SAMPLE, queries: int = SPACING_QUERIES) -> float:
    """Approximate median point spacing [m] of a surface sampled by ``points`` (n, 3).

    Large sets are estimated from a random subset: on a surface the nearest-neighbour
    distance scales with 1 / sqrt(density), so the subset's median is scaled by
    sqrt(subset / n). A point's spacing is the distance to its nearest other position:
    exact duplicates (a cloud merged with itself) are looked through, up to
    SPACING_DUPLICATES of them; 0.0 only when every queried point has more.
    """
    n = len(points)
    if n < 2:
        return 0.0
    sub = points if n <= max_points else points[rng.choice(n, max_points, replace=False)]
    # A tree split at the midpoints without shrunk node boxes, built for one query: the
    # distances found are the same numbers (each is computed from its two points alone,
    # whatever the tree), and the 22 objects of four test frames (osd_learn, scene3) took
    # 12.7 instead of 13.8 ms.
    tree = cKDTree(sub, balanced_tree=False, compact_nodes=False)
    q = sub[: min(len(sub), queries)]
    d, _ = tree.query(q, k=2)
    d = d[:, 1]
    same = np.flatnonzero(d == 0.0)
    if len(same):
        k = min(len(sub), SPACING_DUPLICATES + 2)
        far, _ = tree.query(q[same], k=k)
        other = far[np.arange(len(same)), np.argmax(far > 0.0, axis=1)]
        d[same] = np.where(other > 0.0, other, np.nan)
        d = d[np.isfinite(d)]
        if len(d) == 0:
            return 0.0
    return float(np.median(d) * math.sqrt(len(sub) / n))


def object_range(points: NDArray[np.float64]) -> tuple[float, float]:
    """Range and extent [m] of an object's ``points`` (n, 3), from at most ~1000 of them.

    The range is the median distance from the sensor; the extent is the length across of a
    uniform segment with the spread of the middle principal axis (2 sqrt(3) std).
    """
    sub = every_kth(points, OBJECT_RANGE_SAMPLE)
    if len(sub) < MIN_MODEL_POINTS:
        return 0.0, math.inf
    q = sub - centroid(sub)
    mid = float(np.linalg.eigvalsh(q.T @ q / len(sub))[1])
    return float(np.median(np.sqrt(np.einsum("ij,ij->i", sub, sub)))), \
        UNIFORM_SPAN * math.sqrt(max(mid, 0.0))


def _model_groups(pts: NDArray[np.float64], order: NDArray[np.int64], ids: NDArray[np.int64],
                  bounds: tuple[NDArray[np.int64], NDArray[np.int64]],
                  flab: NDArray[np.int64] | None, params: ModelingParams,
                  rng: np.random.Generator, supports: dict[int, Plane] | None,
                  view: SceneView | None = None,
                  noise: NoiseEstimate | None = None,
                  slow_null: SlowBendNull | None = None) -> list[Primitive]:
    """Model each group ``order[starts[k]:ends[k]]`` as object ``ids[k]``, in parallel.

    With a ``noise`` estimate each object gets its tolerances at its own range
    (:func:`geomodel_ros.core.noise.object_params`).
    """
    starts, ends = bounds
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
        oparams = params if noise is None else object_params(params, noise, *object_range(opts))
        return model_object(opts, oid, oparams, orng, estimate_spacing(opts, orng),
                            None if flab is None else flab[sel], planes, view,
                            1.0 if noise is None else max(noise.scale, 1.0), slow_null,
                            support=oid in (supports or {}))

    workers = min(len(ids), os.cpu_count() or 1)
    if workers <= 1:
        return [one(k) for k in range(len(ids))]
    # The objects are the parallel grain; the callers (model_objects, model_scene) hold
    # BLAS to one thread, whose own threads would only wait for the cores the workers
    # hold (:func:`~geomodel_ros.core.fastmath.single_threaded_blas`).
    # Largest objects first so that the pool stays balanced.
    order_k = np.argsort(-(ends - starts), kind="stable").tolist()
    done = dict(zip(order_k, parallel_map(one, order_k)))
    return [done[k] for k in range(len(ids))]


def parallel_map(fn: Callable[[T], R], items: list[T]) -> list[R]:
    """Return ``[fn(x) for x in items]``, computed on the modeling's worker threads."""
    if len(items) <= 1 or (os.cpu_count() or 1) <= 1:
        return [fn(x) for x in items]
    return list(_worker_pool().map(fn, items))


class PartModeler:
    """Models objects of the scene ``pts`` (N, 3) [m] once more, as :func:`model_scene` does.

    For :mod:`geomodel_ros.core.compounds`: :meth:`context` is the scene's view and slow
    errors as a labelling (N,) divides it (built once per labelling), and a call models
    one object's points with it (its tolerances at its range, the other supports) from the
    random stream ``[params.seed, *key]``.
    """

    def __init__(self, pts: NDArray[np.float64], params: ModelingParams,
                 supports: dict[int, Plane], noise: NoiseEstimate | None) -> None:
        self.pts, self.params, self.supports, self.noise = pts, params, supports, noise
        self.correlation = 1.0 if noise is None else max(noise.scale, 1.0)

    def context(self, labels: NDArray[np.int64]
                ) -> tuple[SceneView | None, SlowBendNull | None]:
        """Return the scene's view and slow-error null as ``labels`` (N,) divide it."""
        return _scene_context(self.pts, labels, self.params, self.supports, self.noise)

    def __call__(self, points: NDArray[np.float64], object_id: int, key: tuple[int, ...],
                 context: tuple[SceneView | None, SlowBendNull | None]) -> Primitive:
        """Model ``points`` (n, 3) [m] as object ``object_id`` in ``context``."""
        params, noise = self.params, self.noise
        oparams = params if noise is None else object_params(params, noise,
                                                             *object_range(points))
        rng = np.random.default_rng([params.seed, *key])
        planes = tuple(v for k, v in self.supports.items() if k != object_id)
        view, null = context
        return model_object(points, object_id, oparams, rng, estimate_spacing(points, rng),
                            None, planes, view, self.correlation, null)

    def faces(self, points: NDArray[np.float64],
              context: tuple[SceneView | None, SlowBendNull | None]) -> list[NDArray[np.int64]]:
        """Return the faces the modeling finds on ``points`` (n, 3) [m], largest first.

        Each as the indices of its points; the faces of :func:`model_object`.
        """
        oparams = self.params if self.noise is None else object_params(
            self.params, self.noise, *object_range(points))
        _, faces, _ = build_faces(points, oparams, None, self.correlation, context[1])
        return sorted((f.points for f in faces), key=len, reverse=True)


def _scene_context(pts: NDArray[np.float64], lab: NDArray[np.int64], params: ModelingParams,
                   supports: dict[int, Plane] | None, noise: NoiseEstimate | None
                   ) -> tuple[SceneView | None, SlowBendNull | None]:
    """Return the scene's view and its slow errors' bend null for modeling its objects.

    Hidden ends are completed only where the sensor sits at the origin (the view, with
    ``supports`` and ``reproject_along_rays``); the bend test's null comes from the frame's
    support where its noise is correlated (:func:`~geomodel_ros.core.fitting.slow_bend.
    slow_bend_null`).
    """
    view = SceneView(pts, lab, params.max_range) if supports and \
        params.reproject_along_rays else None
    null = None if noise is None or independent_noise(params, noise.scale) else \
        slow_bend_null(pts, lab, supports, noise)
    return view, null


def model_objects(points: NDArray, labels: NDArray, params: ModelingParams | None = None, *,
                  face_labels: NDArray | None = None,
                  rng: np.random.Generator | int | None = None,
                  supports: dict[int, Plane] | None = None,
                  noise: NoiseEstimate | None = None) -> ModelingResult:
    """Model every labelled object of a scene.

    Parameters
    ----------
    points : (N, 3) float array [m]
        Scene points; non-finite rows and rows farther than ``params.max_range`` from the
        origin are ignored.
    labels : (N,) int array
        Object id per point; negative = no object.
    params : ModelingParams, optional
    face_labels : (N,) int array, optional
        Known face id per point (faces are then not searched).
    rng : Generator, seed or None
        Randomness for RANSAC; defaults to ``params.seed``.
    supports : dict id -> (normal (3,), d), optional
        Support planes found by the segmentation; other objects may rest on them, and the
        object of each id is modeled as a support (``model_object``'s ``support``).
    noise : NoiseEstimate, optional
        The frame's noise (e.g. ``Segmentation.noise``); with ``noise_model = auto`` and
        none given it is estimated from ``points``.

    Returns
    -------
    ModelingResult with objects ordered by id, timings [s] and the noise estimate.

    Raises
    ------
    InputError
        For malformed arrays, or points too large for the voxel grids within
        ``max_range`` (never for bad geometry).
    """
    t0 = time.perf_counter()
    params = params if params is not None else ModelingParams()
    pts = as_points(points)
    lab = _check_labels(labels, len(pts), "labels")
    flab = None if face_labels is None else _check_labels(face_labels, len(pts), "face_labels")
    rng = np.random.default_rng(params.seed if rng is None else rng)
    idx_all = np.flatnonzero(in_range(pts, params.max_range) & (lab >= 0))
    with single_threaded_blas():
        if params.noise_model == "auto" and noise is None:
            noise = frame_noise(pts, params)
        result = _model_rows(pts, idx_all, lab, flab, params, rng, supports, t0, noise)
        _settle_planes(result, supports or {})
    return result


def _settle_planes(result: ModelingResult, supports: dict[int, Plane]) -> None:
    """Put the model each plane stands for in its place; in place.

    The segmentation's steps (joins of plane pieces, splits) are done with the planes the
    modeling fitted; for each plane left that is no support the alternative is judged
    (``Primitive.round_alternative``: the round model of a plane that lay through a round
    body, :func:`~.strategies.round_of_plane`, else the solid below a lone top face,
    :func:`~.top_face.solid_below_top`, else the box of a plane folded over two sides,
    :func:`~.strategies.box_of_plane`; on the modeling's worker threads) and reported
    when it holds. Every object leaves without the alternative and its levels.
    """
    todo = [o for o in result.objects if o.round_alternative is not None
            and o.type is PrimitiveType.PLANE and o.id not in supports]
    found = dict(zip((o.id for o in todo),
                     parallel_map(lambda o: o.round_alternative(), todo)))
    result.objects = [found[o.id] if found.get(o.id) is not None else
                      o if o.round_alternative is None and not o.levels else
                      dataclasses.replace(o, round_alternative=None, levels=())
                      for o in result.objects]


def _model_rows(pts: NDArray[np.float64], idx_all: NDArray[np.int64], lab: NDArray[np.int64],
                flab: NDArray[np.int64] | None, params: ModelingParams, rng: np.random.Generator,
                supports: dict[int, Plane] | None, t0: float,
                noise: NoiseEstimate | None = None) -> ModelingResult:
    """Model the objects of the rows ``idx_all`` (usable, labelled) of ``pts`` (N, 3) [m].

    The body of :func:`model_objects` after its checks; ``t0`` is its start time [s].
    """
    objects: list[Primitive] = []
    if idx_all.size:
        order, ids, starts, ends = group_by_label(idx_all, lab[idx_all])
        view, null = _scene_context(pts, lab, params, supports, noise)
        objects = _model_groups(pts, order, ids, (starts, ends), flab, params, rng, supports,
                                view, noise, null)
    return ModelingResult(objects, {"modeling_s": time.perf_counter() - t0}, noise=noise)


def model_scene(points: NDArray, params: ModelingParams | None = None, *,
                organized_shape: tuple[int, int] | None = None,
                rng: np.random.Generator | int | None = None,
                sensor: SensorPose | None = None
                ) -> tuple[NDArray[np.int64], ModelingResult]:
    """Segment a raw scene cloud, then model every segment.

    Parameters
    ----------
    points : (N, 3) or (H, W, 3) float array [m]
        Scene cloud in the sensor frame (non-finite rows and rows farther than
        ``params.max_range`` from the origin allowed, labelled -1); an (H, W, 3) array is an
        organized cloud (its rows row-major). With ``params.viewpoint = auto`` an organized
        cloud in another frame is modeled in its camera's frame, recovered from the pixel
        grid (:func:`~geomodel_ros.core.viewpoint.grid_sensor_pose`), and the objects and
        support planes are returned in the cloud's frame (``result.sensor`` says where the
        camera was). With more than
        ``params.max_points`` of the others, the scene is averaged on a voxel grid first
        (:func:`geomodel_ros.core.input.downsample`) and segmented at that voxel; every
        row then gets the label of its voxel, sizes are exact to that voxel, and point
        counts are voxel counts.
    params : ModelingParams, optional
    organized_shape : (H, W), optional
        Image shape when (N, 3) ``points`` are the rows of an organized cloud (N = H * W). With
        ``params.decimation`` d > 1 only every d-th pixel of every d-th row is modeled
        and every pixel gets a sample's label (:mod:`geomodel_ros.core.decimation`);
        an object's point count is then the number of pixels that carry its label.
    rng : Generator, seed or None
    sensor : SensorPose, optional
        Where the sensor is in the cloud's frame, when the caller knows it (a robot's
        transforms: :meth:`~geomodel_ros.core.viewpoint.SensorPose.from_transform`). The
        cloud is modeled in the sensor's optical frame and the results are returned in
        the cloud's frame, as for a camera recovered from the grid, which it replaces;
        for unorganized clouds, which carry no grid, it is the only way.

    Returns
    -------
    labels : (N,) int64
        Object id per input row (-1 = invalid or noise).
    result : ModelingResult
        Objects by id; timing has ``segmentation_s`` and ``modeling_s`` (and
        ``downsample_s`` when the scene was downsampled).

    Raises
    ------
    InputError
        For malformed arrays, or points too large for the voxel grids within ``max_range``.
    """
    params = params if params is not None else ModelingParams()
    if organized_shape is None and np.ndim(points) == 3:
        organized_shape = tuple(np.shape(points)[:2])
    pts = as_points(points, allow_organized=True)
    if organized_shape is not None and organized_shape[0] * organized_shape[1] != len(pts):
        raise InputError(f"organized_shape {organized_shape} does not match {len(pts)} points")
    rng = np.random.default_rng(params.seed if rng is None else rng)
    # OpenBLAS's helper threads spin for tens of ms after every product they share
    # (measured: a (300000, 3) x (3,) product each 50 ms kept a second core busy
    # throughout), which takes half of a 2-core machine from the rest of the frame.
    with single_threaded_blas():
        pose = sensor if sensor is not None else grid_sensor_pose(pts, organized_shape) \
            if organized_shape is not None and params.viewpoint == "auto" else None
        if pose is None:
            return _model_scene(pts, params, rng, organized_shape)
        labels, result = _model_scene(pose.to_sensor(pts), params, rng, organized_shape)
        return labels, pose.result_to_input(result)


def _model_scene(pts: NDArray[np.float64], params: ModelingParams, rng: np.random.Generator,
                 organized_shape: tuple[int, int] | None
                 ) -> tuple[NDArray[np.int64], ModelingResult]:
    """Return :func:`model_scene` of the checked ``pts`` (N, 3) [m] (its body)."""
    if params.decimation > 1 and organized_shape is not None:
        return _model_decimated(pts, params, rng, organized_shape)
    return _model_every_row(pts, params, rng, organized_shape)


def _model_every_row(pts: NDArray[np.float64], params: ModelingParams,
                     rng: np.random.Generator, organized_shape: tuple[int, int] | None
                     ) -> tuple[NDArray[np.int64], ModelingResult]:
    """Return :func:`model_scene` of ``pts`` (N, 3) [m] without decimation."""
    t0 = time.perf_counter()
    noise = frame_noise(pts, params) if params.noise_model == "auto" else None
    t_noise = time.perf_counter() - t0
    if len(pts) <= params.max_points:
        return _segment_and_model(pts, params, rng, noise, t_noise, organized_shape)
    usable = in_range(pts, params.max_range)
    if np.count_nonzero(usable) <= params.max_points:
        return _segment_and_model(pts, params, rng, noise, t_noise, organized_shape)
    t0 = time.perf_counter()
    ds = downsample(pts, np.flatnonzero(usable), params)
    del usable
    t_down = time.perf_counter() - t0
    wlabels, result = _segment_and_model(ds.points, working_params(params, ds.voxel_size), rng,
                                         noise, t_noise)
    labels = np.full(len(pts), -1, dtype=np.int64)
    labels[ds.rows] = wlabels[ds.inverse]
    result.timing["downsample_s"] = t_down
    result.timing["total_s"] += t_down
    return labels, result


def _model_decimated(pts: NDArray[np.float64], params: ModelingParams,
                     rng: np.random.Generator, shape: tuple[int, int]
                     ) -> tuple[NDArray[np.int64], ModelingResult]:
    """Model the samples of an organized cloud (``decimation``), then label every pixel."""
    t0 = time.perf_counter()
    dec = decimate(pts, shape, params.decimation)
    t_dec = time.perf_counter() - t0
    sample_labels, result = _model_every_row(dec.points, params, rng, dec.shape)
    t0 = time.perf_counter()
    labels = spread_labels(pts, shape, dec, sample_labels, params.seg_voxel_size,
                           params.seg_max_edge_factor)
    # Each object counts the pixels that carry its label (each of its samples among them).
    counts = np.bincount(labels[labels >= 0], minlength=max((o.id for o in result.objects),
                                                            default=-1) + 1)
    result.objects = [dataclasses.replace(o, point_count=int(counts[o.id]))
                      for o in result.objects]
    result.timing["decimation_s"] = t_dec + time.perf_counter() - t0
    result.timing["total_s"] += result.timing["decimation_s"]
    return labels, result


def _segment_and_model(pts: NDArray[np.float64], params: ModelingParams,
                       rng: np.random.Generator, noise: NoiseEstimate | None, t_noise: float,
                       organized_shape: tuple[int, int] | None = None
                       ) -> tuple[NDArray[np.int64], ModelingResult]:
    """Segment ``pts`` (N, 3) [m] and model every segment (the body of :func:`model_scene`).

    ``noise`` is the frame's estimate (None with ``noise_model = fixed``), which took
    ``t_noise`` [s]. Once the objects are modeled, the support points whose viewing rays
    enter an object's solid are given to it
    (:func:`~geomodel_ros.core.band_claim.give_back_band_points`: its lower part in the
    support's band); fragments are taken out of the objects (:func:`_drop_fragments`).
    ``organized_shape`` (H, W) is handed to the segmentation.
    """
    from geomodel_ros.core.compounds import join_pieces, split_compounds
    from geomodel_ros.core.segmentation import segment_scene

    seg = segment_scene(pts, params, rng=rng, noise=noise, organized_shape=organized_shape)
    # The segmentation labels only finite rows within max_range: no further checks.
    t0 = time.perf_counter()
    result = _model_rows(pts, np.flatnonzero(seg.labels >= 0), seg.labels, None, params, rng,
                         seg.support_planes, t0, noise)
    model = PartModeler(pts, params, seg.support_planes, noise)
    labels = join_pieces(pts, seg.labels, result, params, seg.support_planes, noise, model)
    split: set[int] = set()  # the parts of the segments split (a box's face among them)
    labels = split_compounds(pts, labels, result, params, seg.support_planes, noise, model,
                             split)
    if split:
        labels = join_pieces(pts, labels, result, params, seg.support_planes, noise, model,
                             among=split)
    _settle_planes(result, seg.support_planes)
    labels = give_back_band_points(pts, labels, result, seg.support_planes, params, noise)
    result.timing["modeling_s"] = time.perf_counter() - t0
    labels = _drop_fragments(labels, result, params)
    result.timing.update(seg.timing)
    result.timing["noise_s"] = t_noise
    result.timing["total_s"] = result.timing["modeling_s"] + seg.timing["segmentation_s"] \
        + t_noise
    result.supports = dict(seg.support_planes)
    result.supported = resting_objects(result.objects, result.supports,
                                       partial(_contact_tolerance, params=params, noise=noise))
    return labels, result


def _contact_tolerance(o: Primitive, params: ModelingParams, noise: NoiseEstimate | None
                       ) -> float:
    """Contact tolerance [m] of object ``o`` with a support: SUPPORT_END_FACTOR support bands.

    The band is ``seg_plane_threshold``, or with a noise estimate at least the support band
    the estimate sets (:func:`geomodel_ros.core.noise.support_band`) at the object's range.
    """
    band = params.seg_plane_threshold
    if noise is not None:
        band = max(band, support_band(noise, float(np.linalg.norm(o.center))))
    return SUPPORT_END_FACTOR * band


def _drop_fragments(labels: NDArray[np.int64], result: ModelingResult,
                    params: ModelingParams) -> NDArray[np.int64]:
    """Take the fragments (:func:`geomodel_ros.core.noise.is_fragment`) out of ``result``.

    Their points get label -1 (noise) in the returned copy of ``labels`` (N,) when there is
    one; ``result.fragments`` counts them. Supports are never fragments.
    """
    cut = [o for o in result.objects if o.type == PrimitiveType.UNKNOWN
           and o.id not in result.supports and
           is_fragment(o.point_count, float(np.linalg.norm(o.center)), result.noise,
                       params)]
    if not cut:
        return labels
    gone = np.array([o.id for o in cut], dtype=np.int64)
    result.objects = [o for o in result.objects if o.id not in set(gone.tolist())]
    result.fragments = len(cut)
    labels = labels.copy()
    labels[np.isin(labels, gone)] = -1
    return labels
