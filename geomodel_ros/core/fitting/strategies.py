"""How an object's type is decided and which fallbacks are tried when no candidate fits.

:func:`decide` applies the model graph. :data:`STRATEGIES` is the ordered list of
attempts :func:`run_strategies` makes until one fits: the model graph's own candidates,
the curved faces alone (when mixed faces fit no rule), curved faces with flat normals
taken as planes, and round candidates upright above a support plane. A round fit also
has to beat a box: the box of the planar faces and of the flat cores of curved faces (a
box side with a gable, fold or shrink-wrap ripples over part of it), the other curved
faces left out as outliers (:func:`box_rival`); the shape with the smaller truncated
residual over all the object's points (MSAC cost at the noise band) is taken
(:func:`prefer_box`). An object with no such box (no planar face, no flat core: far from
the sensor a small box's faces may each span two of its sides) meets the box whose axes
are the modes of its point normals, judged on how well each model's surface normals
agree with the measured ones (:func:`prefer_box_of_normals`). A box, in turn, has to
beat the round model of all the object's faces taken as curved, on the same cost
(:func:`prefer_round`). Last, planar faces that fit no rule of the model graph are
fitted as the box of the point normals' modes (:class:`PlanarFacesWithoutRule`); an
object that no strategy typed but whose surface showed itself curved two ways (a side
rejected for a bowed profile, or curvatures neither developable nor spherical) is tried
as a sphere (:class:`DoublyCurvedAsSphere`); and, after everything else, a mixed object,
or an object of planar faces only, with every face taken as curved
(:class:`AllFacesCurvedAfterAll`). An object still untyped then meets
:data:`LAST_STRATEGIES`: the box of its point normals' modes (:class:`NormalsBoxAfterAll`),
an open container's wall fitted without the faces seen from inside it
(:class:`OuterWallAfterAll`), and a box upright on the support below whose frame holds
faces the noise turned (:class:`UprightBoxOnSupport`).
"""

from __future__ import annotations

import copy
import dataclasses
import math
from dataclasses import dataclass, field
from functools import cached_property
from typing import Callable, Iterator, Protocol, Sequence

import numpy as np
from numpy.typing import NDArray
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import ConvexHull, QhullError

from geomodel_ros.core.faces import faces_from_labels, link_folds
from geomodel_ros.core.fastmath import centroid
from geomodel_ros.core.geometry import frame_with_z
from geomodel_ros.core.fitting.cloud import (ObjectCloud, ObjectFace, as_planar,
                                             bends_beyond_noise, describe_faces)
from geomodel_ros.core.fitting.curved import CurvedFit, fit_curved
from geomodel_ros.core.confidence import round_outline, surface_distance, surface_normals
from geomodel_ros.core.fitting.axial import (across_axis, cap_facing, rim_arc,
                                              seen_from_outside)
from geomodel_ros.core.fitting.measure import every_kth
from geomodel_ros.core.fitting.normal_box import (MIN_SIDE_NORMALS, axis_costs, box_axes,
                                                  normal_costs, side_labels)
from geomodel_ros.core.fitting.orient import toward_sensor
from geomodel_ros.core.fitting.paired_cost import lower_beyond_noise, spread_blocks
from geomodel_ros.core.fitting.result import Rejected
from geomodel_ros.core.fitting.sphere import sphere_test
from geomodel_ros.core.fitting.units import fit_first
from geomodel_ros.core.fitting.verify import bowed_profile, standing_on
from geomodel_ros.core import obb
from geomodel_ros.core.model_graph import (BETWEEN_BOUNDS, NO_CURVATURE, NOT_ALIGNED,
                                           SLIVER_SHARE, BoxCorner, FaceInfo, GraphDecision,
                                           box_corner, cuboid_decision, curvature_candidates,
                                           decide_type)
from geomodel_ros.core.params import ModelingParams
from geomodel_ros.core.primitives import FaceSummary, Primitive, PrimitiveType
from geomodel_ros.core.ransac import (CylinderModel, PlaneModel, SphereModel, fit_plane_svd,
                                     ransac)
from geomodel_ros.core.surface_type import face_feature, principal_curvatures

__all__ = ["Situation", "Attempt", "Strategy", "STRATEGIES", "LAST_STRATEGIES", "decide",
           "run_strategies", "ModelGraphCandidates", "CurvedFacesAlone", "FlatCurvedFacesAsPlanar",
           "UprightAboveSupport", "BoxRival", "PlanarPatchesOfCurvedObjects", "BoxOfFlatCores",
           "DoublyCurvedAsSphere", "FacesInBoxFrame", "faces_in_box_frame", "flat_faces",
           "flat_core_faces", "box_rival", "normal_box_rival", "prefer_box_of_normals",
           "support_below", "truncated_cost", "truncated_costs", "cavity_floor",
           "prefer_box", "prefer_round", "round_rival", "round_of_plane", "box_of_plane",
           "thinned", "all_faces_curved", "as_curved", "outline_circle"]

#: Principal curvatures are fitted as quadrics (six terms) over at least this many
#: neighbours of each working point.
MIN_CURVATURE_NEIGHBOURS = 6
#: Parallel planar faces whose offsets differ by at most this many RANSAC thresholds are
#: one plane (the band within which a plane's own points scatter).
COPLANAR_FACTOR = 3
#: Principal curvatures come from the smooth (non-edge) working points when at least
#: this many are; otherwise from all of them.
MIN_SMOOTH_POINTS = 10
#: A curved face whose point normals stay within this angle [rad] of their mean (at the
#: FLAT_NORMALS_PERCENTILE) may be taken as planar when no model fits it as curved. A
#: round surface's normals turn with its arc (at least ``min_arc`` for an accepted fit).
FLAT_FACE_ANGLE = math.radians(20.0)
FLAT_NORMALS_PERCENTILE = 10.0
#: A curved face has a flat core when this percentile of its point normals (half of
#: them) stays within FLAT_FACE_ANGLE of their mean: a box side with a gable, a fold or
#: shrink-wrap ripples over a minority of it. A round side seen from one viewpoint does
#: not: its normals turn with the arc (a cylinder's visible half has about a third of
#: them, sin 20 deg, within 20 deg of the mean).
FLAT_CORE_PERCENTILE = 50.0
#: Points on which the truncated residuals of rival shapes are compared (as
#: CONFIDENCE_SAMPLE: a mean over 2000 samples has a standard error of a few per cent).
RIVAL_SAMPLE = 2000
#: Points on which a cuboid's round rival is looked at first (:func:`round_rival`): its
#: candidates come from the curvatures of about this many working points, and it is
#: fitted on as many face points (:func:`thinned`, no full-resolution refinement) -- a few
#: hundred, enough for its curvature medians, RANSAC and checks to find a round side that
#: the object really has, at a fraction of the full fit's time; only a rival whose first
#: look costs no more than the box on average is refitted on all the points.
RIVAL_FIT_POINTS = 400
#: Fewest point normals and smallest mean-normal norm for which flatness is judged.
MIN_FLAT_NORMALS = 3
MIN_FLAT_MEAN_NORM = 1e-9
#: The planar faces of a mixed object may be patches of its curved surface when its curved
#: faces hold more than this share of its working points (the curved surface dominates).
CURVED_MAJORITY = 0.5
#: Faces seen from inside are a container's inner wall only when this share of their
#: points lie within its wall (:func:`inner_wall_refusal`; a simple majority would leave
#: a third object's face half inside by chance) ...
INNER_WALL_SHARE = 0.8
#: ... at most this share of the radius inside the outer wall (ceramic and plastic ware:
#: walls of 3-8 mm on radii of 30-130 mm).
WALL_SHARE = 0.25
#: A face seen from outside holds an inner part when this share of it is seen from inside
#: (:func:`seen_from_inside`; a rim's rounding or noise marks scattered points only).
INNER_PART_SHARE = 0.2
#: Planar faces without a rule are fitted as the box of the point normals' modes only
#: when at least this share of the working points' normals face one of its sides (a
#: simple majority: a box's normals gather on its sides, and only its edges' mixed
#: normals lie off them).
BOX_NORMALS_MIN_SHARE = 0.5
ROUND_TYPES = (PrimitiveType.CYLINDER, PrimitiveType.CONE, PrimitiveType.FRUSTUM)
FLAT_TYPES = (PrimitiveType.PLANE, PrimitiveType.CUBOID)


def graph_decision(infos: list[FaceInfo], adjacency: NDArray[np.bool_],
                   curvature: tuple[NDArray, NDArray] | None,
                   params: ModelingParams, blocks: NDArray[np.int64] | None = None
                   ) -> GraphDecision:
    """Return the model graph's decision with the thresholds of ``params``.

    With a measured noise (``noise_model = auto``) a side that passes as perpendicular to
    its cap but leans to one side of it by at least ``min_cone_half_angle`` (the least
    half-angle the cone and frustum units accept) is tried as a frustum first, and the
    frustum unit's taper test decides; ``fixed`` keeps the cylinder first. ``blocks``
    (M,): the curvatures' points' blocks (:func:`curvature_blocks`).
    """
    tilt = params.min_cone_half_angle if params.noise_model == "auto" else None
    return decide_type(infos, adjacency, params.angle_tolerance,
                       COPLANAR_FACTOR * params.ransac_threshold, curvature,
                       params.sphere_curvature_ratio, params.developable_curvature_ratio,
                       params.cone_curvature_variation, tilt, blocks)


def _curvature_rows(cloud: ObjectCloud, which: NDArray[np.bool_]) -> NDArray[np.int64]:
    """Return the working points (indices) of ``which`` (M,) whose curvatures are judged."""
    wc, params = cloud.wc, cloud.params
    smooth = which & (wc.variation <= params.edge_variation_threshold)
    return np.flatnonzero(smooth if smooth.sum() >= MIN_SMOOTH_POINTS else which)


def curvatures(cloud: ObjectCloud, which: NDArray[np.bool_]) -> tuple[NDArray, NDArray]:
    """Principal curvatures k_max, k_min [1/m] of the working points ``which`` (M,) selects."""
    wc = cloud.wc
    return principal_curvatures(wc.points, wc.normals, wc.neighbors,
                                _curvature_rows(cloud, which))


def curvature_blocks(cloud: ObjectCloud, which: NDArray[np.bool_]) -> NDArray[np.int64] | None:
    """Blocks of neighbouring points (:func:`~.paired_cost.spread_blocks`) of :func:`curvatures`.

    One per curvature of ``which`` (M,); None with ``noise_model = fixed`` (the curvature
    ratio is then judged against its bounds alone, as before).
    """
    if cloud.params.noise_model != "auto":
        return None
    return spread_blocks(cloud.wc.points[_curvature_rows(cloud, which)])


def _curved_decision(cloud: ObjectCloud, which: NDArray[np.bool_]) -> GraphDecision:
    """Decision for the working points ``which`` (M,) as an all-curved object."""
    params = cloud.params
    cands, why = curvature_candidates(*curvatures(cloud, which), params.sphere_curvature_ratio,
                                      params.developable_curvature_ratio,
                                      params.cone_curvature_variation,
                                      curvature_blocks(cloud, which))
    return GraphDecision("curved", cands, -1, (), why, between_bounds=BETWEEN_BOUNDS in why)


def decide(cloud: ObjectCloud) -> GraphDecision:
    """Apply the model graph to the faces of ``cloud`` (curvatures when all are curved)."""
    infos = [f.info for f in cloud.faces]
    if infos and not any(i.planar for i in infos):
        return _curved_decision(cloud, np.ones(len(cloud.wc.points), dtype=bool))
    return graph_decision(infos, cloud.adjacency, None, cloud.params)


def curved_faces_alone(cloud: ObjectCloud) -> GraphDecision:
    """Decision for the curved faces of ``cloud`` alone, as an all-curved object."""
    mask = np.zeros(len(cloud.wc.points), dtype=bool)
    for f in cloud.faces:
        if not f.info.planar:
            mask[f.working] = True
    return _curved_decision(cloud, mask)


@dataclass
class Situation:
    """An object and the model graph's decision on it, as the strategies see them.

    ``rejected`` collects the fits rejected so far (:func:`run_strategies` fills it).
    """

    cloud: ObjectCloud
    decision: GraphDecision
    rejected: list[Rejected] = field(default_factory=list)

    @property
    def round_misfit(self) -> bool:
        """Whether a round model was found that does not explain the points (``misfit``)."""
        return any(r.misfit and r.type in ROUND_TYPES for r in self.rejected)

    @property
    def no_round_shape(self) -> bool:
        """Whether the curved faces' curvatures fit no primitive by their ratio.

        No candidate to fit, or only those of the ratio's interval (``between_bounds``).
        """
        d = self.fit_decision
        return d.category == "curved" and (not d.candidates or d.between_bounds)

    @property
    def mixed_without_rule(self) -> bool:
        """Whether the planar faces fit no rule with the curved ones (no candidate)."""
        return not self.decision.candidates and self.decision.category == "mixed"

    @cached_property
    def box_rival(self) -> "BoxRival | None":
        """The object's box hypothesis (:func:`box_rival`), found once."""
        return box_rival(self.cloud)

    @cached_property
    def fit_decision(self) -> GraphDecision:
        """The decision fits follow: the graph's, or the curved faces' alone if it had no rule."""
        return curved_faces_alone(self.cloud) if self.mixed_without_rule else self.decision


