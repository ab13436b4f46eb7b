"""Object ids that stay stable across frames: a small multi-object tracker.

Every frame's primitives are matched to the tracks of the previous frames with one globally
optimal assignment (:func:`scipy.optimize.linear_sum_assignment`), so that an object keeps its
id while it persists. The rules:

* **Cost of a pair** (track, new object) of the same type: the mean of the four squared
  normalised errors (the plane terms are 0 for other types)

  - centre distance / (``center_gate_scale`` * size + ``center_gate_abs``), where size is the
    larger characteristic size (diagonal of the extents) of the two;
  - largest relative extent difference ``|log(e_new / e_track)|`` / ``log(size_ratio_gate)``
    (cuboid and plane extents sorted first, so that a permutation of the axes is no change);
  - planes also: normal angle / ``plane_angle_gate`` and offset of the new centre from the
    track's plane / ``plane_offset_gate`` (a wall or desk is known by its plane first).

  A pair is feasible (gated) only when every normalised error is at most 1.
* **Type changes** (a cuboid seen as ``unknown`` for a frame, a cylinder as a cone): a pair
  of different types is feasible only when centre and characteristic size agree within
  ``type_change_fraction`` of their gates (sizes are skipped for ``unknown``, which has none).
  Its cost is always above every same-type cost, so a same-type match wins when there is one.
  The track keeps its id and takes the new type; it remembers its last known size, so an
  ``unknown`` flicker does not loosen the size check of the next frames.
* **Unmatched** new objects get fresh ids (monotonic, never reused). A track not matched for
  more than ``max_missed`` consecutive frames is retired and its id reported as deleted in
  that frame's :class:`TrackingResult` (so that its marker can be deleted).
* **Smoothing** (``smoothing`` > 0). The axes of every same-type match are first expressed
  in the symmetry-equivalent form closest to the track's (any proper signed permutation for
  cuboids, dimensions permuted alike; x, y -> -x, -y for planes; y, z -> -y, -z for
  cylinders), so a cuboid's pose does not jump by 90 degrees between frames. When the object
  moved less than ``static_motion`` from the track's estimate, centre and dimensions become
  the exponential moving average ``s = a * s_prev + (1 - a) * x`` with ``a = smoothing``
  (the std of stationary noise shrinks by ``sqrt((1 - a) / (1 + a))``), and the rotation the
  same average on SO(3) when it is within ``rotation_gate`` of the track's (else the aligned
  new rotation). Objects that move more are passed through (no lag); a slow drift of ``v``
  per frame lags by ``a * v / (1 - a)`` as long as that stays below ``static_motion``.
  Without smoothing the geometry is passed through unchanged; only the id is replaced.

Matching works on plain type strings (``str`` enums compare and convert alike).
"""

from __future__ import annotations

import dataclasses
import itertools
import math
import timeit
from dataclasses import dataclass, field
from typing import Sequence

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import linear_sum_assignment

from geomodel_ros.core.errors import InputError
from geomodel_ros.core.geometry import EPS
from geomodel_ros.core.params import ParamSpec
from geomodel_ros.core.primitives import Primitive

__all__ = ["TRACKER_PARAMETERS", "TrackerConfig", "TrackingResult", "Tracker",
           "measure_update_cost"]

