"""The basic geometric model graph (paper section 3.2.1, Figure 3).

From the surface types of an object's faces and the relations of their normals it
proposes the object's type, as an ordered list of candidates that RANSAC then verifies:

* only planar faces: the largest face is the main matching surface. A perpendicular
  adjacent face -> cuboid (every face must then align with one of three orthogonal
  axes); all faces parallel and coplanar -> one plane (desk, wall, floor).
* planar + curved faces: the largest plane is the auxiliary matching surface. Curved
  normals perpendicular to its normal -> cylinder; at a constant other angle -> cone,
  or frustum (truncated cone: cup, bowl, flower pot) when the fitted cone's apex lies
  beyond the object.
* only curved faces: principal curvatures k1 (largest magnitude) and k2: k2 ~ 0 with k1
  constant -> cylinder, k2 ~ 0 with k1 varying -> cone or frustum, k1 ~ k2 -> sphere.
  The ratio of their medians is judged with its own uncertainty where the points' blocks
  are known: a ratio between the two bounds whose interval reaches a bound gets that
  bound's candidates (:func:`curvature_candidates`).

Cone and frustum share one surface (normals at a constant non-right angle to the axis,
k1 varying along it); which of the two an object is depends on where the fitted cone's
apex lies, which only the fit knows: the graph proposes both, the cone first. The cone
unit rejects a cone whose points stop short of its apex (``verify.CONE_APEX_REACH``),
the frustum unit one whose points reach near it (``fitting.frustum.FRUSTUM_MIN_TOP_RATIO``,
the same share), so exactly one of them accepts a truncated cone. Open cups and bowls
(no cap, the inner wall seen through the opening) are all-curved objects: the same
candidates through their curvatures. Where the surface looks conical (normals at a
constant angle, k1 varying) the frustum comes before the cylinder, which would fit a
tapered side only loosely (a bowl as a cylinder of its mean radius); where it looks
cylindrical (normals perpendicular to the plane, k1 constant) it comes last -- unless the
side's normals, though within the tolerance of the perpendicular (which under correlated
sensor noise holds a frustum's half-angle), all lean to one side of it by at least the
least half-angle a cone or frustum may have (:func:`side_tilt`, ``frustum_tilt``): then the
frustum comes first and its unit's taper test tells the two apart.

An object no rule accepts gets no candidate and becomes ``unknown``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray
from scipy import stats

from geomodel_ros.core.fitting.paired_cost import LOWER_LEVEL, MIN_BLOCKS
from geomodel_ros.core.params import ModelingParams

__all__ = ["FaceInfo", "GraphDecision", "BoxCorner", "box_corner", "curvature_candidates",
           "cuboid_decision", "decide_type", "side_tilt", "ratio_halfwidth", "NO_CURVATURE",
           "BETWEEN_BOUNDS", "NOT_ALIGNED"]


@dataclass(frozen=True)
class FaceInfo:
    """What the model graph needs to know about a face.

    Attributes
    ----------
    planar : bool
    normal : (3,) float64, unit (plane normal for planar faces, mean normal otherwise)
    offset : float [m], plane offset d of n . x + d = 0 (planar faces)
    size : int, working points on the face (a proxy for its visible area)
    point_normals : (m, 3) float64, normals of the face's working points
    center : (3,) float64 [m], centroid of the face
    """

    planar: bool
    normal: NDArray[np.float64]
    offset: float
    size: int
    point_normals: NDArray[np.float64] = field(repr=False)
    center: NDArray[np.float64] | None = None


@dataclass(frozen=True)
class GraphDecision:
    """Outcome of the model graph for one object.

    Attributes
    ----------
    category : str
        ``planar``, ``mixed`` or ``curved`` (or ``empty``).
    candidates : tuple[str, ...]
        Types to verify, most likely first; empty -> ``unknown``.
    main_face : int
        Index of the main (or auxiliary) matching surface, -1 if none.
    axis_of_face : tuple[int, ...]
        For cuboids: which of the three axes each face's normal belongs to (-1: a sliver
        that fits none and is ignored).
    reason : str
    between_bounds : bool
        All-curved objects: the curvature ratio lay between the developable and the
        spherical bound (any candidates come from its uncertainty, not from the ratio).
    concave_corner : bool
        Planar faces on different box axes meet in a concave corner (:func:`_concave_corner`):
        the cuboid candidate is for its rivals only (a round model of all faces may replace
        it, as for any cuboid); as the outcome it is refused (seen from inside: no box).
    """

    category: str
    candidates: tuple[str, ...]
    main_face: int
    axis_of_face: tuple[int, ...] = ()
    reason: str = ""
    between_bounds: bool = False
    concave_corner: bool = False


#: Faces smaller than this share of an object's working points that fit no relation are
#: slivers (contact rims, noise) and do not veto the object's type.
SLIVER_SHARE = 0.05
#: A planar face at an angle to the auxiliary plane of a planar + curved object vetoes
#: the cylinder/cone rules only above this share of the object's working points; smaller
#: ones are taken as flat-looking slivers of the curved surface. Twice
#: :data:`SLIVER_SHARE`, the value the method's results were obtained with.
MIXED_VETO_SHARE = 2 * SLIVER_SHARE
#: Curved normals at a constant angle to the plane (a cone with its base): their
#: interquartile spread is at most this many angle tolerances (+- one tolerance about
#: the median).
CONE_ANGLE_SPREAD = 2
#: Part of the reason of a planar decision whose faces meet in a concave corner.
CONCAVE_CORNER = " meeting in a concave corner"
#: Reason of a planar decision whose faces meet at right angles in a corner but not all
#: lie within the angle tolerance of the corner's three axes.
NOT_ALIGNED = "planar faces not aligned with three orthogonal axes"
#: Reason of :func:`curvature_candidates` when no point has a curvature to judge.
NO_CURVATURE = "no curvature"
#: Part of the reason of :func:`curvature_candidates` when the ratio lay between the bounds
#: and its interval proposed the candidates (``GraphDecision.between_bounds``).
BETWEEN_BOUNDS = "between the bounds"


@dataclass(frozen=True)
class BoxCorner:
    """The box axes a corner of planar faces proposes (:func:`box_corner`).

    Attributes
    ----------
    main : int, the largest face
    assignment : (F,) int64, the axis (0, 1, 2) nearest to each face's normal
    aligned : (F,) bool, the faces within the angle tolerance of their axis
    sliver : (F,) bool, faces below SLIVER_SHARE of the points (they fit no axis)
    """

    main: int
    assignment: NDArray[np.int64]
    aligned: NDArray[np.bool_]
    sliver: NDArray[np.bool_]


def box_corner(faces: list[FaceInfo], adjacency: NDArray[np.bool_], tol: float
               ) -> BoxCorner | None:
    """Return the box axes of the largest face and its largest perpendicular neighbour.

    The third axis is their cross product; every face goes to the axis nearest to its
    normal. None when no neighbour of the largest face is perpendicular to it within
    ``tol`` [rad].
    """
    sizes = np.array([f.size for f in faces])
    main = int(np.argmax(sizes))
    normals = np.array([f.normal for f in faces])
    cos_main = np.abs(normals @ normals[main])
    adjacent_perp = np.flatnonzero(adjacency[main] & (cos_main <= math.sin(tol)))
    if not adjacent_perp.size:
        return None
    second = int(adjacent_perp[np.argmax(sizes[adjacent_perp])])
    third = np.cross(normals[main], normals[second])
    third /= np.linalg.norm(third)
    cos_axes = np.abs(normals @ np.array([normals[main], normals[second], third]).T)
    return BoxCorner(main, np.argmax(cos_axes, axis=1), cos_axes.max(axis=1) >= math.cos(tol),
                     sizes < SLIVER_SHARE * sizes.sum())


def cuboid_decision(faces: list[FaceInfo], adjacency: NDArray[np.bool_], corner: BoxCorner,
                    usable: NDArray[np.bool_], reason: str) -> GraphDecision:
    """Return the cuboid decision on the axes of ``corner`` with the ``usable`` (F,) faces.

    Faces not usable fit no axis (-1). Whether two faces on different axes meet in a
    concave corner (:func:`_concave_corner`) is judged on every face but the slivers.
    """
    concave = _concave_corner(faces, adjacency, np.where(corner.sliver, -1, corner.assignment))
    assignment = np.where(usable, corner.assignment, -1)
    return GraphDecision("planar", ("cuboid",), corner.main, tuple(int(a) for a in assignment),
                         reason + (CONCAVE_CORNER if concave else ""), concave_corner=concave)


def _planar_decision(faces: list[FaceInfo], adjacency: NDArray[np.bool_], tol: float,
                     coplanar_tol: float) -> GraphDecision:
    sizes = np.array([f.size for f in faces])
    sliver = sizes < SLIVER_SHARE * sizes.sum()
    main = int(np.argmax(sizes))
    normals = np.array([f.normal for f in faces])
    cos_main = np.abs(normals @ normals[main])
    parallel = cos_main >= math.cos(tol)
    corner = box_corner(faces, adjacency, tol)
    if corner is not None:
        if np.all(corner.aligned | corner.sliver):
            return cuboid_decision(faces, adjacency, corner, corner.aligned,
                                   "planar faces with perpendicular adjacent normals")
        return GraphDecision("planar", (), main, (), NOT_ALIGNED)
    if (parallel | sliver).all():
        # Coplanar: every parallel face's centre lies on the main face's plane (distances
        # are measured where the faces are, not at the sensor's origin).
        m = faces[main]
        gaps = [abs(float(m.normal @ f.center) + m.offset) if f.center is not None and
                m.center is not None else abs(f.offset * np.sign(f.normal @ m.normal) - m.offset)
                for f, ok in zip(faces, parallel) if ok]
        if max(gaps) <= coplanar_tol:
            return GraphDecision("planar", ("plane",), main, (),
                                 "parallel coplanar planar faces merged into one plane"
                                 if len(faces) > 1 else "single planar face")
        return GraphDecision("planar", (), main, (), "parallel planar faces at different offsets")
    return GraphDecision("planar", (), main, (),
                         "planar faces neither perpendicular nor parallel to the main face")


def _concave_corner(faces: list[FaceInfo], adjacency: NDArray[np.bool_],
                    axis: NDArray[np.int64]) -> bool:
    """Tell whether two adjacent faces on different box axes meet in a concave corner.

    ``axis`` (F,): the box axis of each face, -1 for faces not counted (slivers). A convex
    solid's faces seen from outside each lie behind (or on) the planes of the others,
    their normals towards the sensor; two adjacent perpendicular faces each of whose
    centres lies in front of the other's plane are seen from inside (a room's corner, a
    box against a wall), which no box shows. At a box's edge each centre lies behind the
    other face's plane by half its face's width; the noise moves a fitted plane at another
    face's centre by a small share of the point noise (both are least-squares fits of
    their points), so the signs decide without a band. Faces on one axis (pieces of one
    side, or two parallel sides) are not compared: a side that a sensor's slow error bends
    gives pieces whose signs are the noise's.
    """
    idx = [i for i, f in enumerate(faces) if axis[i] >= 0 and f.center is not None]
    for a in idx:
        for b in idx:
            if a < b and adjacency[a, b] and axis[a] != axis[b]:
                fa, fb = faces[a], faces[b]
                if float(fb.normal @ fa.center) + fb.offset > 0.0 and \
                        float(fa.normal @ fb.center) + fa.offset > 0.0:
                    return True
    return False


def side_tilt(normals: NDArray[np.float64], axis: NDArray[np.float64]) -> float:
    """Return the tilt [rad] of a round side's normals (M, 3) to one side of ``axis`` (3,).

    The arcsine of the median of their components along the axis, signed: the point
    normals are oriented towards the sensor, so a frustum's (or cone's) side normals all
    lean towards its top, by its half-angle, while a cylinder's scatter to both sides of
    the perpendicular by the noise and their median stays near zero. The unsigned
    angles (:func:`_mixed_decision`'s perpendicularity test) grow with the noise instead.
    """
    if not len(normals):
        return 0.0
    return math.asin(min(1.0, abs(float(np.median(normals @ axis)))))


def _mixed_decision(faces: list[FaceInfo], tol: float,
                    frustum_tilt: float | None = None) -> GraphDecision:
    planar = [i for i, f in enumerate(faces) if f.planar]
    main = max(planar, key=lambda i: faces[i].size)
    n0 = faces[main].normal
    total = sum(f.size for f in faces)
    others = [i for i in planar if i != main]
    # Small planar pieces at an angle to the main plane are slivers of the curved surface.
    if any(abs(faces[i].normal @ n0) < math.cos(tol) and faces[i].size > MIXED_VETO_SHARE * total
           for i in others):
        return GraphDecision("mixed", (), main, (),
                             "several non-parallel planar faces with curved faces")
    curved_normals = np.vstack([f.point_normals for f in faces if not f.planar])
    angles = np.arcsin(np.clip(np.abs(curved_normals @ n0), 0.0, 1.0))
    median = float(np.median(angles))
    q1, q3 = np.percentile(angles, [25, 75])
    if median <= tol:
        tilt = side_tilt(curved_normals, n0)
        if frustum_tilt is not None and tilt >= frustum_tilt:
            return GraphDecision("mixed", ("frustum", "cylinder", "cone"), main, (),
                                 "curved normals perpendicular to the plane normal, tilted "
                                 f"{math.degrees(tilt):.1f} deg to one side")
        return GraphDecision("mixed", ("cylinder", "cone", "frustum"), main, (),
                             "curved normals perpendicular to the plane normal")
    if q3 - q1 <= CONE_ANGLE_SPREAD * tol:
        return GraphDecision("mixed", ("cone", "frustum", "cylinder"), main, (),
                             f"curved normals at a constant {math.degrees(median):.1f} deg "
                             "to the plane")
    return GraphDecision("mixed", (), main, (), "curved normals at varying angles to the plane")


#: A median |k1| below this share of its upper quartile is zero: the relative variation
#: (interquartile range over the median) has no scale then.
ZERO_MEDIAN_SHARE = 1e-6


def ratio_halfwidth(a_max: NDArray[np.float64], a_min: NDArray[np.float64],
                    blocks: NDArray[np.int64]) -> float:
    """Return the half-width of the interval of the curvature ratio median |k2| / median |k1|.

    The ratio of each block's medians (``blocks`` (M,), e.g.
    :func:`~.fitting.paired_cost.spread_blocks` of the points: neighbouring points share
    their depth errors, and so their curvature errors) scatters about the object's ratio;
    the half-width is the Student quantile at ``LOWER_LEVEL`` (one-sided, blocks - 1
    degrees of freedom) times the standard error of the blocks' mean ratio. Blocks whose
    median |k1| is zero are left out; 0 with fewer than ``MIN_BLOCKS`` blocks.

    Parameters
    ----------
    a_max, a_min : (M,) float64 arrays [1/m], finite, >= 0
        |k1| and |k2| per point.
    blocks : (M,) int64 array, block index per point
    """
    ids = np.unique(blocks)
    num = np.array([np.median(a_min[blocks == b]) for b in ids])
    den = np.array([np.median(a_max[blocks == b]) for b in ids])
    ratios = num[den > 0] / den[den > 0]
    g = len(ratios)
    if g < MIN_BLOCKS:
        return 0.0
    se = float(np.std(ratios, ddof=1)) / math.sqrt(g)
    return float(stats.t.ppf(1.0 - LOWER_LEVEL, g - 1)) * se


def _developable(a_max: NDArray[np.float64], cone_variation: float) -> tuple[tuple[str, ...], str]:
    """Return the developable candidates (cone first when |k1| (M,) varies) and why."""
    q1, med, q3 = np.percentile(a_max, [25, 50, 75])
    if not med > ZERO_MEDIAN_SHARE * q3:
        # Most of the face is straight in every direction: |k1| varies without a scale.
        return ("cone", "frustum", "cylinder"), \
            f"k2 ~ 0, k1 varies (median ~0, quartiles {q1:.3g}-{q3:.3g} 1/m)"
    variation = float((q3 - q1) / med)
    if variation > cone_variation:
        return ("cone", "frustum", "cylinder"), f"k2 ~ 0, k1 varies ({variation:.2f})"
    return ("cylinder", "cone", "frustum"), f"k2 ~ 0, k1 constant ({variation:.2f})"


def curvature_candidates(k_max: NDArray[np.float64], k_min: NDArray[np.float64],
                         sphere_ratio: float, developable_ratio: float,
                         cone_variation: float, blocks: NDArray[np.int64] | None = None
                         ) -> tuple[tuple[str, ...], str]:
    """Propose the candidates of an all-curved object from its principal curvatures.

    A ratio between the two bounds is measured on a finite, noisy sample: with ``blocks``
    its interval (:func:`ratio_halfwidth`) decides whether the data can tell it from a
    bound; the candidates of each bound within its reach are proposed, the nearer first,
    and the fits' own verification decides. Without ``blocks``, or when neither bound is
    within reach, such a ratio fits no primitive.

    Parameters
    ----------
    k_max, k_min : (M,) float64 arrays [1/m]
        Curvatures of largest and smallest magnitude per point (NaN: unknown).
    sphere_ratio : float
        Median |k_min| / median |k_max| at or above which the object is a sphere.
    developable_ratio : float
        Ratio at or below which it is a cylinder or cone.
    cone_variation : float
        Relative spread of |k_max| (IQR / median) above which cone is tried first.
    blocks : (M,) int64 array, optional
        Block of neighbouring points of each point (:func:`ratio_halfwidth`).

    Returns
    -------
    (candidates, reason) : (tuple[str, ...], str)
    """
    a_max = np.abs(k_max[np.isfinite(k_max)])
    a_min = np.abs(k_min[np.isfinite(k_min)])
    if a_max.size == 0 or np.median(a_max) <= 0:
        return (), NO_CURVATURE
    ratio = float(np.median(a_min) / np.median(a_max))
    if ratio >= sphere_ratio:
        return ("sphere",), f"k1 ~ k2 (median ratio {ratio:.2f})"
    if ratio <= developable_ratio:
        return _developable(a_max, cone_variation)
    why = f"principal curvature ratio {ratio:.2f}"
    if blocks is None:
        return (), f"{why} fits no primitive"
    both = np.isfinite(k_max) & np.isfinite(k_min)
    half = ratio_halfwidth(np.abs(k_max[both]), np.abs(k_min[both]), blocks[both])
    dev = _developable(a_max, cone_variation) if ratio - half <= developable_ratio else None
    sph = (("sphere",), "k1 ~ k2") if ratio + half >= sphere_ratio else None
    if dev is None and sph is None:
        return (), f"{why} (+- {half:.2f}) fits no primitive"
    near_dev = ratio - developable_ratio <= sphere_ratio - ratio
    order = [c for c in ((dev, sph) if near_dev else (sph, dev)) if c is not None]
    return (tuple(k for c, _ in order for k in c),
            f"{why} +- {half:.2f} {BETWEEN_BOUNDS}: " + ", then ".join(w for _, w in order))


def decide_type(faces: list[FaceInfo], adjacency: NDArray[np.bool_], tol: float,
                coplanar_tol: float, curvature: tuple[NDArray, NDArray] | None = None,
                sphere_ratio: float = ModelingParams.sphere_curvature_ratio,
                developable_ratio: float = ModelingParams.developable_curvature_ratio,
                cone_variation: float = ModelingParams.cone_curvature_variation,
                frustum_tilt: float | None = None,
                blocks: NDArray[np.int64] | None = None) -> GraphDecision:
    """Apply the model graph.

    Parameters
    ----------
    faces : list of FaceInfo
    adjacency : (F, F) bool
    tol : float [rad]
        Angle tolerance for parallel / perpendicular.
    coplanar_tol : float [m]
        Largest offset difference of parallel faces merged into one plane.
    curvature : (k_max, k_min) arrays [1/m], optional
        Principal curvatures of the working points; without them an all-curved object
        gets every curved candidate.
    sphere_ratio, developable_ratio, cone_variation : float
        See :func:`curvature_candidates`; defaults: the :class:`ModelingParams` defaults
        ``sphere_curvature_ratio``, ``developable_curvature_ratio`` and
        ``cone_curvature_variation``.
    frustum_tilt : float [rad], optional
        A planar + curved object whose curved normals pass as perpendicular to the plane
        but lean to one side of it by at least this angle (:func:`side_tilt`) gets the
        frustum first: its unit's taper test (``fitting.frustum``) then tells a tapered
        side from a cylinder's. None (the default) keeps the cylinder first.
    blocks : (M,) int64 array, optional
        Block of neighbouring points of each curvature's point (:func:`curvature_candidates`).

    Returns
    -------
    GraphDecision
    """
    if not faces:
        return GraphDecision("empty", (), -1, (), "no faces")
    planar = [f.planar for f in faces]
    if all(planar):
        return _planar_decision(faces, adjacency, tol, coplanar_tol)
    if any(planar):
        total = sum(f.size for f in faces)
        curved = sum(f.size for f in faces if not f.planar)
        if curved < SLIVER_SHARE * total:
            # Curved slivers (rounded edges, noise) on a planar object: the planar faces
            # decide.
            d = _planar_decision(faces, adjacency, tol, coplanar_tol)
            return GraphDecision(d.category, d.candidates, d.main_face, d.axis_of_face,
                                 d.reason + " (curved slivers ignored)")
        return _mixed_decision(faces, tol, frustum_tilt)
    if curvature is None:
        return GraphDecision("curved", ("cylinder", "cone", "sphere", "frustum"), -1, (),
                             "all faces curved")
    cands, why = curvature_candidates(*curvature, sphere_ratio, developable_ratio, cone_variation,
                                      blocks)
    return GraphDecision("curved", cands, -1, (), why, between_bounds=BETWEEN_BOUNDS in why)