@dataclass(frozen=True)
class Attempt:
    """One try of a strategy: fit ``decision``'s candidates to ``cloud``.

    ``note`` (if any) is added to the reasons before the fits', ``prefix`` before each
    fit's reason; ``axis_prior`` (3,) constrains round fits. ``accept`` (if any) judges
    the model fitted: a reason refuses it, None accepts it.
    """

    cloud: ObjectCloud
    decision: GraphDecision
    axis_prior: NDArray[np.float64] | None = None
    note: str | None = None
    prefix: str = ""
    accept: Callable[[Primitive], str | None] | None = None


class Strategy(Protocol):
    """A named way to model an object; :func:`run_strategies` tries them in order."""

    name: str

    def applies(self, situation: Situation) -> bool:
        """Return True when the strategy has something to try."""

    def attempt(self, situation: Situation) -> Attempt | None:
        """Return what to fit (None: nothing after all)."""


class ModelGraphCandidates:
    """The candidates of the model graph (paper 3.2.1)."""

    name = "model graph"

    def applies(self, situation: Situation) -> bool:
        """Return True when the model graph proposed a type."""
        return bool(situation.decision.candidates)

    def attempt(self, situation: Situation) -> Attempt:
        """Fit the graph's candidates."""
        return Attempt(situation.cloud, situation.decision)


class CurvedFacesAlone:
    """Judge the curved faces alone when the planar ones fit no rule with them.

    Handles, rims and slivers of noise: the object is taken as all-curved (no axis prior).
    """

    name = "curved faces alone"

    def applies(self, situation: Situation) -> bool:
        """Return True for mixed faces that fit no rule of the model graph."""
        return situation.mixed_without_rule

    def attempt(self, situation: Situation) -> Attempt:
        """Fit the candidates of the curved faces' principal curvatures."""
        decision = situation.fit_decision
        return Attempt(situation.cloud, decision, note=f"curved faces alone: {decision.reason}")


def _flat(info: FaceInfo, percentile: float = FLAT_NORMALS_PERCENTILE) -> bool:
    """Whether a face's point normals stay within FLAT_FACE_ANGLE of their mean.

    All but ``percentile`` per cent of them must.
    """
    n = info.point_normals
    if len(n) < MIN_FLAT_NORMALS:
        return False
    mean = centroid(n)
    norm = float(np.linalg.norm(mean))
    if norm <= MIN_FLAT_MEAN_NORM:
        return False
    cos = np.abs(n @ (mean / norm))
    return float(np.percentile(cos, percentile)) >= math.cos(FLAT_FACE_ANGLE)


def flat_faces(cloud: ObjectCloud) -> list[int]:
    """Return the curved faces whose normals are flat (:data:`FLAT_FACE_ANGLE`)."""
    return [i for i, f in enumerate(cloud.faces) if not f.info.planar and _flat(f.info)]


class FlatCurvedFacesAsPlanar:
    """Take curved faces with flat normals as planes (a box side bent by sensor noise).

    With them as planes the object may be a plane or cuboid after all.
    """

    name = "flat curved faces as planar"

    def applies(self, situation: Situation) -> bool:
        """Return True when some curved face has flat normals."""
        return bool(flat_faces(situation.cloud))

    def attempt(self, situation: Situation) -> Attempt | None:
        """Fit the plane or cuboid the graph proposes for the re-described faces, if any."""
        cloud, flat = situation.cloud, flat_faces(situation.cloud)
        faces = [as_planar(cloud.wc, f, cloud.params.ransac_threshold) if i in flat else f
                 for i, f in enumerate(cloud.faces)]
        decision = graph_decision([f.info for f in faces], cloud.adjacency, None, cloud.params)
        decision = dataclasses.replace(
            decision, candidates=tuple(k for k in decision.candidates if k in FLAT_TYPES))
        if not decision.candidates:
            return None
        note = (f"faces {flat} taken as planar (their normals turn less than "
                f"{math.degrees(FLAT_FACE_ANGLE):.0f} deg): {decision.reason}")
        return Attempt(dataclasses.replace(cloud, faces=faces), decision, note=note)


def flat_core_faces(cloud: ObjectCloud) -> list[int]:
    """Return the curved faces with a flat core (:data:`FLAT_CORE_PERCENTILE`)."""
    return [i for i, f in enumerate(cloud.faces)
            if not f.info.planar and _flat(f.info, FLAT_CORE_PERCENTILE)]


@dataclass(frozen=True)
class BoxRival:
    """A box hypothesis for an object (:func:`box_rival`).

    ``cloud`` holds the box's candidate sides as its faces, ``decision`` proposes the
    cuboid for them, ``note`` says which faces were used and how.
    """

    cloud: ObjectCloud
    decision: GraphDecision
    note: str


def _aligned(faces: list[ObjectFace], adjacency: NDArray[np.bool_], tol: float) -> list[int]:
    """Return the faces aligned with one set of box axes within ``tol`` [rad].

    The axes are the normals of the largest face and of its largest perpendicular
    neighbour; all faces when the largest has no such neighbour.
    """
    sizes = np.array([f.info.size for f in faces])
    normals = np.array([f.info.normal for f in faces])
    main = int(np.argmax(sizes))
    cos_main = np.abs(normals @ normals[main])
    perp = np.flatnonzero(adjacency[main] & (cos_main <= math.sin(tol)))
    if not perp.size:
        return list(range(len(faces)))
    second = int(perp[np.argmax(sizes[perp])])
    third = np.cross(normals[main], normals[second])
    axes = np.array([normals[main], normals[second], third / np.linalg.norm(third)])
    return np.flatnonzero(np.abs(normals @ axes.T).max(axis=1) >= math.cos(tol)).tolist()


def box_rival(cloud: ObjectCloud) -> BoxRival | None:
    """Return the box hypothesis of an object whose faces do not all fit a box.

    The planar faces and the flat cores of curved faces (:func:`flat_core_faces`, taken
    as their planes) that are aligned with one set of box axes are the box's sides; the
    other faces (a carton's gable, a handle, a rim) are left out, so their points count
    as off the box. None when no face is left out or re-described, or when the model
    graph proposes no cuboid for the sides.
    """
    flat = flat_core_faces(cloud)
    cand = [i for i, f in enumerate(cloud.faces) if f.info.planar or i in flat]
    if not cand:
        return None
    params = cloud.params
    faces = [as_planar(cloud.wc, cloud.faces[i], params.ransac_threshold) if i in flat
             else cloud.faces[i] for i in cand]
    sub = _aligned(faces, cloud.adjacency[np.ix_(cand, cand)], params.angle_tolerance)
    kept = [cand[j] for j in sub]
    left_out = sorted(set(range(len(cloud.faces))) - set(kept))
    if not left_out and not flat:
        return None
    faces = [faces[j] for j in sub]
    adjacency = cloud.adjacency[np.ix_(kept, kept)]
    decision = graph_decision([f.info for f in faces], adjacency, None, params)
    if PrimitiveType.CUBOID not in decision.candidates:
        return None
    note = (f"box of faces {kept} (flat cores of {flat} as planes, {left_out} left out): "
            f"{decision.reason}")
    return BoxRival(dataclasses.replace(cloud, faces=faces, adjacency=adjacency),
                    dataclasses.replace(decision, candidates=(PrimitiveType.CUBOID,)), note)