#: Tracker parameters: one definition (name, default, unit, range, meaning) that
#: :class:`TrackerConfig` validates with and a node can declare its parameters from.
TRACKER_PARAMETERS: tuple[ParamSpec, ...] = (
    # 5 frames = 0.5 s at 10 Hz: rides out a brief occlusion or a failed fit without leaving
    # a stale object behind for long.
    ParamSpec("max_missed", 5, "count", 0, 100000,
              "Consecutive frames a track may go unmatched before its id is retired."),
    # A fit's centre shifts by up to about half the object's size when a face drops out of
    # view or is occluded.
    ParamSpec("center_gate_scale", 0.5, "1", 0.0, 100.0,
              "Centre gate as a fraction of the object's size (diagonal of its extents)."),
    # Centre noise of fits at Kinect range (~5 mm) plus motion of a few cm per frame.
    ParamSpec("center_gate_abs", 0.03, "m", 0.0, 100.0,
              "Absolute term of the centre gate (sensor noise and motion per frame)."),
    # Extents of one object vary by well under 50 % between frames (partial views); a
    # different object of the same type next to it usually differs by more.
    ParamSpec("size_ratio_gate", 1.5, "1", 1.01, 1000.0,
              "Largest ratio (larger / smaller) of an extent between a track and its match."),
    # Plane normals of walls and desks are stable to a few degrees.
    ParamSpec("plane_angle_gate", 0.26, "rad", 0.001, 1.5708,
              "Largest angle between the normals of a plane track and its match."),
    # Offset noise of a fitted plane is a few mm; 3 cm also tolerates a slightly moved desk.
    ParamSpec("plane_offset_gate", 0.03, "m", 1e-6, 100.0,
              "Largest distance of a matched plane's centre from the track's plane."),
    # A type flicker (cuboid <-> unknown) keeps the object where it was: a quarter of the
    # gates is tight enough not to hand an id to a different neighbouring object.
    ParamSpec("type_change_fraction", 0.25, "1", 0.0, 1.0,
              "Fraction of the centre and size gates within which an object may match a "
              "track of another type (0: never)."),
    ParamSpec("smoothing", 0.0, "1", 0.0, 0.99,
              "Weight of the previous estimate in the moving average of static objects' "
              "centre, dimensions and rotation (0: off)."),
    # About 3 x the centre noise of a fit: below it the change is noise, above it motion.
    ParamSpec("static_motion", 0.01, "m", 0.0, 100.0,
              "Centre displacement per frame below which an object counts as static."),
    # Axis noise of fitted cuboids and cylinders is a few degrees.
    ParamSpec("rotation_gate", 0.17, "rad", 0.0, 3.0,
              "Largest rotation between track and new axes that is averaged when smoothing."),
)

_SPECS = {s.name: s for s in TRACKER_PARAMETERS}

#: Extents are floored at 1 mm (below the sensor's resolution) before their log ratio.
SIZE_FLOOR = 1e-3
#: Cost of leaving a track or a new object unmatched [1]: any feasible pair (cost < 2) is
#: preferred to leaving both of its members unmatched.
UNMATCHED_COST = 1.0
#: Cost of an infeasible pair; larger than any sum of feasible and unmatched costs.
INFEASIBLE_COST = 1e9
#: Cross-type pairs cost ``CROSS_TYPE_BASE + ...`` in [1, 1.5]: above every same-type cost
#: ([0, 1]), below two unmatched costs.
CROSS_TYPE_BASE = 1.0


def _proper_signed_permutations() -> NDArray[np.float64]:
    mats = []
    for perm in itertools.permutations(range(3)):
        for signs in itertools.product((1.0, -1.0), repeat=3):
            m = np.zeros((3, 3))
            m[list(perm), [0, 1, 2]] = signs
            if np.linalg.det(m) > 0:
                mats.append(m)
    return np.array(mats)


#: Rotations ``S`` (K, 3, 3) with ``R @ S`` describing the same object as ``R``, per type.
_SYMMETRIES: dict[str, NDArray[np.float64]] = {
    "cuboid": _proper_signed_permutations(),
    "plane": np.array([np.eye(3), np.diag([-1.0, -1.0, 1.0])]),
    "cylinder": np.array([np.eye(3), np.diag([1.0, -1.0, -1.0])]),
    "cone": np.array([np.eye(3)]),
}
#: Most extents per object compared (a frustum has radius, top radius and height).
MAX_EXTENTS = 4
#: Types whose extents are compared sorted (their axis order carries no meaning).
_SORTED_EXTENTS = ("cuboid", "plane")


def _field(name: str):
    return field(default=_SPECS[name].default)


@dataclass(frozen=True)
class TrackerConfig:
    """Frozen tracker parameters; see :data:`TRACKER_PARAMETERS` for units and ranges.

    Out-of-range or mistyped values raise
    :class:`~geomodel_ros.core.params.ParameterError`.
    """

    max_missed: int = _field("max_missed")
    center_gate_scale: float = _field("center_gate_scale")
    center_gate_abs: float = _field("center_gate_abs")
    size_ratio_gate: float = _field("size_ratio_gate")
    plane_angle_gate: float = _field("plane_angle_gate")
    plane_offset_gate: float = _field("plane_offset_gate")
    type_change_fraction: float = _field("type_change_fraction")
    smoothing: float = _field("smoothing")
    static_motion: float = _field("static_motion")
    rotation_gate: float = _field("rotation_gate")

    def __post_init__(self) -> None:
        for spec in TRACKER_PARAMETERS:
            object.__setattr__(self, spec.name, spec.check(getattr(self, spec.name)))


@dataclass(frozen=True)
class TrackingResult:
    """One frame's tracking output.

    Attributes
    ----------
    objects : list[Primitive]
        The frame's primitives in input order, each with its stable track id (and, with
        smoothing, its smoothed centre, rotation and dimensions).
    deleted_ids : tuple[int, ...]
        Ids retired in this frame (ascending); they are never given out again.
    new_ids : tuple[int, ...]
        Ids created in this frame (ascending).
    """

    objects: list[Primitive]
    deleted_ids: tuple[int, ...] = ()
    new_ids: tuple[int, ...] = ()


@dataclass
class _Track:
    id: int
    type: str
    center: NDArray[np.float64]
    rotation: NDArray[np.float64]
    dims: dict[str, float]
    extents: NDArray[np.float64] | None
    missed: int = 0


def _type_name(t: object) -> str:
    """Plain type string of a ``str`` or a (``str``-valued) enum member."""
    return str(getattr(t, "value", t))


def _extents(type_name: str, dimensions: dict[str, float]) -> NDArray[np.float64] | None:
    """Comparison extents [m] of an object (radii as diameters), ``None`` without sizes."""
    if not dimensions:
        return None
    ext = np.array([2.0 * v if "radius" in k else v for k, v in dimensions.items()], float)
    ext = np.maximum(ext, SIZE_FLOOR)
    return np.sort(ext) if type_name in _SORTED_EXTENTS else ext


def _stack(items: list[tuple[str, NDArray, NDArray, NDArray | None]]
           ) -> tuple[NDArray, NDArray, NDArray, NDArray, NDArray, NDArray]:
    """Types (n,), centres (n, 3), z axes (n, 3), log-extents (n, W), sizes (n,), counts (n,).

    Log-extents are zero-padded to ``W`` = :data:`MAX_EXTENTS`; sizes (diagonal of the
    extents [m]) and extent counts are 0 for objects without dimensions.
    """
    n = len(items)
    log_ext = np.zeros((n, MAX_EXTENTS))
    sizes = np.zeros(n)
    counts = np.zeros(n, dtype=np.int64)
    for i, (_, _, _, e) in enumerate(items):
        if e is not None:
            counts[i] = len(e)
            log_ext[i, :min(len(e), MAX_EXTENTS)] = np.log(e[:MAX_EXTENTS])
            sizes[i] = math.hypot(*e)
    types = np.array([t for t, *_ in items], dtype=object)
    centers = np.array([c for _, c, _, _ in items], float).reshape(n, 3)
    normals = np.array([r[:, 2] for _, _, r, _ in items], float).reshape(n, 3)
    return types, centers, normals, log_ext, sizes, counts