def normal_box_rival(cloud: ObjectCloud, axes: NDArray[np.float64] | None = None
                     ) -> BoxRival | None:
    """Return the box whose axes are the modes of the object's point normals, or None.

    ``axes`` (3, 3) (columns) when already found, else from
    :func:`~.normal_box.box_axes` of all the working points' normals (tolerance
    ``angle_tolerance``, which grows with the noise band); each visible side is the
    working points whose normals face it (:func:`~.normal_box.side_labels`; an edge's
    mixed normals are left out), taken as a plane with the side's direction as its
    normal, and its input points are those of its working points. None when fewer than
    two sides along different axes hold :data:`~.normal_box.MIN_SIDE_NORMALS` normals
    each.
    """
    wc, tol = cloud.wc, cloud.params.angle_tolerance
    axes = box_axes(wc.normals, tol) if axes is None else axes
    if axes is None:
        return None
    labels = side_labels(wc.normals, axes, tol)
    counts = np.bincount(labels[labels >= 0], minlength=6)
    sides = np.flatnonzero(counts >= MIN_SIDE_NORMALS)
    if len({int(s) // 2 for s in sides}) < 2:
        return None
    # The face each working point came from (its summary's CF is the new side's).
    origin = np.full(len(wc.points), -1, dtype=np.int64)
    for i, f in enumerate(cloud.faces):
        origin[f.working] = i
    faces = []
    for side in sides:
        widx = np.flatnonzero(labels == side)
        center = centroid(wc.points[widx])
        normal = toward_sensor(axes[:, side // 2], center)
        info = FaceInfo(True, normal, float(-normal @ center), len(widx), wc.normals[widx],
                        center)
        pidx = np.flatnonzero(labels[wc.point_to_working] == side)
        came = origin[widx]
        cf = cloud.faces[int(np.argmax(np.bincount(came[came >= 0], minlength=1)))].summary.cf \
            if (came >= 0).any() else 0.0
        faces.append(ObjectFace(info, FaceSummary("planar", cf, len(pidx), normal), widx, pidx))
    axis_of_face = tuple(int(s) // 2 for s in sides)
    main = int(np.argmax(counts[sides]))
    decision = GraphDecision("planar", (PrimitiveType.CUBOID,), main, axis_of_face,
                             "sides from the modes of the point normals")
    adjacency = ~np.eye(len(faces), dtype=bool)
    note = (f"box of the point normals' modes (sides along axes {list(axis_of_face)}, "
            f"{int(np.count_nonzero(labels < 0))} of {len(labels)} normals off every side)")
    return BoxRival(dataclasses.replace(cloud, faces=faces, adjacency=adjacency), decision, note)


def prefer_box_of_normals(situation: Situation, prim: Primitive,
                          faces: tuple[FaceSummary, ...], reasons: list[str]
                          ) -> tuple[Primitive, tuple[FaceSummary, ...]]:
    """Return the round fit ``prim`` or the box of the point normals' modes, by the normals.

    For an object with no box of faces (:func:`box_rival` None: no planar face, no flat
    core). Far from the sensor the noise band outgrows a small box, and a round model
    explains its points' positions as well as the box; the measured normals still face
    the box's sides, where a round side's turn with its arc. The box
    (:func:`normal_box_rival`) replaces ``prim`` when the angles between the measured
    normals of the working points and each model's surface normals
    (:func:`~geomodel_ros.core.confidence.surface_normals`) cost less for the box beyond
    the noise (:func:`~.normal_box.normal_costs`, band ``angle_tolerance``; the
    block-paired test :func:`~.paired_cost.lower_beyond_noise`, as the normals' errors
    are correlated over neighbouring points too) and the round model's truncated
    residuals are not lower beyond the noise (:func:`truncated_costs`: the positions do
    not contradict the box). The axes and the normals' costs come from every k-th
    working point, about :data:`RIVAL_FIT_POINTS` (a first look, as for the round
    rival); the box is fitted (its sides from all the working points) only when its axes
    alone (no box with them has lower normal costs) pass the normals' test. Only with
    ``noise_model = auto``; the comparison is added to ``reasons`` when the box is
    fitted.
    """
    cloud = situation.cloud
    params = cloud.params
    if prim.type not in ROUND_TYPES or params.noise_model != "auto":
        return prim, faces
    tol = params.angle_tolerance
    points, normals = _first_look_normals(cloud)
    axes = box_axes(normals, tol)
    model = None if axes is None else surface_normals(prim, points)
    if model is None:
        return prim, faces
    c_round = normal_costs(model, normals, tol)
    blocks = spread_blocks(points)
    if not lower_beyond_noise(axis_costs(axes, normals, tol), c_round, blocks)[0]:
        return prim, faces
    rival = normal_box_rival(cloud, axes)
    if rival is None:
        return prim, faces
    box, _ = fit_first(rival.cloud, rival.decision)
    if box is None:
        return prim, faces
    c_box = normal_costs(surface_normals(box, points), normals, tol)
    lower, stat = lower_beyond_noise(c_box, c_round, blocks)
    p_round, p_box = truncated_costs(prim, cloud), truncated_costs(box, cloud)
    closer, stat_p = lower_beyond_noise(p_round, p_box,
                                        spread_blocks(every_kth(cloud.points, RIVAL_SAMPLE)))
    replace = lower and not closer
    verdict = "replaces" if replace else "does not replace"
    reasons.append(f"{rival.note}; cuboid (normal cost {np.mean(c_box):.3f}, cost "
                   f"{np.mean(p_box):.3f}) {verdict} {prim.type} (normal cost "
                   f"{np.mean(c_round):.3f}, t = {stat:.1f}; cost {np.mean(p_round):.3f}, "
                   f"t = {stat_p:.1f})")
    if replace:
        return box, tuple(f.summary for f in rival.cloud.faces)
    return prim, faces


def truncated_costs(p: Primitive, cloud: ObjectCloud,
                    keep: NDArray[np.bool_] | None = None) -> NDArray[np.float64]:
    """MSAC cost (k,) of ``p`` per compared point: min(d, t)^2 / t^2, in [0, 1].

    ``d`` is each point's distance to the fitted surface (every k-th of about
    :data:`RIVAL_SAMPLE` points of the object, of those ``keep`` (N,) marks if given),
    ``t`` the RANSAC threshold (the noise band): points on the surface cost their squared
    residual, points off it (outliers) one band each. All ones when ``p`` has no surface.
    """
    t = cloud.params.ransac_threshold
    points = cloud.points if keep is None else cloud.points[keep]
    sample = np.ascontiguousarray(every_kth(points, RIVAL_SAMPLE))
    d = surface_distance(p, sample)
    if d is None or t <= 0:
        return np.ones(len(sample))
    return np.minimum(d / t, 1.0) ** 2


def truncated_cost(p: Primitive, cloud: ObjectCloud,
                   keep: NDArray[np.bool_] | None = None) -> float:
    """MSAC cost of ``p`` on the object's points: the mean of :func:`truncated_costs`."""
    c = truncated_costs(p, cloud, keep)
    return float(np.mean(c)) if len(c) else 1.0


def cavity_floor(cloud: ObjectCloud, round_model: Primitive) -> NDArray[np.bool_]:
    """Which of the object's points (N,) lie on a floor seen inside ``round_model``.

    The planar faces perpendicular to its axis (within ``angle_tolerance``) that are seen
    from inside the solid at the end they are nearer to (:func:`~.axial.axial_extent`: a
    cup's or bowl's inner floor): an open container's cavity, which neither a round solid
    nor a box explains.
    """
    axis, center = round_model.rotation[:, 2], round_model.center
    floor = np.zeros(len(cloud.points), dtype=bool)
    for f in across_axis(cloud, axis):
        if not len(f.points):
            continue
        q = cloud.points[f.points]
        high_end = float(np.median((q - center) @ axis)) >= 0
        # Seen from inside: its normal towards the sensor points into the solid.
        floor[f.points] = seen_from_outside(-cap_facing(q, f.info.normal, axis), high_end)
    return floor


def prefer_box(situation: Situation, prim: Primitive, faces: tuple[FaceSummary, ...],
               reasons: list[str]) -> tuple[Primitive, tuple[FaceSummary, ...]]:
    """Return the round fit ``prim`` or the box of the flat cores, whichever costs less.

    The box (:func:`box_rival`) is fitted to the same object; it replaces ``prim``
    when its :func:`truncated_cost` over the object's points is lower (an open
    container's inner floor left out, :func:`cavity_floor`: neither solid explains it). The
    comparison is added to ``reasons``. Without that box, the box of the point
    normals' modes is judged instead (:func:`prefer_box_of_normals`).
    """
    if prim.type not in ROUND_TYPES:
        return prim, faces
    rival = situation.box_rival
    if rival is None:
        return prefer_box_of_normals(situation, prim, faces, reasons)
    box_cloud, note = rival.cloud, rival.note
    box, _ = fit_first(box_cloud, rival.decision)
    if box is None:
        return prim, faces
    cloud = situation.cloud
    walls = ~cavity_floor(cloud, prim)
    return _cheaper(cloud, (prim, faces), (box, tuple(f.summary for f in box_cloud.faces)),
                   f"{note}; cuboid", reasons, walls)


def _cheaper(cloud: ObjectCloud, held: tuple[Primitive, tuple[FaceSummary, ...]],
            rival: tuple[Primitive, tuple[FaceSummary, ...]], name: str, reasons: list[str],
            keep: NDArray[np.bool_] | None = None
            ) -> tuple[Primitive, tuple[FaceSummary, ...]]:
    """Return ``rival`` (model, faces) if its :func:`truncated_cost` is lower, else ``held``.

    Over the object's points (those ``keep`` marks, if given); the comparison is added to
    ``reasons``, the rival called ``name``.
    """
    c_held, c_rival = truncated_cost(held[0], cloud, keep), truncated_cost(rival[0], cloud, keep)
    verdict = "replaces" if c_rival < c_held else "does not replace"
    reasons.append(f"{name} (cost {c_rival:.3f}) {verdict} {held[0].type} (cost {c_held:.3f})")
    return rival if c_rival < c_held else held


def support_below(cloud: ObjectCloud) -> NDArray[np.float64] | None:
    """Return the normal (3,) of a support plane that ``cloud`` stands above, or None.

    The plane of :func:`~.verify.standing_on` (objects stacked on others count too).
    """
    plane = standing_on(cloud)
    return None if plane is None else np.asarray(plane[0], dtype=np.float64)


class UprightAboveSupport:
    """Fit round candidates with their axis along the normal of the support below.

    A round object standing on the desk (or on another object on it) mostly has its
    axis along the desk's normal. Without that prior, a large flat lid grown together
    with the side (over a rounded edge) draws RANSAC to a huge cylinder through the lid.
    """

    name = "upright above the support"

    def applies(self, situation: Situation) -> bool:
        """Return True when cylinder or cone is a candidate."""
        return any(k in ROUND_TYPES for k in situation.fit_decision.candidates)

    def attempt(self, situation: Situation) -> Attempt | None:
        """Fit the round candidates along the support's normal, if the object stands on one."""
        up = support_below(situation.cloud)
        if up is None:
            return None
        d = situation.fit_decision
        upright = dataclasses.replace(d, candidates=tuple(k for k in d.candidates
                                                          if k in ROUND_TYPES))
        return Attempt(situation.cloud, upright, axis_prior=up,
                       prefix="upright above the support: ")


def as_curved(face: ObjectFace) -> ObjectFace:
    """Return ``face`` re-described as curved (normal: the mean of its point normals)."""
    info = face.info
    mean = centroid(info.point_normals) if len(info.point_normals) else info.normal
    norm = float(np.linalg.norm(mean))
    normal = mean / norm if norm > MIN_FLAT_MEAN_NORM else info.normal
    curved = dataclasses.replace(info, planar=False, normal=normal, offset=0.0)
    s = face.summary
    return ObjectFace(curved, FaceSummary("curved", s.cf, s.point_count, normal), face.working,
                      face.points)


def _mostly_curved_mixed(situation: Situation) -> bool:
    """Whether a mixed object's curved faces hold most of its points (``auto`` noise only).

    More than :data:`CURVED_MAJORITY` of the faces' working points.
    """
    cloud = situation.cloud
    if situation.decision.category != "mixed" or cloud.params.noise_model != "auto":
        return False
    curved = sum(f.info.size for f in cloud.faces if not f.info.planar)
    return curved > CURVED_MAJORITY * sum(f.info.size for f in cloud.faces)


class PlanarPatchesOfCurvedObjects:
    """Take the planar faces of a mainly curved object as patches of its curved surface.

    Under depth noise a patch of a small round surface can pass as flat (its bend within
    the noise over the patch): a sphere with one "planar" face gets the cylinder and cone
    rules of a mixed object, which fail. When the curved faces hold most of the object
    (CURVED_MAJORITY), every face is taken as curved and the object's principal
    curvatures propose the candidates, fitted to all of its faces, provided each planar
    face bends significantly beyond the noise in its central region (``cloud.
    central_bend``; a face that does not is a true flat end, a lid or base, and the mixed
    rules stand). The fits' own
    checks (inliers and scatter against the noise) still apply. The bend is judged
    against the frame's noise as measured (:func:`~.cloud.bends_beyond_noise`): by its
    significance where the noise is independent, and where slow sensor errors bend flat
    patches as well, beyond the bends they give flat patches of the frame's support as
    large in the image (:mod:`~.slow_bend`); ``fixed`` keeps the previous strategies
    exactly.
    """

    name = "planar patches of a curved object"

    def applies(self, situation: Situation) -> bool:
        """Return True for a mixed object, mostly curved, whose planar faces all bend."""
        cloud = situation.cloud
        faces = cloud.faces
        if not _mostly_curved_mixed(situation):
            return False
        # A planar face without a significant bend is a true flat end (a lid, a base).
        wc, params = cloud.wc, cloud.params
        for f in faces:
            if not f.info.planar:
                continue
            pts, mass = wc.points[f.working], wc.counts[f.working]
            feat = face_feature(pts, params.cf_weights, params.cf_threshold,
                                params.cf_radius_fraction, mass)
            if not bends_beyond_noise(pts, mass, f.info.normal, feat, params,
                                      cloud.correlation, cloud.slow_null):
                return False
        return True

    def attempt(self, situation: Situation) -> Attempt | None:
        """Fit the candidates of the whole object's curvatures with every face curved."""
        return all_faces_curved(situation.cloud,
                                "planar faces taken as patches of the curved surface")


def all_faces_curved(cloud: ObjectCloud, note: str, target: int | None = None
                     ) -> Attempt | None:
    """Return the attempt of the whole object's curvature candidates, every face curved.

    None when the principal curvatures of the object's working points (every k-th, about
    ``target`` of them, when given) propose no primitive, or when the working points have
    no neighbour lists to fit them from (a support plane's, built without a search).
    ``note`` starts the attempt's note (the curvature reason follows).
    """
    if cloud.wc.neighbors.shape[1] < MIN_CURVATURE_NEIGHBOURS:
        return None
    which = np.zeros(len(cloud.wc.points), dtype=bool)
    which[::_every(len(which), target)] = True
    decision = _curved_decision(cloud, which)
    if not decision.candidates:
        return None
    faces = [as_curved(f) for f in cloud.faces]
    return Attempt(dataclasses.replace(cloud, faces=faces), decision,
                   note=f"{note}: {decision.reason}")


def _first_look_normals(cloud: ObjectCloud) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Return every k-th working point (m, 3) [m] and its measured normal (m, 3).

    About :data:`RIVAL_FIT_POINTS` of them: the points a rival's normals are judged on.
    """
    wc = cloud.wc
    look = slice(None, None, _every(len(wc.points), RIVAL_FIT_POINTS))
    return wc.points[look], wc.normals[look]


def _every(n: int, target: int | None) -> int:
    """Step k that leaves about ``target`` of ``n`` items (1: all, also without a target)."""
    return 1 if target is None else max(1, n // max(1, target))


def thinned(cloud: ObjectCloud, target: int = RIVAL_FIT_POINTS) -> ObjectCloud:
    """Return a first-look copy of ``cloud`` thinned to about ``target`` face points.

    Every k-th working point of each face (with its normal) and every k'-th of the
    object's points (the faces' full-resolution points among them), k and k' the counts
    over ``target``; the working cloud and everything else are shared. Its round fits
    skip their full-resolution refinement (``ObjectCloud.first_look``).
    """
    kw = _every(sum(len(f.working) for f in cloud.faces), target)
    kp = _every(len(cloud.points), target)
    faces = []
    for f in cloud.faces:
        normals = f.info.point_normals
        info = dataclasses.replace(f.info, size=len(f.working[::kw]),
                                   point_normals=normals[::kw] if len(normals) == len(
                                       f.working) else normals)
        faces.append(ObjectFace(info, f.summary, f.working[::kw],
                                f.points[f.points % kp == 0] // kp))
    return dataclasses.replace(cloud, points=cloud.points[::kp], faces=faces, first_look=True)


def _apart(cloud: ObjectCloud) -> ObjectCloud:
    """Return ``cloud`` drawing from a copy of its random stream (its own stays as it was)."""
    return dataclasses.replace(cloud, rng=copy.deepcopy(cloud.rng))


def round_rival(cloud: ObjectCloud, box: Primitive
                ) -> tuple[Attempt, Primitive, NDArray[np.int64], NDArray[np.float64],
                           NDArray[np.float64]] | None:
    """Return the round model of all of the object's faces taken as curved, or None.

    Its candidates come from the curvatures of about :data:`RIVAL_FIT_POINTS` working
    points, and it is fitted first on :func:`thinned` faces; None when that fit fails
    its own checks or its mean :func:`truncated_costs` exceed the ``box``'s (on the
    synthetic suite and the real frames measured, no rival the box beat on average went
    on to replace it after the refit, which costs tens of milliseconds on a large box).
    Taken as curved, a can's lid draws a fit's side inwards: an axial first look that
    loses to the box is fitted once more with the planar faces across its axis kept
    planar (:func:`_without_ends`), and the cheaper of the two is the first look. It is
    then refitted on all the faces' points but its ends (the first look's model is kept
    when the refit's mean cost is higher: kinect-real clutter seed 2's lying can r 37.8
    -> 34.3 mm with its ends, true 38.7), and returned with its attempt, the compared
    points' blocks
    (:func:`~.paired_cost.spread_blocks`), the box's :func:`truncated_costs` on them
    (computed once, for the first look and the verdict) and the returned model's.
    """
    attempt = all_faces_curved(cloud, "all faces taken as curved", RIVAL_FIT_POINTS)
    if attempt is None:
        return None
    cheap, _ = fit_first(thinned(attempt.cloud), attempt.decision)
    if cheap is None:
        return None
    c_box, c_cheap = truncated_costs(box, cloud), truncated_costs(cheap, cloud)
    decision = attempt.decision
    if np.mean(c_cheap) > np.mean(c_box):
        cheap, c_cheap, decision = _cheapest_type(cloud, attempt, cheap, c_cheap)
    sides = _without_ends(cloud, attempt.cloud, cheap)
    if np.mean(c_cheap) > np.mean(c_box) and sides is not attempt.cloud:
        again, _ = fit_first(thinned(sides), decision)
        if again is not None:
            c_again = truncated_costs(again, cloud)
            if np.mean(c_again) < np.mean(c_cheap):
                cheap, c_cheap = again, c_again
                sides = _without_ends(cloud, attempt.cloud, cheap)
    if np.mean(c_cheap) > np.mean(c_box):
        return None
    rnd, _ = fit_first(sides, decision)
    if rnd is None:
        return None
    c_round = truncated_costs(rnd, cloud)
    if np.mean(c_round) > np.mean(c_cheap):  # the refit went astray (a flat end seen with
        rnd, c_round = cheap, c_cheap        # the side drew it)
    return attempt, rnd, spread_blocks(every_kth(cloud.points, RIVAL_SAMPLE)), c_box, c_round


def _cheapest_type(cloud: ObjectCloud, attempt: Attempt, first: Primitive,
                   c_first: NDArray[np.float64]
                   ) -> tuple[Primitive, NDArray[np.float64], GraphDecision]:
    """Return the cheapest first look of the attempt's candidate types, its costs and decision.

    :func:`~.units.fit_first` takes the first candidate whose unit accepts it; under a real
    sensor's noise a cone's or frustum's checks pass on a can's side with its lid (taken
    as curved), at an axis tilted by the lid (kinect-real clutter seed 13's can r 31 mm: a
    cone of r 52 mm, mean truncated cost 0.068 against its box's 0.049). When that first
    look ``first`` (its :func:`truncated_costs` ``c_first``) loses to the box, each other
    candidate is fitted alone on the same :func:`thinned` faces (on a copy of the random
    stream: where none costs less, every later fit is as before), and the cheapest on
    average is the first look; the decision returned names that type alone, so that the
    refits keep it.
    """
    best = (first, c_first, attempt.decision)
    for kind in attempt.decision.candidates:
        if kind == first.type:
            continue
        alone = dataclasses.replace(attempt.decision, candidates=(kind,))
        other, _ = fit_first(_apart(thinned(attempt.cloud)), alone)
        if other is None:
            continue
        c_other = truncated_costs(other, cloud)
        if np.mean(c_other) < np.mean(best[1]):
            best = (other, c_other, alone)
    return best


def _without_ends(cloud: ObjectCloud, curved: ObjectCloud, first: Primitive) -> ObjectCloud:
    """Return ``curved`` (``cloud`` with every face taken as curved) with its ends planar.

    The ends are ``cloud``'s planar faces across the axis of the first look ``first`` (a
    cylinder, cone or frustum; :func:`~.axial.across_axis`): taken as curved, a can's lid
    lies in the side's band near its rim, inside it, and draws the side's refit inwards;
    kept planar, it is no side point and may close the side's end.
    """
    if first.type not in (PrimitiveType.CYLINDER, PrimitiveType.CONE,
                          PrimitiveType.FRUSTUM):
        return curved
    ends = {id(f) for f in across_axis(cloud, first.rotation[:, 2])}
    if not ends:
        return curved
    faces = [f if id(f) in ends else g for f, g in zip(cloud.faces, curved.faces)]
    if all(f.info.planar for f in faces):
        return curved
    return dataclasses.replace(curved, faces=faces)


def disc_end(cloud: ObjectCloud, cylinder: Primitive) -> bool:
    """Whether a planar face of ``cloud`` is a disc end of ``cylinder``, all round.

    A face whose normal is within ``angle_tolerance`` of the cylinder's axis, whose points
    all lie inside its circle and whose rim runs round the whole circle but for a gap
    below ``min_arc`` (:func:`~.axial.rim_arc`): a can's lid seen whole. A box's face
    reaches beyond the circle through its sides (its corners), and a cylinder is no box.
    """
    if cylinder.type is not PrimitiveType.CYLINDER:
        return False
    params = cloud.params
    axis, origin, radius = cylinder.rotation[:, 2], cylinder.center, \
        cylinder.dimensions["radius"]
    side = CylinderModel(origin, axis, radius)
    caps = [cloud.points[f.points] for f in across_axis(cloud, axis)]
    arc = rim_arc(caps, side.distance, axis, origin, cloud.spacing, params.ransac_threshold)
    return arc >= 2.0 * math.pi - params.min_arc


def _circle_2d(uv: NDArray[np.float64]) -> tuple[NDArray[np.float64], float] | None:
    """Least-squares circle (Kasa) through 2-D points (k, 2): centre (2,) and radius."""
    if len(uv) < 3:
        return None
    a = np.column_stack([2.0 * uv, np.ones(len(uv))])
    sol, *_ = np.linalg.lstsq(a, np.einsum("ij,ij->i", uv, uv), rcond=None)
    r2 = sol[2] + sol[0] ** 2 + sol[1] ** 2
    return (sol[:2], math.sqrt(r2)) if r2 > 0 else None


def _rectangle_distance(rim: NDArray[np.float64]) -> NDArray[np.float64]:
    """Distances [m] of a convex outline's vertices (m, 2) to its least-area rectangle.

    The rectangle of least area holding the outline has a side along one of the
    outline's edges (rotating calipers); ``rim`` are the vertices of a convex hull in
    order. Each vertex's distance to that rectangle's sides (the nearest one).
    """
    edges = np.roll(rim, -1, axis=0) - rim
    lengths = np.linalg.norm(edges, axis=1)
    keep = lengths > 0
    u = edges[keep] / lengths[keep, None]                 # (E, 2) side directions
    a, b = rim @ u.T, rim @ np.column_stack([-u[:, 1], u[:, 0]]).T  # (m, E) coordinates
    lo_a, hi_a, lo_b, hi_b = a.min(axis=0), a.max(axis=0), b.min(axis=0), b.max(axis=0)
    best = int(np.argmin((hi_a - lo_a) * (hi_b - lo_b)))
    return np.minimum.reduce([a[:, best] - lo_a[best], hi_a[best] - a[:, best],
                              b[:, best] - lo_b[best], hi_b[best] - b[:, best]])


def _round_outline(rim: NDArray[np.float64], centre: NDArray[np.float64], radius: float
                   ) -> bool:
    """Whether a convex outline (its vertices in order, (m, 2) [m]) follows a circle.

    Its vertices lie nearer the circle of ``centre`` (2,) and ``radius`` than the
    least-area rectangle round them (median distances, :func:`_rectangle_distance`).
    """
    return bool(np.median(np.abs(np.linalg.norm(rim - centre, axis=1) - radius))
                < np.median(_rectangle_distance(rim)))


def outline_circle(uv: NDArray[np.float64]) -> tuple[NDArray[np.float64], float] | None:
    """Return the circle (centre (2,), radius [m]) a flat face's outline follows, or None.

    ``uv``: the face's points in its plane (k, 2) [m]. Its outline is their convex hull,
    its circle the least-squares one through the hull's vertices, followed when the
    vertices lie nearer it than the least-area rectangle round them
    (:func:`_round_outline`).
    """
    try:
        hull = ConvexHull(uv)
    except (QhullError, ValueError):
        return None
    rim = uv[hull.vertices]
    circle = _circle_2d(rim)
    if circle is None or not _round_outline(rim, *circle):
        return None
    return circle


def _lid_on_circle(cloud: ObjectCloud, lid: ObjectFace, cylinder: Primitive) -> bool:
    """Whether the outline of ``lid`` (a planar face) follows the circle of ``cylinder``.

    The convex hull of the lid's points projected along the axis, :func:`_round_outline`
    against the cylinder's own circle: a can's lid, whole or with part of it hidden (the
    cut's straight edge adds no vertices between its ends, which lie on the circle); a
    box's top under a cylinder through the box and its neighbour follows a rectangle.
    """
    axis = cylinder.rotation[:, 2]
    uv = (cloud.points[lid.points] - cylinder.center) @ frame_with_z(axis)[:, :2]
    try:
        hull = ConvexHull(uv)
    except (QhullError, ValueError):
        return False
    return _round_outline(uv[hull.vertices], np.zeros(2), cylinder.dimensions["radius"])


def _round_faces(cloud: ObjectCloud, box: Primitive
                 ) -> Iterator[tuple[int, NDArray[np.float64], NDArray[np.float64],
                                     NDArray[np.float64], NDArray[np.float64], float]]:
    """Yield the planar faces across one of the box's axes whose outline follows a circle.

    Largest first; each face's outline is the convex hull of its points in its plane, its
    circle the least-squares one through the hull's vertices (:func:`outline_circle`).
    Yields the box axis's index k, the face's normal (3,), its plane's frame (3, 3) and
    centroid (3,), and the circle's centre (2,) in that frame and radius [m].
    """
    cos_tol = math.cos(cloud.params.angle_tolerance)
    for face in sorted((f for f in cloud.faces if f.info.planar), key=lambda f: -f.info.size):
        n = face.info.normal
        cos = np.abs(box.rotation.T @ n)
        k = int(np.argmax(cos))
        if cos[k] < cos_tol:
            continue
        pts = cloud.points[face.points]
        frame = frame_with_z(n)
        c0 = centroid(pts)
        circle = outline_circle((pts - c0) @ frame[:, :2])
        if circle is not None:
            yield k, n, frame, c0, *circle


def disc_cylinder(cloud: ObjectCloud, box: Primitive,
                  round_faces: list[tuple] | None = None) -> Primitive | None:
    """Return the cylinder whose end is a planar face of the object seen as a disc, or None.

    The largest planar face across one of the box's axes whose outline follows a circle
    (:func:`_round_faces`) is taken as a can's lid: that circle with the box's extent
    along that axis (completed where the box's was, its rmse over the object's points).
    Its outline is the evidence; its rim need not run round the whole circle
    (:func:`disc_end`): under a real sensor's noise the rim of a lid seen whole frays
    (kinect-real clutter seeds 13 and 50: cans of r 31 and 34 mm at 0.56 and 0.95 m,
    cuboids while the rim was asked; their cylinders' radii within 0.9 and 0.1 mm).
    ``round_faces``: those faces when already listed.
    """
    if round_faces is None:
        round_faces = list(_round_faces(cloud, box))
    if not round_faces:
        return None
    k, n, frame, c0, centre2, radius = round_faces[0]
    name = ("length", "width", "height")[k]
    length = box.dimensions[name]
    axis = box.rotation[:, k] * (1.0 if box.rotation[:, k] @ n < 0 else -1.0)
    top = c0 + frame[:, :2] @ centre2
    cyl = Primitive(cloud.oid, PrimitiveType.CYLINDER, top + axis * length / 2.0,
                    frame_with_z(-axis), {"radius": float(radius), "height": float(length)},
                    len(cloud.points), 0.0, completed=("height",) if name in box.completed else ())
    d = surface_distance(cyl, cloud.points)
    return dataclasses.replace(cyl, rmse=float(np.sqrt(np.mean(d * d))))


def prefer_round(situation: Situation, prim: Primitive, faces: tuple[FaceSummary, ...],
                 reasons: list[str]) -> tuple[Primitive, tuple[FaceSummary, ...]]:
    """Return the cuboid ``prim`` or the round model of the whole object, whichever costs less.

    A round side seen up close under depth noise splits into facets that each pass as
    planar, and the facets of a lying cylinder meet at about right angles: a box verifies
    on them (its inlier band holds the facets' bend), and the box of flat cores beats a
    round fit made on part of the faces. The round rival is fitted to all of the object's
    faces taken as curved (:func:`round_rival`; the fits' own checks, inliers and
    scatter against the measured noise, apply); it replaces the box when its
    :func:`truncated_costs` over the same points are lower beyond the noise
    (:func:`~.paired_cost.lower_beyond_noise`: the mean difference against its standard
    error over blocks of neighbouring points, whose depth errors are correlated). Far
    from the sensor the noise band outgrows a small object's shape, and a round model
    may fit a box's points about as well; a real box's edges do not fit a round model
    where the shape shows (its cost stays far above the box's). Within the noise the flat
    end decides: a round rival that is a cylinder, costs less on average and has a disc
    end (:func:`disc_end`) replaces the box too. A box that no round rival replaces meets
    the cylinder of its disc face, if it has one (:func:`_prefer_disc_cylinder`). Only with
    ``noise_model = auto`` (``fixed`` keeps the previous strategies exactly). The
    comparisons are added to ``reasons``.
    """
    cloud = situation.cloud
    if prim.type is not PrimitiveType.CUBOID or cloud.params.noise_model != "auto":
        return prim, faces
    found = round_rival(cloud, prim)
    if found is not None:
        attempt, rnd, blocks, c_box, c_round = found
        lower, stat = lower_beyond_noise(c_round, c_box, blocks)
        disc = not lower and np.mean(c_round) < np.mean(c_box) and disc_end(cloud, rnd)
        verdict = "replaces" if lower or disc else "does not replace"
        reasons.append(f"{attempt.note}; {rnd.type} (cost {np.mean(c_round):.3f}) {verdict} "
                       f"cuboid (cost {np.mean(c_box):.3f}, t = {stat:.1f}"
                       f"{', a disc end' if disc else ''})")
        if lower or disc:
            return rnd, tuple(f.summary for f in attempt.cloud.faces)
    round_faces = list(_round_faces(cloud, prim))
    if round_faces:  # a real box's faces are rectangles: no lid to look below
        below = _lid_cylinder_rival(cloud, prim, reasons)
        if below is not None:
            return below
    held = _prefer_disc_cylinder(cloud, prim, faces, reasons, round_faces)
    if held[0] is not prim:
        return held
    return _face_as_lid(cloud, prim, reasons) or held


def _face_as_lid(cloud: ObjectCloud, box: Primitive, reasons: list[str]
                 ) -> tuple[Primitive, tuple[FaceSummary, ...]] | None:
    """Return the cylinder of one of the box's planar faces taken as its lid, if it holds closer.

    A can seen from above and a side: its side passes as one or two planar faces under a
    real sensor's noise, the box round lid and side verifies, and taken as curved with the
    side the lid draws the round rival off the can (kinect-real clutter seed 5's can of r
    26 mm: a cone of r 48 mm, mean truncated cost 0.042 against its box's 0.025). Each
    planar face about whose normal a circle holds the rest of the object closer than the
    box (:func:`_side_round_about`) is taken in turn as the lid (the main face: the
    cylinder's axis along its normal) and the others as the side, fitted first on
    :func:`thinned` faces (on a copy of the object's random stream); the cheapest on
    average is refitted on all the faces' points (the first look kept when the refit
    costs more) and replaces the box when its :func:`truncated_costs` are lower beyond
    the noise (:func:`~.paired_cost.lower_beyond_noise`). Unlike :func:`prefer_round`'s rivals,
    whose lid is the face the graph or the outline found, it gets no decision within the
    noise by its flat end: any face may be taken as the lid here, and the top of a small
    box far away passes as a disc end under the noise (held-out kinect-real seed 137's
    box of 53 x 42 x 71 mm at 1.04 m: a cylinder of mean cost 0.087 against its poor
    box's 0.101, t = 0.3, its top a disc end all round). Only a box that explains the
    object (at least ``min_inlier_ratio`` of its points within the band) is tried: one
    that does not holds more than one body (kinect-real clutter seed 10's box and can in
    one segment, 73 % of the points in the box's band: a cylinder of r 118 mm round both
    held them closer and kept them in one segment), which the segment's split parts.
    Measured on kinect-real clutter seeds 0-29 (every face tried, no pre-test): of 126
    boxes, 90 gave no cylinder that verifies, one a cylinder of the box's cost (seed 11's
    box 7, 0.041 both), the rest cylinders of 2.2-20 times the box's cost; seed 5's can
    0.012 against 0.025. None when no face gives a cylinder that holds the points closer on
    average; the comparison is added to ``reasons`` when one does.
    """
    c_box = truncated_costs(box, cloud)
    if np.mean(c_box < 1.0) < cloud.params.min_inlier_ratio:
        return None
    best = None
    for i, face in enumerate(cloud.faces):
        if not face.info.planar or not _side_round_about(cloud, box, face):
            continue
        lidded = dataclasses.replace(cloud, faces=[
            f if j == i else as_curved(f) for j, f in enumerate(cloud.faces)])
        decision = GraphDecision("mixed", ("cylinder",), i, reason="a face as the lid")
        look, _ = fit_first(_apart(thinned(lidded)), decision)
        if look is None or look.type is not PrimitiveType.CYLINDER:
            continue
        c_look = truncated_costs(look, cloud)
        if best is None or np.mean(c_look) < np.mean(best[1]):
            best = (look, c_look, lidded, decision)
    if best is None or np.mean(best[1]) >= np.mean(c_box):
        return None
    cyl, c_cyl, lidded, decision = best
    refit, _ = fit_first(_apart(lidded), decision)
    if refit is not None and refit.type is PrimitiveType.CYLINDER:
        c_refit = truncated_costs(refit, cloud)
        if np.mean(c_refit) <= np.mean(c_cyl):
            cyl, c_cyl = refit, c_refit
    lower = _lower_beyond_noise(cloud, c_cyl, c_box, "a face taken as the lid: cylinder",
                                "cuboid", reasons)
    return (cyl, tuple(f.summary for f in lidded.faces)) if lower else None


def _lower_beyond_noise(cloud: ObjectCloud, c_rival: NDArray[np.float64],
                        c_held: NDArray[np.float64], rival: str, held: str,
                        reasons: list[str]) -> bool:
    """Whether a rival's truncated costs are lower than the held model's beyond the noise.

    ``c_rival`` and ``c_held``: :func:`truncated_costs` on the same points of ``cloud``,
    compared by :func:`~.paired_cost.lower_beyond_noise` over their blocks; the comparison
    (the rival named ``rival``, the held model's type ``held``) is added to ``reasons``.
    """
    lower, stat = lower_beyond_noise(c_rival, c_held,
                                     spread_blocks(every_kth(cloud.points, RIVAL_SAMPLE)))
    reasons.append(f"{rival} (cost {np.mean(c_rival):.3f}) "
                   f"{'replaces' if lower else 'does not replace'} {held} (cost "
                   f"{np.mean(c_held):.3f}, t = {stat:.1f})")
    return lower


def _side_round_about(cloud: ObjectCloud, box: Primitive, lid: ObjectFace) -> bool:
    """Whether a circle about ``lid``'s normal holds the rest of the object closer than ``box``.

    The points off the planar face ``lid`` (of every k-th of about :data:`RIVAL_FIT_POINTS`),
    seen along the face's normal, and the circle of least squared distances to them
    (:func:`_geometric_circle`): its mean truncated cost (bands of ``ransac_threshold``)
    below the box's on the same points. A can's side about its lid's normal is that
    circle (kinect-real clutter seeds 5, 13, 45: 0.020 against the box's 0.032, 0.014
    against 0.077, 0.012 against 0.047); a box's sides about one of its faces' normals
    are a rectangle's, which no circle holds as closely as the box (on seeds 0-59, 38 of
    603 faces of boxes pass). A pre-test of :func:`_face_as_lid`: the cylinder below the
    face is fitted only after it.
    """
    t = cloud.params.ransac_threshold
    look = np.zeros(len(cloud.points), dtype=bool)
    look[::_every(len(look), RIVAL_FIT_POINTS)] = True
    look[lid.points] = False
    side = cloud.points[look]
    if len(side) < 3 or t <= 0:
        return False
    circle = _geometric_circle(side @ frame_with_z(lid.info.normal)[:, :2])
    if circle is None:
        return False
    _, _, residuals = circle
    d_box = surface_distance(box, side)
    if d_box is None:
        return True
    return bool(np.mean(np.minimum(np.abs(residuals) / t, 1.0) ** 2)
                < np.mean(np.minimum(d_box / t, 1.0) ** 2))


#: Gauss-Newton steps of :func:`_geometric_circle` at most, and the step [m] (far below a
#: sensor's noise) below which it has converged.
CIRCLE_STEPS, CIRCLE_SETTLED = 8, 1e-5


def _geometric_circle(uv: NDArray[np.float64]
                      ) -> tuple[NDArray[np.float64], float, NDArray[np.float64]] | None:
    """Return the circle of least squared distances to 2-D points (k, 2) [m], or None.

    Started from the algebraic circle (:func:`_circle_2d`, biased towards small radii on
    a short noisy arc) and refined by Gauss-Newton on the distances. Returns its centre
    (2,), radius and the points' signed distances (k,) to it.
    """
    start = _circle_2d(uv)
    if start is None:
        return None
    centre, radius = np.asarray(start[0], dtype=np.float64), start[1]
    for _ in range(CIRCLE_STEPS):
        d = uv - centre
        rho = np.maximum(np.linalg.norm(d, axis=1), 1e-12)
        jac = np.column_stack([-d / rho[:, None], -np.ones(len(uv))])
        try:
            step = np.linalg.solve(jac.T @ jac, jac.T @ (radius - rho))
        except np.linalg.LinAlgError:
            return None
        centre, radius = centre + step[:2], radius + float(step[2])
        if not np.all(np.isfinite(step)) or np.abs(step).max() < CIRCLE_SETTLED:
            break
    if not (np.all(np.isfinite(centre)) and math.isfinite(radius)):
        return None
    return centre, abs(radius), np.linalg.norm(uv - centre, axis=1) - abs(radius)


def _lid_cylinder_rival(cloud: ObjectCloud, box: Primitive, reasons: list[str]
                        ) -> tuple[Primitive, tuple[FaceSummary, ...]] | None:
    """Return the cylinder below the box's largest plane if it holds the points closer, or None.

    A can seen from above with part of its lid hidden (by another object, or cut by the
    image's edge): taken as curved, the lid draws the round rival's fits off the side, and
    the lid is no disc all round. Its largest plane taken as the lid and the rest as its
    side give the can's cylinder when the lid is a disc end or its outline follows the
    circle (:func:`lid_cylinder`); it replaces the box when its mean
    :func:`truncated_costs` over the object's points are lower. As for the round rival with
    a disc end (:func:`prefer_round`), the flat end decides within the noise: the side
    strip that tells a can from a box is a narrow band of the object (measured: 111 of 685
    points of a can 0.9 m away in noise-free clutter), so the box's excess lies in a few
    of the 16 blocks of :func:`~.paired_cost.lower_beyond_noise`, and an excess alike in m
    of them gives the statistic 4 sqrt(m / (16 - m)) whatever its size: at most 1.9 for
    three blocks, below the test's 2.1. The statistic is still reported. :func:`prefer_round`
    tries it only when one of the box's faces has a round outline (:func:`_round_faces`);
    as for the round rival, a first look on :func:`thinned` faces that costs no less than
    the box on average ends the attempt before the refinement. The comparison is added to
    ``reasons``.
    """
    split = _lid_and_side(cloud)
    if split is None:
        return None
    c_box = truncated_costs(box, cloud)
    look, _ = fit_first(_apart(thinned(split)), _LID_AND_SIDE)
    if look is None or look.type is not PrimitiveType.CYLINDER or \
            np.mean(truncated_costs(look, cloud)) >= np.mean(c_box):
        return None
    found = lid_cylinder(cloud, split=split)
    if found is None:
        return None
    cyl, split = found
    c_cyl = truncated_costs(cyl, cloud)
    _, stat = lower_beyond_noise(c_cyl, c_box,
                                 spread_blocks(every_kth(cloud.points, RIVAL_SAMPLE)))
    lower = bool(np.mean(c_cyl) < np.mean(c_box))
    reasons.append(f"the cylinder below its largest plane (cost {np.mean(c_cyl):.3f}) "
                   f"{'replaces' if lower else 'does not replace'} cuboid (cost "
                   f"{np.mean(c_box):.3f}, t = {stat:.1f})")
    return (cyl, tuple(f.summary for f in split.faces)) if lower else None


def _prefer_disc_cylinder(cloud: ObjectCloud, box: Primitive, faces: tuple[FaceSummary, ...],
                          reasons: list[str], round_faces: list[tuple] | None = None
                          ) -> tuple[Primitive, tuple[FaceSummary, ...]]:
    """Return the cylinder of the box's disc face (:func:`disc_cylinder`) if it costs less.

    A can seen mostly by its lid, its side a few grazing slivers (or facets that pass as
    planar), gives no round fit, and the box round the lid verifies. The lid's outline
    is the can's circle: the cylinder of that circle, as long as the box along its axis,
    replaces the box when its mean :func:`truncated_costs` over the object's points are
    lower (a real box's top whose outline the noise band lets pass as a disc keeps its
    box: its sides and corners cost the cylinder far more). ``round_faces``: the box's
    faces of :func:`_round_faces` when already listed.
    """
    disc = disc_cylinder(cloud, box, round_faces)
    if disc is None:
        return box, faces
    return _cheaper(cloud, (box, faces), (disc, faces), "the cylinder of its disc face", reasons)


def round_of_plane(situation: Situation, plane: Primitive, reasons: list[str]
                   ) -> tuple[Primitive, tuple[FaceSummary, ...]] | None:
    """Return the round model of an object fitted as a plane, with its faces, or None.

    A small round body far from the sensor under a real sensor's noise: the band of its
    range (``ransac_threshold``) holds the whole visible side of a ball, a cone or a
    lying can, its one face passes as planar, and a plane verifies, lying through the body
    (measured: balls 30-45 mm across at 0.8-1.2 m in kinect-real clutter, truncated cost
    0.12-0.17 against 0.01 for the sphere). The round model of the object's face taken as
    curved (:func:`round_rival`, with the fits' own checks) is returned when it holds
    the points closer than the plane beyond the noise (:func:`truncated_costs`,
    :func:`~.paired_cost.lower_beyond_noise`) and the measured normals follow it: at
    least ``min_inlier_ratio`` of the working points' normals (every k-th, about
    :data:`RIVAL_FIT_POINTS`) within ``angle_tolerance`` of its surface's
    (:func:`~geomodel_ros.core.confidence.surface_normals`), as its points lie within the
    band. A flat surface bent by slow sensor errors (a wall, a carton's side) may be held
    closer by a wide cone or cylinder, but its normals do not turn with that model's. Only
    with ``noise_model = auto``; the comparison is added to ``reasons`` when a round model
    was found. The plane stays the segmentation's (a face cut off a body is joined to it
    as a plane): the modeling puts this model in its place once the segmentation is done
    (``Primitive.round_alternative``).
    """
    cloud = situation.cloud
    params = cloud.params
    if plane.type is not PrimitiveType.PLANE or params.noise_model != "auto":
        return None
    found = round_rival(cloud, plane)
    if found is None:
        return None
    attempt, rnd, blocks, c_plane, c_round = found
    closer, stat = lower_beyond_noise(c_round, c_plane, blocks)
    points, normals = _first_look_normals(cloud)
    model = surface_normals(rnd, points)
    share = 0.0 if model is None else float(np.mean(
        normal_costs(model, normals, params.angle_tolerance) < 1.0))
    follow = share >= params.min_inlier_ratio
    verdict = "replaces" if closer and follow else "does not replace"
    reasons.append(f"{attempt.note}; {rnd.type} (cost {np.mean(c_round):.3f}, "
                   f"{share:.0%} of the normals within its tolerance) {verdict} plane "
                   f"(cost {np.mean(c_plane):.3f}, t = {stat:.1f})")
    if not (closer and follow):
        return None
    return rnd, tuple(f.summary for f in attempt.cloud.faces)


def box_of_plane(situation: Situation, plane: Primitive, reasons: list[str]
                 ) -> tuple[Primitive, tuple[FaceSummary, ...]] | None:
    """Return the box (or the round model it gives way to) of a folded plane, or None.

    Far from the sensor under a real sensor's noise the crease between two sides of a
    small box (or between a can's lid and a strip of its side) blurs, the face
    segmentation keeps both as one planar face, and a plane verifies through them: its
    band holds the fold (measured: boxes 40-115 mm at 0.7-1.2 m in kinect-real clutter,
    plane rmse 4-10 mm, truncated cost 0.06-0.23 against 0.01-0.03 for the box). The
    measured normals still gather on the sides: the box of their modes
    (:func:`normal_box_rival`, two sides along different axes at least, from the first
    look's normals, :func:`_first_look_normals`) is fitted when most of the working
    points' normals face one of its sides (:data:`BOX_NORMALS_MIN_SHARE`, as for planar
    faces without a rule: a ball's or a cone's normals turn across the sides'
    directions), and it replaces the plane as :func:`round_of_plane`'s round model does
    when its :func:`truncated_costs` are lower beyond the noise
    (:func:`~.paired_cost.lower_beyond_noise`). A flat surface, bent or not, shows one
    mode of normals and has no such box. The box then meets its round rivals as any box
    does (:func:`prefer_round`). Only with ``noise_model = auto``; the comparison is
    added to ``reasons`` when the box is fitted.
    """
    cloud = situation.cloud
    params = cloud.params
    if plane.type is not PrimitiveType.PLANE or params.noise_model != "auto":
        return None
    axes = box_axes(_first_look_normals(cloud)[1], params.angle_tolerance)
    rival = None if axes is None else normal_box_rival(cloud, axes)
    if rival is None:
        return None
    share = sum(len(f.working) for f in rival.cloud.faces) / len(cloud.wc.points)
    if share < BOX_NORMALS_MIN_SHARE:
        return None
    box, _ = fit_first(rival.cloud, rival.decision)
    if box is None:
        return None
    c_plane, c_box = truncated_costs(plane, cloud), truncated_costs(box, cloud)
    closer, stat = lower_beyond_noise(c_box, c_plane,
                                      spread_blocks(every_kth(cloud.points, RIVAL_SAMPLE)))
    verdict = "replaces" if closer else "does not replace"
    reasons.append(f"{rival.note}; cuboid (cost {np.mean(c_box):.3f}, {share:.0%} of the "
                   f"normals on its sides) {verdict} plane (cost {np.mean(c_plane):.3f}, "
                   f"t = {stat:.1f})")
    if not closer:
        return None
    faces = tuple(f.summary for f in rival.cloud.faces)
    return prefer_round(Situation(rival.cloud, rival.decision), box, faces, reasons)


def _lid_and_side(cloud: ObjectCloud, up: NDArray[np.float64] | None = None
                  ) -> ObjectCloud | None:
    """Return ``cloud`` with two faces, its lid (planar) and its side (curved), or None.

    The lid is the plane RANSAC finds with the most of the object's working points (within
    ``ransac_threshold`` and ``ransac_normal_threshold``), the side the other points; None
    when no plane is found or it holds all of them. With ``up`` (3,), a support's normal,
    the lid is sought among the working points whose normals lie within
    ``angle_tolerance`` of it (a standing can's lid faces up). The object's random stream
    is left as it was: the returned cloud draws from a copy.
    """
    params, wc = cloud.params, cloud.wc
    rng = copy.deepcopy(cloud.rng)
    rows = np.arange(len(wc.points)) if up is None else \
        np.flatnonzero(np.abs(wc.normals @ up) >= math.cos(params.angle_tolerance))
    if len(rows) < PlaneModel.sample_size:
        return None
    found = ransac(PlaneModel, wc.points[rows], wc.normals[rows], params.ransac_threshold,
                   params.ransac_normal_threshold, params.ransac_max_iterations,
                   params.ransac_confidence, rng)
    if found is None:
        return None
    lid = np.zeros(len(wc.points), dtype=bool)
    lid[rows[found.inliers]] = True
    if lid.all() or not lid.any():
        return None
    fs = faces_from_labels(wc, np.where(lid, 0, 1)[wc.point_to_working])
    faces = describe_faces(wc, fs, params, planar=(True, False))
    return dataclasses.replace(cloud, faces=faces, adjacency=fs.adjacency, rng=rng)


#: The cylinder unit on a lid and its side (:func:`_lid_and_side`).
_LID_AND_SIDE = GraphDecision("mixed", ("cylinder",), 0, reason="a lid and its side")


def lid_cylinder(cloud: ObjectCloud, split: ObjectCloud | None = None
                 ) -> tuple[Primitive, ObjectCloud] | None:
    """Return the cylinder below the object's lid, with the object as fitted, or None.

    The object as its lid and its side (:func:`_lid_and_side`, or ``split`` when given:
    its result), and the cylinder unit fitting the side with its axis along the lid's
    normal (the main face's, :func:`~.curved.axis_prior`). The cylinder, when it verifies
    and the lid is a disc end of it all round (:func:`disc_end`) or its outline follows
    the circle (:func:`_lid_on_circle`: part of the lid may be hidden; a noisy lid seen
    whole may pass the one test and not the other).
    """
    split = _lid_and_side(cloud) if split is None else split
    if split is None:
        return None
    cyl, _ = fit_first(split, _LID_AND_SIDE)
    if cyl is None or cyl.type is not PrimitiveType.CYLINDER:
        return None
    if not (disc_end(split, cyl) or _lid_on_circle(split, split.faces[0], cyl)):
        return None
    return cyl, split


def lid_cylinder_alone(cloud: ObjectCloud, reasons: list[str]
                       ) -> tuple[Primitive, tuple[FaceSummary, ...]] | None:
    """Return the cylinder below the lid of an object no strategy fitted, or None.

    The lid and side of :func:`lid_cylinder`, the lid a disc end all round or its outline
    following the cylinder's circle (part of it may be hidden, as in
    :func:`_lid_cylinder_rival`): cans whose lid joined their side and whose faces
    fit no rule (facets that meet at no right angles) or whose round fits failed.
    Nothing competes, but a ball's cap passes as a lid under the noise and the cylinder
    below it verifies: it is kept only when its :func:`truncated_cost` is lower than that
    of the sphere least squares fits to the whole object (:func:`_rival_sphere`;
    unverified: a rival, not a result). Only with ``noise_model = auto``; the comparison
    is added to ``reasons``.
    """
    if cloud.params.noise_model != "auto":
        return None
    found = lid_cylinder(cloud)
    if found is None:
        return None
    cyl, split = found
    sphere = _rival_sphere(cloud)
    c_cyl = truncated_cost(cyl, cloud)
    c_sphere = 1.0 if sphere is None else truncated_cost(sphere, cloud)
    verdict = "kept" if c_cyl < c_sphere else "not kept"
    reasons.append(f"the cylinder below its lid (cost {c_cyl:.3f}) {verdict} against a "
                   f"sphere (cost {c_sphere:.3f})")
    return (cyl, tuple(f.summary for f in split.faces)) if c_cyl < c_sphere else None


def _rival_sphere(cloud: ObjectCloud) -> Primitive | None:
    """Return the sphere least squares fits to all of the object's faces (unverified), or None.

    :func:`~.curved.fit_curved` with every face taken as curved (RANSAC and refinement),
    from a copy of the object's random stream.
    """
    curved = dataclasses.replace(cloud, faces=[as_curved(f) for f in cloud.faces],
                                 rng=copy.deepcopy(cloud.rng))
    side = fit_curved(curved, PrimitiveType.SPHERE, SphereModel, sphere_test(cloud.params),
                      with_caps=False)
    if not isinstance(side, CurvedFit):
        return None
    return Primitive(cloud.oid, PrimitiveType.SPHERE, side.model.center.copy(), np.eye(3),
                     {"radius": float(side.model.radius)}, len(cloud.points), side.rmse)


def prefer_lid_cylinder(situation: Situation, prim: Primitive,
                        faces: tuple[FaceSummary, ...], reasons: list[str]
                        ) -> tuple[Primitive, tuple[FaceSummary, ...]]:
    """Return the cone or frustum ``prim`` or the cylinder below a lid, whichever costs less.

    A can seen from above where the noise band is a large share of its radius: its lid
    and the grazing strips of its side are one curved face (the normals turn smoothly
    over the rim under the noise), no cylinder holds that face (the lid scatters far off
    any side), and a wide cone through lid and side verifies -- of two to three times
    the can's radius. Told apart, the lid is the object's largest plane and the side the
    rest: the cylinder of that side with its axis along the lid's normal
    (:func:`lid_cylinder`; the lid a disc end all round or its outline following the
    cylinder's circle, as the noise may take the one or the other from a lid seen whole)
    replaces ``prim`` when its mean :func:`truncated_costs` over the object's points are
    lower. A real cone or cup has no plane that is the lid of a cylinder holding the rest
    (the unit's checks refuse it), or costs a cylinder more. When that cylinder does not
    replace ``prim`` and the largest plane does not face up, the lid facing up may
    (:func:`_lid_facing_up`, beyond the noise). Only with ``noise_model = auto``; the
    comparisons are added to ``reasons``.
    """
    cloud = situation.cloud
    if prim.type not in (PrimitiveType.CONE, PrimitiveType.FRUSTUM) or \
            cloud.params.noise_model != "auto":
        return prim, faces
    largest = _lid_and_side(cloud)
    found = None if largest is None else lid_cylinder(cloud, split=largest)
    if found is not None:
        cyl, split = found
        held = _cheaper(cloud, (prim, faces), (cyl, tuple(f.summary for f in split.faces)),
                        "the cylinder below its lid", reasons)
        if held[0] is not prim:
            return held
    return _lid_facing_up(cloud, prim, largest, reasons) or (prim, faces)


def _lid_facing_up(cloud: ObjectCloud, prim: Primitive, largest: ObjectCloud | None,
                   reasons: list[str]) -> tuple[Primitive, tuple[FaceSummary, ...]] | None:
    """Return the cylinder below the plane that faces up, if it holds closer beyond the noise.

    For a cone or frustum ``prim`` standing on a support (:func:`support_below`) whose
    largest plane (``largest``, :func:`_lid_and_side`) does not face along the support's
    normal (within ``angle_tolerance``): under a real sensor's noise the largest plane may
    lie through a can's side (held-out kinect-real seed 107's can of r 29.5 mm at 0.99 m:
    88 deg off its axis, a cone of r 58 mm kept), and the lid is the plane of the points
    whose normals face up (:func:`_lid_and_side` with the support's normal). Its cylinder
    (:func:`lid_cylinder`) replaces ``prim`` only when its :func:`truncated_costs` are
    lower beyond the noise (:func:`~.paired_cost.lower_beyond_noise`): a pot's top faces
    up too, and far away the cylinder below it holds a gentle taper within the noise
    band about as closely as the frustum. None otherwise; the comparison is added to
    ``reasons`` when a cylinder is found.
    """
    up = support_below(cloud)
    cos_tol = math.cos(cloud.params.angle_tolerance)
    if up is None or (largest is not None and
                      abs(float(largest.faces[0].info.normal @ up)) >= cos_tol):
        return None
    lidded = _lid_and_side(cloud, up)
    found = None if lidded is None else lid_cylinder(cloud, split=lidded)
    if found is None:
        return None
    cyl, split = found
    lower = _lower_beyond_noise(cloud, truncated_costs(cyl, cloud), truncated_costs(prim, cloud),
                                "the cylinder below its lid facing up", prim.type.value,
                                reasons)
    return (cyl, tuple(f.summary for f in split.faces)) if lower else None


class BoxOfFlatCores:
    """The box of the flat cores (:func:`box_rival`) of an object no round model explains.

    A round fit that verifies competes with this box in :func:`prefer_box`. When no
    round fit verified and a round model was found that does not explain the points
    (``Rejected.misfit``: too few inliers, or a scatter beyond the measured noise; e.g. a
    carton whose gable merged with a side into one curved face), or the curved faces'
    curvatures fit no round primitive at all (``Situation.no_round_shape``: e.g. a box
    side bent over an edge into its neighbour by sensor errors, whose principal
    curvatures are neither developable nor spherical), the box is fitted on its own and
    kept if it passes the cuboid unit's verification. Objects with a round shape that
    was not rejected as a misfit, or without flat cores aligned as a box, are not given a
    box this way.
    """

    name = "box of the flat cores"

    def applies(self, situation: Situation) -> bool:
        """Return True when no round model explains the points and a box rival exists."""
        return (situation.round_misfit or situation.no_round_shape) and \
            situation.box_rival is not None

    def attempt(self, situation: Situation) -> Attempt:
        """Fit the cuboid to the box rival's sides."""
        rival = situation.box_rival
        return Attempt(rival.cloud, rival.decision,
                       note=f"no round model explains the points; {rival.note}")


def planar_without_rule(situation: Situation) -> bool:
    """Tell whether two or more planar faces fit no rule of the model graph (``auto`` noise)."""
    d = situation.decision
    return (situation.cloud.params.noise_model == "auto" and d.category == "planar"
            and not d.candidates and len(situation.cloud.faces) > 1)


class PlanarFacesWithoutRule:
    """The box of the point normals' modes for planar faces that fit no rule.

    Far from the sensor the noise cuts a box's sides, and a round side, into facets that
    each pass as planar but meet at no right angles: the model graph has no rule for
    them ("planar faces not aligned with three orthogonal axes"). The faces are then no
    evidence; the measured normals of the whole object are (:func:`normal_box_rival`:
    a box's normals gather about its three axes). The box is fitted to the sides its
    normals' modes give and, like every cuboid, compared with the round model of all
    the object's faces (:func:`prefer_round`: the round one replaces it when its costs
    are lower beyond the noise). As the faces are no evidence, the normals must be
    strong evidence: it is tried only when most of them face one of its sides
    (:data:`BOX_NORMALS_MIN_SHARE`; a round side's normals turn across the sides'
    directions) and they show sides along all three axes (a corner of the box, as the
    sides of :data:`~.normal_box.MIN_SIDE_NORMALS` normals each). Only with
    ``noise_model = auto``.
    """

    name = "planar faces without a rule"
    #: Begins the attempt's note (the reasons say why the normals' box was tried).
    note_prefix = "planar faces without a rule"

    def applies(self, situation: Situation) -> bool:
        """Return True for planar faces without a candidate (``auto`` noise)."""
        return planar_without_rule(situation)

    def attempt(self, situation: Situation) -> Attempt | None:
        """Fit the cuboid to the sides of the point normals' modes, if most face them."""
        cloud = situation.cloud
        tol = cloud.params.angle_tolerance
        axes = box_axes(cloud.wc.normals, tol)
        if axes is None:
            return None
        labels = side_labels(cloud.wc.normals, axes, tol)
        sides = np.flatnonzero(np.bincount(labels[labels >= 0], minlength=6)
                               >= MIN_SIDE_NORMALS)
        if np.mean(labels >= 0) < BOX_NORMALS_MIN_SHARE or len(set(sides // 2)) < 3:
            return None
        rival = normal_box_rival(cloud, axes)
        if rival is None:
            return None
        return Attempt(rival.cloud, rival.decision, note=f"{self.note_prefix}; {rival.note}")


def faces_in_box_frame(cloud: ObjectCloud) -> tuple[BoxCorner, NDArray[np.bool_]] | None:
    """Return the corner of ``cloud``'s planar faces and which faces (F,) its frame holds.

    The frame: the axes of the corner of the largest face and its largest perpendicular
    neighbour (:func:`~geomodel_ros.core.model_graph.box_corner`), made orthogonal as the
    cuboid unit makes them (:func:`~.obb.orthonormalize_axes`, weighted by the faces'
    working points) from the faces within the angle tolerance of them: the turned faces do
    not turn the frame. Every face lies across its nearest axis; it is held when at least
    ``min_inlier_ratio`` of its working points lie within ``ransac_threshold`` of the plane
    across that axis through their centroid. None without such a corner.
    """
    params = cloud.params
    infos = [f.info for f in cloud.faces]
    corner = box_corner(infos, cloud.adjacency, params.angle_tolerance)
    if corner is None:
        return None
    weights = np.array([float(len(f.working)) for f in cloud.faces])
    aligned = corner.aligned & ~corner.sliver
    rot = obb.orthonormalize_axes(np.array([i.normal for i in infos])[aligned],
                                  weights[aligned], corner.assignment[aligned])
    held = np.zeros(len(infos), dtype=bool)
    for k, (f, axis) in enumerate(zip(cloud.faces, corner.assignment)):
        across = cloud.wc.points[f.working] @ rot[:, axis]
        held[k] = np.mean(np.abs(across - across.mean()) <= params.ransac_threshold) \
            >= params.min_inlier_ratio
    return corner, held


class FacesInBoxFrame:
    """A box whose smaller faces the noise turned beyond the angle tolerance.

    The model graph takes planar faces for a box when each lies within ``angle_tolerance``
    of the axes of the corner its largest face makes with its largest perpendicular
    neighbour. A small face seen obliquely turns further under a real sensor's noise
    (osd_learn learn17 and learn18: a box under another, seen in pieces round it, one
    face 10 and 14 deg off its axis: `unknown`). What the tolerance stands for is whether
    the box's plane holds the face's points: the box frame of the faces within the
    tolerance is tried when it holds every face but slivers (:func:`faces_in_box_frame`,
    the cuboid unit's inlier bar); the turned faces fit no axis (their points size the
    box), nor does a sliver, as in the graph. Tried last
    (:data:`LAST_STRATEGIES`: a can whose lid and side facets pass as such faces has its
    cylinder below the lid first). Only with ``noise_model = auto``.
    """

    name = "the faces in their box frame"

    def applies(self, situation: Situation) -> bool:
        """Return True for planar faces at a corner not all within the angle tolerance."""
        return situation.cloud.params.noise_model == "auto" and \
            situation.decision.reason == NOT_ALIGNED

    def attempt(self, situation: Situation) -> Attempt | None:
        """Fit the cuboid on the corner's axes when their frame holds the faces."""
        cloud = situation.cloud
        framed = faces_in_box_frame(cloud)
        if framed is None:
            return None
        corner, held = framed
        if not np.all(held | corner.sliver):
            return None
        note = "their box frame holds each face within the noise"
        decision = cuboid_decision([f.info for f in cloud.faces], cloud.adjacency, corner,
                                   corner.aligned, note)
        return Attempt(cloud, decision, note=note)


class NormalsBoxAfterAll(PlanarFacesWithoutRule):
    """The box of the point normals' modes for an object nothing else fitted.

    Under the noise a box's sides may also pass as curved faces whose round fits all fail
    (Kinect-class clutter seed 46: a box 109 x 53 x 42 mm, "k2 ~ 0, k1 varies"); its
    measured normals still gather about its three axes. Tried last (after every other
    strategy and the cylinder below a lid, :data:`LAST_STRATEGIES`), with the evidence
    :class:`PlanarFacesWithoutRule` asks of the normals (most of them facing the box's
    sides, sides along all three axes), for the objects that strategy did not apply to.
    """

    name = "the box of the point normals after all"
    note_prefix = "no strategy fitted"

    def applies(self, situation: Situation) -> bool:
        """Return True with ``auto`` noise where :class:`PlanarFacesWithoutRule` did not apply."""
        return situation.cloud.params.noise_model == "auto" and \
            not PlanarFacesWithoutRule.applies(self, situation)


class UprightBoxOnSupport:
    """A box standing on a support, its faces turned by the noise beyond every rule.

    A small box seen from above at 0.7 m under kinect-real noise shows its top and a strip
    of one side; the noise of a few millimetres across a patch a few centimetres wide
    turns the strip's fitted normal far from the side's (kinect-real clutter seed 70's box
    42 x 47 x 47 mm: the top 4.6 deg from the desk's normal, the strip 47.9 deg from it):
    "planar faces neither perpendicular nor parallel to the main face", no corner, too few
    sides for the box of the point normals, and the segment, left ``unknown``, was then
    taken out as a fragment. A box resting on a support stands upright on it: its axis 2
    is the support's normal (:func:`support_below`) when a face (no sliver) lies within
    ``angle_tolerance`` of it (a top seen), and its axes 0 and 1 are the side faces'
    directions about that normal (:func:`~geomodel_ros.core.obb.upright_axes`: every
    other face is a side, on the axis across the normal nearest to its own). As for
    :class:`FacesInBoxFrame`, the frame is the evidence only where it holds each face
    (but slivers): ``min_inlier_ratio`` of its working points within
    ``ransac_threshold`` of the plane across its axis through their median. The cuboid is
    then fitted in that frame (``axis_prior``: the faces' planes keep the frame's
    normals, :func:`~.cuboid.fit_cuboid`) and meets the round model of all the faces as
    every cuboid does (:func:`prefer_round`). Tried last, only for otherwise ``unknown``
    objects; only with ``noise_model = auto``.
    """

    name = "a box upright on its support"

    def applies(self, situation: Situation) -> bool:
        """Return True for two or more planar faces without a candidate (``auto`` noise)."""
        return planar_without_rule(situation)

    def attempt(self, situation: Situation) -> Attempt | None:
        """Fit the cuboid upright on the support below when its frame holds every face."""
        cloud = situation.cloud
        up = support_below(cloud)
        framed = None if up is None else upright_frame(cloud, up)
        if framed is None:
            return None
        rot, assignment = framed
        thr, share = cloud.params.ransac_threshold, cloud.params.min_inlier_ratio
        for f, axis in zip(cloud.faces, assignment):
            h = cloud.wc.points[f.working] @ rot[:, axis] if axis >= 0 else None
            if h is not None and np.mean(np.abs(h - np.median(h)) <= thr) < share:
                return None
        note = "the box upright on its support holds each face within the noise"
        main = int(np.argmax([f.info.size for f in cloud.faces]))
        decision = GraphDecision("planar", (PrimitiveType.CUBOID,), main,
                                 tuple(int(a) for a in assignment), note)
        return Attempt(cloud, decision, axis_prior=up, note=note)


def upright_frame(cloud: ObjectCloud, up: NDArray[np.float64]
                  ) -> tuple[NDArray[np.float64], NDArray[np.int64]] | None:
    """Return the frame (3, 3) of a box upright along ``up`` (3,) and each face's axis (F,).

    Faces within ``angle_tolerance`` of ``up`` are on axis 2, slivers on none (-1), the
    others on the axis across ``up`` nearest to their normals, the first axis being the
    direction of the largest of them; the frame then follows all of them
    (:func:`~geomodel_ros.core.obb.upright_axes`, weighted by their working points).
    None unless a face (no sliver) lies on axis 2 and another does not.
    """
    sizes = np.array([float(len(f.working)) for f in cloud.faces])
    normals = np.array([f.info.normal for f in cloud.faces])
    sliver = sizes < SLIVER_SHARE * sizes.sum()
    on_up = np.abs(normals @ up) >= math.cos(cloud.params.angle_tolerance)
    sides = np.flatnonzero(~on_up & ~sliver)
    if not np.any(on_up & ~sliver) or not sides.size:
        return None
    largest = np.full(len(sizes), -1)
    largest[sides[np.argmax(sizes[sides])]] = 0
    across = np.abs(normals @ obb.upright_axes(up, normals, sizes, largest)[:, :2])
    assignment = np.where(sliver, -1, np.where(on_up, 2, np.argmax(across, axis=1)))
    return obb.upright_axes(up, normals, sizes, assignment), assignment


class DoublyCurvedAsSphere:
    """Try a sphere on an object whose surface is curved two ways, when nothing else fitted.

    A cylinder, cone or frustum bends around its axis only; a sphere bends along every
    direction. Two observations show the second bend when no strategy typed the object:
    an axial model whose side's profile bows (:func:`~.verify.check_profile_bow`: its
    tangent turns by more than ``min_arc`` along the axis, significantly; the profile of a
    sphere is a circle arc), or principal curvatures whose ratio lies between the
    developable and the spherical bound (:attr:`Situation.no_round_shape`; depth noise
    pulls the smaller curvature of a sphere's points down, the larger one up). A small
    sphere far from the sensor shows both: part of its cap passes as planar, or its
    curvature ratio falls below ``sphere_curvature_ratio``. Every face is then taken as
    curved and the sphere unit's own checks (inliers, radius, scatter against the
    measured noise) decide; a torus, whose profile bows as well, scatters about its best
    sphere far beyond the noise. Tried after every strategy that might type the object
    otherwise (only :class:`AllFacesCurvedAfterAll` follows), so it only types objects
    that would otherwise be ``unknown``; only with ``noise_model = auto`` (``fixed`` keeps the
    previous strategies exactly).
    """

    name = "doubly curved as a sphere"

    def applies(self, situation: Situation) -> bool:
        """Return True when a bowed profile or non-developable curvatures were seen."""
        if situation.cloud.params.noise_model != "auto":
            return False
        bowed = any(bowed_profile(r) for r in situation.rejected)
        return bowed or (situation.no_round_shape and
                         situation.fit_decision.reason != NO_CURVATURE)

    def attempt(self, situation: Situation) -> Attempt:
        """Fit a sphere to every face taken as curved."""
        cloud = situation.cloud
        bowed = any(bowed_profile(r) for r in situation.rejected)
        why = "a side's profile bows" if bowed else \
            "curvatures neither developable nor spherical"
        faces = [as_curved(f) for f in cloud.faces]
        return Attempt(dataclasses.replace(cloud, faces=faces),
                       GraphDecision("curved", (PrimitiveType.SPHERE.value,), -1, (), why),
                       note=f"curved two ways ({why}): every face taken as curved")


class AllFacesCurvedAfterAll:
    """Every face of an untyped object taken as curved, when nothing else fits.

    A planar face of a mixed object whose bend stays within the frame's noise is taken
    for a true flat end (a lid, a base) and the mixed rules apply
    (:class:`PlanarPatchesOfCurvedObjects`). Far from the sensor a small patch of a round
    surface bends within the noise as well (a ball at 1.5 m under slow sensor errors: a
    48-point patch on its top and the cone and cylinder of the mixed rules, their axes
    along its normal, fail). When every strategy before this one found no model, the
    flat-end reading has failed and the patch's flatness is no evidence against the
    curved one: every face of a mixed object is taken as curved and the candidates of
    the object's principal curvatures are fitted, under their units' own checks, and the
    round model meets the box of the flat cores as every round fit does
    (:func:`prefer_box`). Whatever share the planar faces hold: a lying can whose side
    came as a curved face and a larger facet that passed as planar gets round fits whose
    axis must follow the facet's normal, as a cap's, and all fail ("axis not aligned with
    its planar face"; Kinect-class clutter seed 47's can, r 25.8 mm, `unknown` before).
    The same holds for an object whose faces all passed as planar: a small round
    body at 0.7-1.2 m under slow sensor errors comes as two or three facets meeting at
    no right angle (no rule of the model graph, no box of its normals' modes), or as one
    face whose plane its points scatter beyond the noise about. Tried last, so it
    changes only objects otherwise left ``unknown``; only with ``noise_model = auto``.
    A first look on :func:`thinned` faces (candidates from about
    :data:`RIVAL_FIT_POINTS` working points) must fit before the full fit is tried: most
    objects that reach this strategy are no primitive (a torus, a bottle pack) and every
    fit on them fails (the suite's tori: 174 -> 63 ms over 18 frames; the office: 132 -> 84 ms).
    """

    name = "nothing fitted, all faces curved"

    def applies(self, situation: Situation) -> bool:
        """Return True for a mixed object, or one of planar faces only.

        The latter only when its points do not lie within one plane's inlier band,
        ``ransac_threshold`` either side of it (as a box must be thicker than a
        threshold, :func:`~.verify.check_thickness`): a plane explains such points as
        well as any bend. Pieces of walls at 3.5-4 m under kinect-real noise, 1.1-1.4
        thresholds thick, took cones and cylinders of 80-254 mm radius; the small round
        bodies this serves are 2.4-4 thresholds thick.
        """
        cloud = situation.cloud
        if cloud.params.noise_model == "auto" and situation.decision.category == "mixed":
            return True
        return (cloud.params.noise_model == "auto" and situation.decision.category == "planar"
                and _thickness(cloud.wc.points) > 2.0 * cloud.params.ransac_threshold)

    def attempt(self, situation: Situation) -> Attempt | None:
        """Take every face as curved and propose the curvatures' candidates."""
        note = ("planar and curved faces that fit nothing"
                if situation.decision.category == "mixed"
                else "planar faces that fit nothing") + ", all faces taken as curved"
        attempt = all_faces_curved(situation.cloud, note, RIVAL_FIT_POINTS)
        if attempt is None or fit_first(thinned(attempt.cloud), attempt.decision)[0] is None:
            return None
        return all_faces_curved(situation.cloud, note)


def _thickness(points: NDArray[np.float64]) -> float:
    """Extent [m] of ``points`` (n, 3) along the normal of their least-squares plane."""
    return float(np.ptp(points @ fit_plane_svd(points).normal))


def seen_from_inside(cloud: ObjectCloud) -> NDArray[np.bool_]:
    """Mark the working points (M,) of ``cloud``'s curved faces seen from inside.

    The fold of a link between two working points of a face
    (:func:`~geomodel_ros.core.faces.link_folds`) is positive on a surface bent away from
    the sensor (seen from outside), negative on one bent towards it: a cup's or bowl's
    inner wall seen over its rim. A face is concave where the median fold of its links to
    its own working points is negative (the segmentation's test of its patches,
    :func:`~geomodel_ros.core.segmentation._concave_patches`): all its points are marked.
    A face that is not holds its inner part when the two walls grew into one face over
    the rim: the points whose own links' mean fold is negative, their largest connected
    group (links within the face) when it holds at least ``min_face_points`` and
    :data:`INNER_PART_SHARE` of the face.
    """
    wc = cloud.wc
    marked = np.zeros(len(wc.points), dtype=bool)
    if wc.neighbors.shape[1] < 2:
        return marked
    for f in cloud.faces:
        if f.info.planar or len(f.working) < 2:
            continue
        rows = f.working
        own = np.zeros(len(wc.points), dtype=bool)
        own[rows] = True
        j = wc.neighbors[rows]
        link = own[j] & (j != rows[:, None])
        src = np.broadcast_to(np.arange(len(rows))[:, None], j.shape)[link]
        i = rows[src]
        j = j[link]
        if not len(i):
            continue
        fold = link_folds(wc.points, wc.normals, i, j)
        if np.median(fold) < 0.0:
            marked[rows] = True
            continue
        count = np.bincount(src, minlength=len(rows))
        mean = np.bincount(src, weights=fold, minlength=len(rows)) / np.maximum(count, 1)
        inner = (mean < 0.0) & (count > 0)
        if np.count_nonzero(inner) < max(cloud.params.min_face_points,
                                         INNER_PART_SHARE * len(rows)):
            continue
        local = np.full(len(wc.points), -1, dtype=np.int64)
        local[rows] = np.arange(len(rows))
        both = inner[src] & inner[local[j]]
        graph = csr_matrix((np.ones(np.count_nonzero(both)), (src[both], local[j][both])),
                           shape=(len(rows), len(rows)))
        _, comp = connected_components(graph, directed=False)
        comp = np.where(inner, comp, -1)
        sizes = np.bincount(comp[inner])
        best = int(np.argmax(sizes))
        if sizes[best] >= max(cloud.params.min_face_points, INNER_PART_SHARE * len(rows)):
            marked[rows[comp == best]] = True
    return marked


def inside_and_outside(cloud: ObjectCloud) -> NDArray[np.bool_] | None:
    """Return :func:`seen_from_inside` of ``cloud`` when its curved faces are seen both ways.

    None unless some working points of its curved faces are seen from inside and at least
    ``min_face_points`` of them from outside.
    """
    inner = seen_from_inside(cloud)
    curved = np.zeros(len(inner), dtype=bool)
    for f in cloud.faces:
        if not f.info.planar:
            curved[f.working] = True
    if not inner.any() or np.count_nonzero(curved & ~inner) < cloud.params.min_face_points:
        return None
    return inner


class OuterWallAfterAll:
    """An open container's wall fitted without what is seen from inside it.

    Seen over its rim, a cup or bowl shows its inner wall beside its outer one: a curved
    surface seen concave from the sensor (:func:`seen_from_inside`: a face of its own, or
    part of one that grew over the rim), a wall thickness inside the outer surface and
    tapered the other way near the floor. Every round fit of both together scatters
    beyond the noise or leaves inliers out (noise-free clutter: cups of r 50 mm at 0.6 m,
    `unknown`). When nothing else fitted an object whose curved faces are seen from
    outside and from inside, its model is fitted to its faces without the points seen
    from inside (with its planar faces) and kept only when those points are its inner
    wall (:func:`inner_wall_refusal`); the object keeps all its points. Only with
    ``noise_model = auto``.
    """

    name = "the outer wall of an open container"

    def applies(self, situation: Situation) -> bool:
        """Return True for an object with curved faces (the attempt looks inside them)."""
        cloud = situation.cloud
        return cloud.params.noise_model == "auto" and any(not f.info.planar
                                                           for f in cloud.faces)

    def attempt(self, situation: Situation) -> Attempt | None:
        """Fit the model graph's decision on the object without the parts seen from inside.

        None unless its curved faces are seen both ways (:func:`inside_and_outside`).
        """
        cloud = situation.cloud
        inner = inside_and_outside(cloud)
        if inner is None:
            return None
        drop = inner[cloud.wc.point_to_working]
        new_index = np.cumsum(~drop) - 1
        kept, faces = [], []
        for n, f in enumerate(cloud.faces):
            keep_w = ~inner[f.working]
            if np.count_nonzero(keep_w) < cloud.params.min_face_points:
                continue
            normals = f.info.point_normals
            info = dataclasses.replace(f.info, size=int(np.count_nonzero(keep_w)),
                                       point_normals=normals[keep_w] if len(normals) == len(
                                           f.working) else normals)
            pts = f.points[~drop[f.points]]
            faces.append(ObjectFace(info, f.summary, f.working[keep_w], new_index[pts]))
            kept.append(n)
        if not any(not f.info.planar for f in faces):
            return None
        outer = dataclasses.replace(cloud, points=cloud.points[~drop], faces=faces,
                                    adjacency=cloud.adjacency[np.ix_(kept, kept)])
        # Curvatures from the faces kept only (``decide`` takes an all-curved object's
        # from every working point, the inner wall's among them).
        planar = any(f.info.planar for f in faces)
        decision = decide(outer) if planar else curved_faces_alone(outer)
        if not decision.candidates and planar:
            decision = curved_faces_alone(outer)
        if not decision.candidates:
            return None
        left_out = cloud.points[drop]
        threshold = cloud.params.ransac_threshold
        n_inner = sum(1 for f in cloud.faces if inner[f.working].any())
        return Attempt(outer, decision,
                       note=f"the parts of {n_inner} curved face(s) seen from inside left out",
                       accept=lambda prim: inner_wall_refusal(prim, left_out, threshold))


def inner_wall_refusal(prim: Primitive, inner: NDArray[np.float64], threshold: float
                       ) -> str | None:
    """Return why ``inner`` (n, 3) [m] is no inner wall of the round model ``prim``, or None.

    An open container's inner wall lies inside its outer wall, a wall's thickness in:
    at least :data:`INNER_WALL_SHARE` of the points lie within the model's heights
    (``threshold`` [m] beyond its ends) and between its surface (``threshold`` outside
    it) and :data:`WALL_SHARE` of the radius there inside it. A concave face of
    another object (a bowl's inner wall beside a can fitted alone) lies elsewhere.
    """
    outline = round_outline(prim)
    if outline is None:
        return f"{prim.type.value} has no wall of revolution for the faces seen from inside"
    half_height, radius_at, _ = outline
    local = (inner - prim.center) @ prim.rotation
    z = local[:, 2]
    r = radius_at(np.clip(z, -half_height, half_height))
    depth = r - np.hypot(local[:, 0], local[:, 1])
    wall = (np.abs(z) <= half_height + threshold) & (depth >= -threshold) \
        & (depth <= WALL_SHARE * r + threshold)
    share = float(np.mean(wall)) if len(wall) else 0.0
    if share < INNER_WALL_SHARE:
        return (f"{prim.type.value} refused: {share:.0%} of the faces seen from inside lie "
                f"within its wall (< {INNER_WALL_SHARE:.0%})")
    return None


#: The strategies in the order they are tried.
STRATEGIES: tuple[Strategy, ...] = (ModelGraphCandidates(), CurvedFacesAlone(),
                                    FlatCurvedFacesAsPlanar(), UprightAboveSupport(),
                                    PlanarPatchesOfCurvedObjects(), BoxOfFlatCores(),
                                    PlanarFacesWithoutRule(), DoublyCurvedAsSphere(),
                                    AllFacesCurvedAfterAll())
#: Tried after the cylinder below a lid, for an object no strategy fitted.
LAST_STRATEGIES: tuple[Strategy, ...] = (NormalsBoxAfterAll(), FacesInBoxFrame(),
                                         OuterWallAfterAll(), UprightBoxOnSupport())


def run_strategies(situation: Situation, strategies: Sequence[Strategy] = STRATEGIES,
                   last: Sequence[Strategy] = LAST_STRATEGIES
                   ) -> tuple[Primitive | None, tuple[FaceSummary, ...], list[str]]:
    """Try ``strategies`` in order until one fits.

    Returns the primitive (None if none fits), the face summaries it was fitted with
    (those of ``situation.cloud`` if none) and every reason on the way. A round fit
    is checked against the box of the flat cores (:func:`prefer_box`), a cuboid against
    the round model of all the object's faces (:func:`prefer_round`), a cone or frustum
    against the cylinder below its lid (:func:`prefer_lid_cylinder`); an object no
    strategy fits meets that cylinder alone (:func:`lid_cylinder_alone`), and then the
    ``last`` strategies.
    """
    reasons = [situation.decision.reason]
    found = _first_fit(situation, strategies, reasons)
    if found is not None:
        return (*found, reasons)
    alone = lid_cylinder_alone(situation.cloud, reasons)
    if alone is not None:
        return (*alone, reasons)
    found = _first_fit(situation, last, reasons)
    if found is not None:
        return (*found, reasons)
    return None, tuple(f.summary for f in situation.cloud.faces), reasons


def _first_fit(situation: Situation, strategies: Sequence[Strategy], reasons: list[str]
               ) -> tuple[Primitive, tuple[FaceSummary, ...]] | None:
    """Return the model of the first of ``strategies`` that fits, with its faces, or None.

    Each fit meets its rivals (:func:`prefer_box`, :func:`prefer_round`,
    :func:`prefer_lid_cylinder`); reasons are added to ``reasons``.
    """
    for strategy in strategies:
        if not strategy.applies(situation):
            continue
        attempt = strategy.attempt(situation)
        if attempt is None:
            continue
        if attempt.note:
            reasons.append(attempt.note)
        prim, tried = fit_first(attempt.cloud, attempt.decision, attempt.axis_prior,
                                situation.rejected)
        reasons.extend(attempt.prefix + r for r in tried)
        refused = None if prim is None or attempt.accept is None else attempt.accept(prim)
        if refused is not None:
            reasons.append(attempt.prefix + refused)
            continue
        if prim is not None:
            faces = tuple(f.summary for f in attempt.cloud.faces)
            prim, faces = prefer_box(situation, prim, faces, reasons)
            prim, faces = prefer_round(situation, prim, faces, reasons)
            prim, faces = prefer_lid_cylinder(situation, prim, faces, reasons)
            if prim.type == PrimitiveType.CUBOID and attempt.decision.concave_corner:
                reasons.append("cuboid refused: its faces meet in a concave corner (seen "
                               "from inside: no box)")
                continue
            return prim, faces
    return None