def _pair_costs(tracks: list[_Track], dets: list[tuple[str, NDArray, NDArray, NDArray | None]],
                cfg: TrackerConfig) -> NDArray[np.float64]:
    """Return the assignment cost (T, D) of every (track, object) pair (infeasible > 2)."""
    tt, tc, tn, tl, ts, tk = _stack([(t.type, t.center, t.rotation, t.extents) for t in tracks])
    dt, dc, dn, dl, ds, dk = _stack(dets)
    same = tt[:, None] == dt[None, :]
    delta = dc[None, :, :] - tc[:, None, :]
    gate = cfg.center_gate_scale * np.maximum(ts[:, None], ds[None, :]) + cfg.center_gate_abs
    e_center = np.linalg.norm(delta, axis=2) / np.maximum(gate, np.finfo(float).tiny)
    both_sized = (ts[:, None] > 0) & (ds[None, :] > 0)
    log_gate = math.log(cfg.size_ratio_gate)
    e_ext = np.abs(dl[None, :, :] - tl[:, None, :]).max(axis=2) / log_gate
    e_ext = np.where(both_sized & (tk[:, None] == dk[None, :]), e_ext, 0.0)
    plane = (tt[:, None] == "plane") & (dt[None, :] == "plane")
    cos = np.clip(np.abs(tn @ dn.T), 0.0, 1.0)
    e_angle = np.where(plane, np.arccos(cos) / cfg.plane_angle_gate, 0.0)
    e_offset = np.where(plane, np.abs(np.einsum("tk,tdk->td", tn, delta)) / cfg.plane_offset_gate,
                        0.0)
    terms = np.stack([e_center, e_ext, e_angle, e_offset])
    cost = np.where(same & (terms.max(axis=0) <= 1.0), (terms ** 2).mean(axis=0), INFEASIBLE_COST)
    frac = cfg.type_change_fraction
    if frac > 0:
        e_size = np.where(both_sized, np.abs(np.log(np.maximum(ds[None, :], SIZE_FLOOR))
                                             - np.log(np.maximum(ts[:, None], SIZE_FLOOR))), 0.0)
        e_size /= log_gate
        ok = ~same & (e_center <= frac) & (e_size <= frac)
        cross = CROSS_TYPE_BASE + ((e_center / frac) ** 2 + (e_size / frac) ** 2) / 4.0
        cost = np.where(ok, cross, cost)
    return cost


def _assign(cost: NDArray[np.float64]) -> list[tuple[int, int]]:
    """Optimal (track, object) pairs for ``cost`` (T, D), each side free to stay unmatched."""
    n_t, n_d = cost.shape
    big = np.full((n_t + n_d, n_t + n_d), INFEASIBLE_COST)
    big[:n_t, :n_d] = cost
    big[:n_t, n_d:][np.diag_indices(n_t)] = UNMATCHED_COST
    big[n_t:, :n_d][np.diag_indices(n_d)] = UNMATCHED_COST
    big[n_t:, n_d:] = 0.0
    rows, cols = linear_sum_assignment(big)
    return [(int(r), int(c)) for r, c in zip(rows, cols)
            if r < n_t and c < n_d and cost[r, c] < INFEASIBLE_COST]


def _align(type_name: str, track_rot: NDArray[np.float64], rot: NDArray[np.float64],
           dims: dict[str, float]) -> tuple[NDArray[np.float64], dict[str, float]]:
    """``rot`` (3, 3) and ``dims`` [m] in the symmetry-equivalent form closest to ``track_rot``.

    Cuboid dimensions are permuted with the axes (``length``, ``width``, ``height`` stay
    the extents along the x, y, z columns).
    """
    sym = _SYMMETRIES.get(type_name)
    if sym is None or len(sym) == 1:
        return rot, dims
    # trace(R_t^T R S) is 1 + 2 cos(angle) of the remaining rotation: largest = closest.
    best = sym[int(np.argmax(np.einsum("ij,ik,skj->s", track_rot, rot, sym)))]
    if type_name == "cuboid":
        keys = list(dims)
        values = np.abs(best).T @ np.array([dims[k] for k in keys])
        dims = {k: float(v) for k, v in zip(keys, values)}
    return rot @ best, dims


def _blend_rotation(track_rot: NDArray[np.float64], rot: NDArray[np.float64], weight: float,
                    gate: float) -> NDArray[np.float64]:
    """Rotation (3, 3) a fraction ``1 - weight`` of the way from ``track_rot`` to ``rot``.

    The geodesic on SO(3): ``track_rot @ exp((1 - weight) * log(track_rot.T @ rot))``.
    Returns ``rot`` when the two differ by more than ``gate`` [rad] (< pi).
    """
    q = track_rot.T @ rot
    # Axis-angle of q: w = sin(angle) * axis, cos(angle) = (trace - 1) / 2.
    w = 0.5 * np.array([q[2, 1] - q[1, 2], q[0, 2] - q[2, 0], q[1, 0] - q[0, 1]])
    sin_a = math.hypot(*w)
    angle = math.atan2(sin_a, 0.5 * (float(np.trace(q)) - 1.0))
    if angle > gate:
        return rot
    if sin_a < EPS:
        return track_rot.copy()
    k = w / sin_a
    kx = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    phi = (1.0 - weight) * angle
    # Rodrigues: exp(phi [k]x) = I + sin(phi) [k]x + (1 - cos(phi)) [k]x^2.
    return track_rot @ (np.eye(3) + math.sin(phi) * kx + (1.0 - math.cos(phi)) * (kx @ kx))


def _check(dets: list[tuple[str, NDArray, NDArray, NDArray | None]]) -> None:
    """Raise :class:`InputError` unless every centre is finite (3,) and rotation (3, 3)."""
    for i, (_, center, rot, ext) in enumerate(dets):
        if center.shape != (3,) or rot.shape != (3, 3):
            raise InputError(f"primitive {i}: center must have shape (3,) and rotation (3, 3), "
                             f"got {center.shape} and {rot.shape}")
        if not (np.isfinite(center).all() and np.isfinite(rot).all()
                and (ext is None or np.isfinite(ext).all())):
            raise InputError(f"primitive {i}: center, rotation and dimensions must be finite")


class Tracker:
    """Keeps object ids stable across frames (see the module docstring for the rules).

    Parameters
    ----------
    config : TrackerConfig, optional
        Gates, retirement and smoothing; defaults when omitted.

    Examples
    --------
    >>> tracker = Tracker(TrackerConfig(max_missed=3))
    >>> result = tracker.update(primitives)            # doctest: +SKIP
    >>> [o.id for o in result.objects], result.deleted_ids  # doctest: +SKIP
    """

    def __init__(self, config: TrackerConfig | None = None) -> None:
        self.config = config if config is not None else TrackerConfig()
        self._tracks: dict[int, _Track] = {}
        self._next_id = 0

    @property
    def active_ids(self) -> tuple[int, ...]:
        """Ids of the live tracks (matched recently enough not to be retired), ascending."""
        return tuple(sorted(self._tracks))

    def reset(self) -> tuple[int, ...]:
        """Retire every track; return their ids. New ids continue after the old ones."""
        ids = self.active_ids
        self._tracks.clear()
        return ids

    def update(self, primitives: Sequence[Primitive]) -> TrackingResult:
        """Match one frame's primitives to the tracks and give each its stable id.

        Parameters
        ----------
        primitives : sequence of Primitive
            The frame's objects (their own ``id`` is ignored); centres in one fixed frame
            [m] for every call.

        Returns
        -------
        TrackingResult
            The primitives with track ids in input order, the ids retired and created.

        Raises
        ------
        InputError
            A centre, rotation or dimension is not finite or has the wrong shape (the
            tracker's state is left unchanged).
        """
        dets = [(_type_name(p.type), np.asarray(p.center, float), np.asarray(p.rotation, float),
                 _extents(_type_name(p.type), p.dimensions)) for p in primitives]
        _check(dets)
        tracks = list(self._tracks.values())
        pairs = _assign(_pair_costs(tracks, dets, self.config)) if tracks and dets else []
        out: list[Primitive | None] = [None] * len(dets)
        for ti, di in pairs:
            out[di] = self._follow(tracks[ti], primitives[di], dets[di][0])
        deleted = self._age({tracks[ti].id for ti, _ in pairs})  # before new tracks start
        new_ids = []
        for di in (i for i, o in enumerate(out) if o is None):
            out[di] = self._start(primitives[di], dets[di])
            new_ids.append(out[di].id)
        return TrackingResult(out, deleted, tuple(new_ids))

    def _start(self, prim: Primitive, det: tuple[str, NDArray, NDArray, NDArray | None]
               ) -> Primitive:
        tid = self._next_id
        self._next_id += 1
        self._tracks[tid] = _Track(tid, det[0], det[1].copy(), det[2].copy(),
                                   dict(prim.dimensions), det[3])
        return dataclasses.replace(prim, id=tid)

    def _age(self, matched: set[int]) -> tuple[int, ...]:
        """Count a miss for every unmatched track; retire and return those over the limit."""
        gone = []
        for tid, track in self._tracks.items():
            if tid not in matched:
                track.missed += 1
                if track.missed > self.config.max_missed:
                    gone.append(tid)
        for tid in gone:
            del self._tracks[tid]
        return tuple(sorted(gone))

    def _follow(self, track: _Track, prim: Primitive, type_name: str) -> Primitive:
        """Update ``track`` with its match ``prim``; return ``prim`` with the track's id."""
        cfg = self.config
        center = np.asarray(prim.center, float)
        rot = np.asarray(prim.rotation, float)
        dims = dict(prim.dimensions)
        if cfg.smoothing > 0 and type_name == track.type:
            rot, dims = _align(type_name, track.rotation, rot, dims)
            if math.dist(center, track.center) < cfg.static_motion:
                a = cfg.smoothing
                center = a * track.center + (1.0 - a) * center
                rot = _blend_rotation(track.rotation, rot, a, cfg.rotation_gate)
                old = track.dims
                dims = {k: a * old[k] + (1.0 - a) * v if k in old else v for k, v in dims.items()}
        ext = _extents(type_name, dims)
        track.type, track.center, track.rotation, track.missed = type_name, center, rot, 0
        track.extents = ext if ext is not None else track.extents
        track.dims = dims
        return dataclasses.replace(prim, id=track.id, center=center, rotation=rot,
                                   dimensions=dims)


def measure_update_cost(n_objects: int = 16, frames: int = 1000, smoothing: float = 0.7,
                        seed: int = 0) -> float:
    """Median wall time [s] of one :meth:`Tracker.update` on a static noisy scene.

    ``n_objects`` cuboids, cylinders and planes (1 mm Gaussian noise on centres and sizes)
    are tracked over ``frames`` frames; the first frame (which creates the tracks) is not
    counted.
    """
    rng = np.random.default_rng(seed)
    kinds = [("cuboid", {"length": 0.1, "width": 0.06, "height": 0.04}),
             ("cylinder", {"radius": 0.03, "height": 0.12}),
             ("plane", {"length": 0.8, "width": 0.5})]
    base = [(kinds[i % 3], rng.uniform(-1.0, 1.0, 3) + [0.0, 0.0, 2.0]) for i in range(n_objects)]

    def frame() -> list[Primitive]:
        return [Primitive(i, t, c + rng.normal(0, 1e-3, 3), np.eye(3),
                          {k: v + float(rng.normal(0, 1e-3)) for k, v in d.items()}, 1000, 1e-3)
                for i, ((t, d), c) in enumerate(base)]

    tracker = Tracker(TrackerConfig(smoothing=smoothing))
    tracker.update(frame())
    scenes = [frame() for _ in range(frames)]
    it = iter(scenes)
    times = timeit.repeat(lambda: tracker.update(next(it)), repeat=frames, number=1)
    return float(np.median(times))


if __name__ == "__main__":
    print(f"Tracker.update, 16 objects: median {measure_update_cost() * 1e3:.3f} ms per frame")
