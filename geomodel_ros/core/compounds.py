"""One object or two: the models check the segmentation after the modeling.

:func:`~geomodel_ros.core.modeling.model_scene` segments a frame and models each segment.
Under noise the segmentation now and then cuts a face off a body, or keeps two touching
bodies in one segment (a can against a box, a ball beside a bowl) when the crease between
them is lost in the noise. The fitted models then show it, and both cases are decided by
one rule: parts are one object when one model explains each of them as well as their own
models do (:func:`join_pieces`), and two objects when each has a model of its own that
the other part's model does not explain and neither body lies in the other
(:func:`split_compounds`). Labels a caller gives (:func:`~geomodel_ros.core.modeling.
model_objects`) are never changed.
"""

from __future__ import annotations

import dataclasses
import math
from typing import TYPE_CHECKING, Iterator

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from geomodel_ros.core.confidence import estimate_confidence, round_outline, surface_distance
from geomodel_ros.core.fastmath import group_by_label, pair_components, take_rows
from geomodel_ros.core.geometry import perpendicular_basis
from geomodel_ros.core.fitting.cloud import Plane
from geomodel_ros.core.fitting.levels import nearest_support_below
from geomodel_ros.core.footprint import SEEN_TYPES, Returns, footprint_split, seen_through
from geomodel_ros.core.joins import ROUND_TYPES
from geomodel_ros.core.model_graph import SLIVER_SHARE
from geomodel_ros.core.noise import NoiseEstimate, is_fragment, object_params
from geomodel_ros.core.params import ModelingParams
from geomodel_ros.core.primitives import ModelingResult, Primitive, PrimitiveType

if TYPE_CHECKING:
    from geomodel_ros.core.modeling import PartModeler

__all__ = ["join_pieces", "split_compounds"]

#: A piece joins a body (:func:`join_pieces`) across a border of at least this
#: many of its points within a segmentation link of the body's points, times the square
#: root of its points (the border of a face is about that long in points).
PIECE_MIN_BORDER = 1.0
#: Bodies a piece may join: a box's face, a can's lid or a facet or strip of its side.
SOLID_TYPES = (PrimitiveType.CUBOID, PrimitiveType.CYLINDER, PrimitiveType.CONE,
               PrimitiveType.FRUSTUM, PrimitiveType.SPHERE)
#: Random stream of the bodies modeled again with their pieces (``[seed, this, body id,
#: piece id]``): independent of the segmentation's, the modeling's and the noise's.
PIECE_STREAM = 0x6A6F696E
#: Random stream of the parts of a segment modeled apart (``[seed, this, object id, fit]``).
SPLIT_STREAM = 0x73706C74
#: A point lies off its object's model beyond this many RANSAC thresholds (the
#: confidence's inlier band is one). Measured on the clutter benchmark under kinect-real
#: noise (seeds 0-59): of the 592 typed objects segmented whole, 2 have a linked group of
#: ``seg_min_cluster_points`` this far off their models; of the 18 typed segments holding
#: two objects, 13 do.
SPLIT_OFF_FACTOR = 2.0
#: The cheap pre-test (:func:`_may_hold_two`) passes objects whose estimated count of
#: points off the inlier band reaches this share of the group size asked. With exactly a
#: group's size off the band (the band is one threshold, the group's two: usually many
#: more are off it), the sampled count is about 4 standard errors above the bar for an
#: object of 5,000 points and 2 for one of 20,000.
OFF_PRETEST_SHARE = 0.5
#: Rounds of refitting the two parts and handing each point to the nearer model ...
SPLIT_ROUNDS = 3
#: ... ending early once fewer than this share of the points change hands.
SPLIT_SETTLED = 0.01
#: A part lies in the other's body when more than SLIVER_SHARE of its points are inside
#: that solid deeper than this many RANSAC thresholds (a bowl's or a cup's inner wall).
INSIDE_DEPTH_FACTOR = 2.0
#: A part is a cap, a rim or an inner floor of a round body (cylinder, cone, frustum) when
#: at least this share of its points lie within the body's round outline widened by
#: CAP_RIM of its radius (a cup's rim, 1.18 radii at the 95th percentile in the clutter
#: scenes), within one radius of its ends: a can's lid, a bowl's floor. A box's top under
#: a standing can reaches 2.4 radii (seed 25, kinect-real: 85 % within).
CAP_SHARE = 0.9
CAP_RIM = 0.25
#: Seeds whose two sides are modeled apart (:func:`_two_models`): a level's, the line
#: parting a footprint (:func:`_seeds`).
APART = ("level", "footprint")
#: A part of a footprint's parting is still seen through when this share of the whole's
#: free space (:class:`_SeenThrough`) or more lies inside it, and an object's worth: the
#: parting did not explain the free space (held-out seed 103: a part cut across a box
#: kept more than the whole had, 3,120 returns against 2,792). A part whose hidden side
#: was completed a little too far keeps a sliver of it (seed 29 from low: 180 of the
#: whole's 19,460 in a box seen over its neighbour's top).
FREE_SPACE_LEFT = 0.5
#: An ``unknown`` object (no model to leave points off), or a typed one whose group off
#: its model gives no split, is split from the models of at most this many of its
#: largest faces, tried in turn (:func:`_seeds`).
FACE_SEEDS = 3

class _Part:
    """The rows (n,) of one object, their points (n, 3) [m], bounds and k-d tree (lazy)."""

    def __init__(self, pts: NDArray[np.float64], rows: NDArray[np.int64]) -> None:
        self.rows = rows
        self.points = take_rows(pts, rows)
        self.lo, self.hi = self.points.min(axis=0), self.points.max(axis=0)
        self._tree: cKDTree | None = None

    @property
    def tree(self) -> cKDTree:
        """Return the k-d tree of the points, built on first use."""
        if self._tree is None:
            self._tree = cKDTree(self.points)
        return self._tree


def _parts(pts: NDArray[np.float64], labels: NDArray[np.int64], wanted: set[int]
           ) -> dict[int, _Part]:
    """Return the :class:`_Part` of each object id in ``wanted`` (labels (N,))."""
    rows = np.flatnonzero(labels >= 0)
    order, ids, starts, ends = group_by_label(rows, labels[rows])
    return {int(i): _Part(pts, order[a:b]) for i, a, b in zip(ids, starts, ends)
            if int(i) in wanted}


def _params_at(params: ModelingParams, noise: NoiseEstimate | None,
               points: NDArray[np.float64]) -> ModelingParams:
    """Return the tolerances at the range of ``points`` (the params without an estimate)."""
    from geomodel_ros.core.modeling import object_range
    return params if noise is None else object_params(params, noise, *object_range(points))


def join_pieces(pts: NDArray[np.float64], labels: NDArray[np.int64],
                result: ModelingResult, params: ModelingParams,
                supports: dict[int, Plane], noise: NoiseEstimate | None, model: PartModeler,
                among: set[int] | None = None) -> NDArray[np.int64]:
    """Join the pieces of bodies to their bodies; return the labels (N,), a new array.

    Under noise the segmentation cuts a face off a body now and then (its border's links
    vote concave by chance): a box's face, a can's lid or a facet of its side is then
    reported as a plane of its own beside the body's model, or, where the cut-off piece of
    a round body bends beyond the frame's errors (a strip of a can's side, its lid with a
    strip of the side), as a smaller round body (:func:`_may_be_piece_of`). A piece (no
    support) whose points touch a body's (a cuboid, cylinder, cone, frustum or sphere; at
    least :data:`PIECE_MIN_BORDER` sqrt(its points) of them within a segmentation link)
    joins it when the two are one body: their union, modeled again as one object
    (``model``), is of the body's type and its surface holds the body's points and the
    piece's each as well as their own models did (:func:`_explains`); or, where that refit
    fails, the body's own model holds the piece's points so (a lid on the can's capped
    solid). A flat object beside a box or on a can (a lying can's flat side, a book), or a
    can beside a can, is no part of a body through both. ``result`` is updated in place:
    the body's model becomes the union's, the piece is gone. With ``among`` only the pairs
    with a body or a piece among those ids are tried (the parts a split made: a box's face
    kept with another body in one segment is a plane of its own once the body is split
    off).
    """
    bodies = [o for o in result.objects if o.type in SOLID_TYPES and o.id not in supports]
    pieces = [o for o in result.objects if o.id not in supports
              and (o.type == PrimitiveType.PLANE or o.type in ROUND_TYPES)]
    if not bodies or not pieces:
        return labels
    labels = labels.copy()
    by_id = {o.id: o for o in result.objects}
    parts = _parts(pts, labels, {o.id for o in bodies + pieces})
    gone: set[int] = set()
    for body in sorted(bodies, key=lambda o: -o.point_count):
        if body.id in gone:  # a round body joined to a larger one as its piece
            continue
        # The tolerances at the body's range, for a round body's pre-test (_may_extend).
        at_body = params if round_outline(body) is None else \
            _params_at(params, noise, parts[body.id].points)
        for piece in sorted(pieces, key=lambda o: -o.point_count):
            own, mine = parts[body.id], parts[piece.id]
            if piece.id in gone or (among is not None and not {body.id, piece.id} & among) \
                    or not _may_be_piece_of(piece, body, len(mine.rows), len(own.rows)) \
                    or not _touching(own, mine, params, noise) \
                    or not _may_extend(by_id[body.id], piece, mine.points, at_body):
                continue
            union = _Part(pts, np.concatenate([own.rows, mine.rows]))
            oparams = _params_at(params, noise, union.points)
            labels[mine.rows] = body.id  # the scene as the union sees it (undone if refused)
            joined = model(union.points, body.id, (PIECE_STREAM, body.id, piece.id),
                           model.context(labels))
            if joined.type != body.type or not all(
                    _explains(joined, by_id[part_id], part.points, oparams)
                    for part_id, part in ((body.id, own), (piece.id, mine))):
                joined = by_id[body.id]  # the body's own model, its refit gone astray
                if not _explains(joined, piece, mine.points, oparams):
                    labels[mine.rows] = piece.id
                    continue
            parts[body.id] = union
            by_id[body.id] = dataclasses.replace(joined, point_count=len(union.rows))
            gone.add(piece.id)
    if gone:
        result.objects = [by_id[o.id] for o in result.objects if o.id not in gone]
    return labels


def _may_be_piece_of(piece: Primitive, body: Primitive, piece_points: int,
                     body_points: int) -> bool:
    """Tell whether ``piece`` may be a piece cut off ``body`` (:func:`join_pieces`).

    A plane may be any body's face; a round piece (a strip of a can's side, or its lid
    with a strip of the side, found round on its own) only a smaller part of a round
    body: a box has no round face.
    """
    if piece.id == body.id:
        return False
    if piece.type == PrimitiveType.PLANE:
        return True
    return body.type in ROUND_TYPES and piece_points < body_points


def _may_extend(body: Primitive, piece: Primitive, points: NDArray[np.float64],
                params: ModelingParams) -> bool:
    """Tell whether the union of a round ``body`` and a ``piece`` may be one body.

    A pre-test before the union's refit (:func:`join_pieces`): a round body's side fixes
    its axis and radius, so a model of its type through both can hold the piece's
    ``points`` (n, 3) only as an end (a plane's normal within ``angle_tolerance`` of the
    axis: a lid) or on its surface: ``min_inlier_ratio`` of the points within
    :data:`SPLIT_OFF_FACTOR` ``ransac_threshold`` of the side, extended past its ends (a
    facet), or of the body's capped solid (a piece of its rim; a round piece must lie so:
    a strip of the side, a lid with a strip of it, not a can standing beside). Boxes and
    spheres pass (a box's face may widen the box).
    """
    outline = round_outline(body)
    if outline is None:
        return True
    axis = body.rotation[:, 2]
    if piece.type == PrimitiveType.PLANE \
            and abs(float(piece.rotation[:, 2] @ axis)) >= math.cos(params.angle_tolerance):
        return True
    _, radius_at, _ = outline
    local = (points - body.center) @ body.rotation
    band = SPLIT_OFF_FACTOR * params.ransac_threshold
    near = (np.abs(np.hypot(local[:, 0], local[:, 1]) - radius_at(local[:, 2])) <= band) \
        | (surface_distance(body, points) <= band)
    return bool(np.mean(near) >= params.min_inlier_ratio)


def _explains(joined: Primitive, alone: Primitive, points: NDArray[np.float64],
              params: ModelingParams) -> bool:
    """Tell whether the ``joined`` model explains a part's ``points`` as its own model did.

    Its inlier ratio over them (within ``ransac_threshold``) must be at least
    ``min_inlier_ratio`` and lose at most a sliver's share
    (:data:`~geomodel_ros.core.model_graph.SLIVER_SHARE`) against ``alone``'s: a box
    standing on a box whose top alone is seen fits one cuboid through both, which leaves
    the lower box's top face off its surface.
    """
    thr = params.ransac_threshold
    together = estimate_confidence(joined, points, thr).inlier_ratio
    apart = estimate_confidence(alone, points, thr).inlier_ratio
    return together >= params.min_inlier_ratio and together >= apart - SLIVER_SHARE


def _touching(a: _Part, b: _Part, params: ModelingParams, noise: NoiseEstimate | None
              ) -> bool:
    """Tell whether the object ``b`` borders on ``a`` (:func:`join_pieces`).

    At least :data:`PIECE_MIN_BORDER` sqrt(its points) of ``b``'s points lie within a
    segmentation link of ``a``'s (``seg_max_edge_factor`` ``seg_voxel_size``, resolved at
    ``b``'s range with a noise estimate).
    """
    oparams = _params_at(params, noise, b.points)
    link = oparams.seg_max_edge_factor * oparams.seg_voxel_size
    need = PIECE_MIN_BORDER * math.sqrt(len(b.rows))
    near = b.points[np.all((b.points >= a.lo - link) & (b.points <= a.hi + link), axis=1)]
    if len(near) < need:
        return False
    dist, _ = a.tree.query(near, distance_upper_bound=link)
    return int(np.count_nonzero(np.isfinite(dist))) >= need


def split_compounds(pts: NDArray[np.float64], labels: NDArray[np.int64],
                    result: ModelingResult, params: ModelingParams,
                    supports: dict[int, Plane], noise: NoiseEstimate | None, model: PartModeler,
                    changed: set[int] | None = None) -> NDArray[np.int64]:
    """Split the segments that hold two bodies; return the labels (N,), a new array.

    A typed object (no support, no plane) whose points include a linked group (links of
    the segmentation's length) of at least ``seg_min_cluster_points`` lying off its model
    (beyond :data:`SPLIT_OFF_FACTOR` thresholds) may be two: the group is modeled on its
    own, then the two models are refitted in turns, each point handed to the nearer
    surface (:func:`_two_models`). An ``unknown`` object (no support) has no model to
    leave points off: the models of its largest faces (:data:`FACE_SEEDS`) take that
    model's place in turn (two cans side by side whose crease the segmentation missed).
    So do they for a typed object when its group gives no split, or it has none: the
    model of the whole may hold both bodies within its band (a box and a lying can as
    one cone, kinect-real clutter seed 32). Last, the two sides of each of the object's
    levels (``Primitive.levels``: a box's top with part of the segment rising beyond it,
    :mod:`~geomodel_ros.core.fitting.levels`) are modeled apart, whether or not points
    lie off the model (a box on a box with a side flush, one box holding both; a can on a
    box it reaches down through). Before all, a cuboid, cylinder or frustum the sensor saw
    through (free space inside it: two boxes side by side at different headings,
    :mod:`~geomodel_ros.core.footprint`) is parted by the line across its footprint into
    two boxes turned against each other, neither of them keeping the whole's free space
    (:data:`FREE_SPACE_LEFT`). The segment is
    split when both parts are typed
    and neither faces of one box nor bands of one round body's side, each model explains
    its own part (inlier ratio >= ``min_inlier_ratio``) and neither part lies in
    the other's body (:func:`_two_bodies`, :func:`_in_body`: a cup's inner wall, a bowl's
    floor, a can's rim or lid are no objects of their own). The second part gets a new id
    (above every label); ``result`` is updated in place, and the ids of both parts of
    every split are added to ``changed`` when given.
    """
    may = {o.id: _may_hold_two(o, params, noise) for o in result.objects
           if o.id not in supports and o.type != PrimitiveType.PLANE}
    free_space = _SeenThrough(pts, params, noise)
    free = {o.id: free_space.count(o, labels) for o in result.objects if o.id in may}
    seen = {i for i, count in free.items() if count >= params.seg_min_cluster_points}
    candidates = [o for o in result.objects
                  if may.get(o.id) or (o.id in may and (o.levels or o.id in seen))]
    if not candidates:
        return labels
    labels = labels.copy()
    parts = _parts(pts, labels, {o.id for o in candidates})
    next_id = int(labels.max()) + 1
    by_id = {o.id: o for o in result.objects}
    added: list[Primitive] = []
    for o in candidates:
        part = parts[o.id]
        split = None
        for group, kind in _seeds(o, part.points, labels, params, noise, model, may[o.id],
                                  o.id in seen, list(supports.values())):
            split = _two_models(o, part, group, kind, next_id, labels, params, noise,
                                model)
            # The footprint's boxes are two where neither keeps the whole's free space.
            if split is not None and kind == "footprint" and free_space.either(
                    free[o.id], split[0], split[1], part.rows, split[2], next_id, labels):
                split = None
            if split is not None:
                break
        if split is None:
            continue
        first, second, in_second = split
        labels[part.rows[in_second]] = next_id
        by_id[o.id] = dataclasses.replace(first, point_count=int(np.count_nonzero(~in_second)))
        added.append(dataclasses.replace(second, point_count=int(np.count_nonzero(in_second))))
        if changed is not None:
            changed.update((o.id, next_id))
        next_id += 1
    if added:
        result.objects = [by_id[o.id] for o in result.objects] + added
    return labels


class _SeenThrough:
    """The free space inside a frame's models (returns set up on first use).

    A cuboid, cylinder or frustum is seen through when at least ``seg_min_cluster_points``
    returns of other labels lie beyond its solid shrunk by half its ``ransac_threshold``
    (:func:`~geomodel_ros.core.footprint.seen_through`; a frustum's inscribed cylinder):
    an object's worth of free space inside it (two boxes side by side, one cylinder of
    176 mm radius round them: kinect-real seed 22 from low, 2,428 returns).
    """

    def __init__(self, pts: NDArray[np.float64], params: ModelingParams,
                 noise: NoiseEstimate | None) -> None:
        self.pts, self.params, self.noise = pts, params, noise
        self._returns: Returns | None = None

    def count(self, p: Primitive, labels: NDArray[np.int64]) -> int:
        """Count the returns seen through the model ``p`` (:func:`seen_through`)."""
        if p.type not in SEEN_TYPES:
            return 0
        if self._returns is None:
            self._returns = Returns(self.pts)
        depth = float(np.linalg.norm(p.center))
        w = (self.params if self.noise is None else object_params(
            self.params, self.noise, depth)).ransac_threshold
        return seen_through(p, self._returns, labels, w)

    def either(self, whole: int, first: Primitive, second: Primitive,
               rows: NDArray[np.int64], in_second: NDArray[np.bool_], second_id: int,
               labels: NDArray[np.int64]) -> bool:
        """Tell whether either model of a split is still seen through.

        ``rows`` (n,) of the split object (``first.id``), ``in_second`` (n,) marking those
        of ``second`` (labelled ``second_id``) in a copy of ``labels``. A part is, when it
        holds an object's worth of free space and :data:`FREE_SPACE_LEFT` of the
        ``whole``'s count (:meth:`count`) or more.
        """
        bar = max(self.params.seg_min_cluster_points, FREE_SPACE_LEFT * whole)
        split = labels.copy()
        split[rows] = first.id
        split[rows[in_second]] = second_id
        return self.count(first, split) >= bar or \
            self.count(dataclasses.replace(second, id=second_id), split) >= bar


def _may_hold_two(o: Primitive, params: ModelingParams, noise: NoiseEstimate | None
                  ) -> bool:
    """Tell whether enough of ``o``'s points lie off its model for :func:`_off_group`.

    A pre-test on the confidence's inlier ratio (measured on about 2000 of the points,
    within one threshold, a wider set than the group's): the points outside it must reach
    OFF_PRETEST_SHARE of ``seg_min_cluster_points``. An ``unknown`` object needs twice
    ``seg_min_cluster_points`` and must be no fragment (too small to be an object, it is
    taken out as noise: :func:`~geomodel_ros.core.noise.is_fragment`).
    """
    if o.type == PrimitiveType.UNKNOWN:
        return o.point_count >= 2 * params.seg_min_cluster_points and not is_fragment(
            o.point_count, float(np.linalg.norm(o.center)), noise, params)
    if o.confidence is None:
        return True
    return (1.0 - o.confidence.inlier_ratio) * o.point_count \
        >= OFF_PRETEST_SHARE * params.seg_min_cluster_points


def _off_group(o: Primitive, points: NDArray[np.float64], oparams: ModelingParams
               ) -> NDArray[np.bool_] | None:
    """Return the largest linked group of ``points`` (n, 3) off ``o``'s model, or None.

    As a mask (n,); None when it holds fewer than ``seg_min_cluster_points``.
    """
    off = np.flatnonzero(surface_distance(o, points) > SPLIT_OFF_FACTOR
                         * oparams.ransac_threshold)
    if len(off) < oparams.seg_min_cluster_points:
        return None
    link = oparams.seg_max_edge_factor * oparams.seg_voxel_size
    pairs = cKDTree(points[off]).query_pairs(link, output_type="ndarray")
    group = pair_components(len(off), pairs)
    largest = off[group == np.bincount(group).argmax()]
    if len(largest) < oparams.seg_min_cluster_points:
        return None
    mask = np.zeros(len(points), dtype=bool)
    mask[largest] = True
    return mask


def _seeds(o: Primitive, points: NDArray[np.float64], labels: NDArray[np.int64],
           params: ModelingParams, noise: NoiseEstimate | None, model: PartModeler,
           off: bool = True, seen: bool = False, supports: list[Plane] | None = None
           ) -> Iterator[tuple[NDArray[np.bool_], str]]:
    """Yield the masks (n,) of ``points`` from which a second part is sought, and their kind.

    With ``seen`` (a solid the sensor saw through, :class:`_SeenThrough`), first
    ``"footprint"``: one side of the line that parts the footprint of ``points`` on the
    support below (of ``supports``) into two rectangles of least joint area
    (:func:`~geomodel_ros.core.footprint.footprint_split`; none when the two rectangles
    are turned less than ``angle_tolerance`` against each other: no two boxes of one
    heading, :func:`_parts_of_one_box`, and no fits for them); both sides are modeled apart
    and kept as the line parts them (handed points by distance, two boxes whose tops
    continue each other's pass points across the contact round by round: seed 80's box
    took 16 mm of its neighbour). With ``off`` (enough points off the model,
    :func:`_may_hold_two`): ``"off"``, a typed object's group off its model
    (:func:`_off_group`); then ``"face"``, the
    object's largest faces (at most :data:`FACE_SEEDS`, each at least
    ``seg_min_cluster_points``), whose models take the place of the object's
    (:func:`_two_models`); the faces are found only when asked. Last, ``"level"``: the
    points rising beyond each of the object's levels (``Primitive.levels``, lowest first:
    :func:`~geomodel_ros.core.fitting.levels.object_levels`), the two sides of which are
    modeled apart.
    """
    oparams = _params_at(params, noise, points)
    if seen:
        support = nearest_support_below(points, supports or [], oparams.ransac_threshold)
        if support is not None:
            e1, e2 = perpendicular_basis(support[0])
            side = footprint_split(np.stack([points @ e1, points @ e2], axis=1),
                                   oparams.seg_min_cluster_points, params.angle_tolerance)
            if side is not None:
                yield side, "footprint"
    if off:
        if o.type != PrimitiveType.UNKNOWN:
            group = _off_group(o, points, oparams)
            if group is not None:
                yield group, "off"
        for face in model.faces(points, model.context(labels))[:FACE_SEEDS]:
            if len(face) < oparams.seg_min_cluster_points:
                break
            mask = np.zeros(len(points), dtype=bool)
            mask[face] = True
            yield mask, "face"
    for level in o.levels:
        yield level.above(points, oparams.ransac_threshold), "level"


def _two_models(o: Primitive, part: _Part, group: NDArray[np.bool_], kind: str,
                new_id: int, labels: NDArray[np.int64], params: ModelingParams,
                noise: NoiseEstimate | None, model: PartModeler
                ) -> tuple[Primitive, Primitive, NDArray[np.bool_]] | None:
    """Model ``part`` (object ``o``) as two; return both models and the second's mask.

    ``group`` (n,) starts the second part, ``o``'s model the first (``kind`` ``"off"``).
    With ``"level"``, ``group`` holds the points beyond a level and the rest's own model
    is the first. With ``"face"``, ``group`` is one of the part's faces (:func:`_seeds`)
    whose own model takes ``o``'s place, and the group off that model
    (:func:`_off_group`) starts the second part;
    for a typed ``o`` only a round or box model does (the rest of a body off one of its
    own planar faces holds that face: on kinect-real clutter such splits were refused
    after their refits, 100-400 ms each, but for two boxes in one cuboid).
    Each round hands every point to the nearer of the two models and fits both again
    (:data:`SPLIT_ROUNDS`, until fewer than :data:`SPLIT_SETTLED` change hands); a part
    whose refit is ``unknown`` (it still holds some of the other body: a bowl's part a
    third of the ball beside it) keeps its last model for the next hand-off. The last
    pair of typed models fitted each to its own part is kept. None when the second
    part's first model is ``unknown``, a part falls below ``seg_min_cluster_points``, no
    such pair was fitted, or the two are not two bodies (:func:`_two_bodies`).
    """
    from geomodel_ros.core.modeling import parallel_map
    points, rows = part.points, part.rows
    scene = labels.copy()

    def context(in_second: NDArray[np.bool_]) -> tuple:
        """Return the scene's context with ``part`` divided as ``in_second`` (n,) says."""
        scene[rows] = o.id
        scene[rows[in_second]] = new_id
        return model.context(scene)

    def fit_second(in_second: NDArray[np.bool_]) -> Primitive:
        return model(points[in_second], new_id, (SPLIT_STREAM, o.id, 0), context(in_second))

    def fit_both(in_second: NDArray[np.bool_], k: int) -> list[Primitive]:
        both = context(in_second)
        return parallel_map(lambda job: model(points[job[0]], job[1], (
            SPLIT_STREAM, o.id, job[2]), both), [
            (~in_second, o.id, 1 + 2 * k), (in_second, new_id, 2 + 2 * k)])

    if kind in APART:  # the two sides of the level or the line modeled apart
        first = model(points[~group], o.id, (SPLIT_STREAM, o.id, 2 * SPLIT_ROUNDS + 1),
                      context(group))
        if first.type == PrimitiveType.UNKNOWN:
            return None
        second = fit_second(group)
    elif kind == "face":  # the face's model takes o's place
        first = model(points[group], o.id, (SPLIT_STREAM, o.id, 2 * SPLIT_ROUNDS + 1),
                      context(~group))
        if first.type == PrimitiveType.UNKNOWN or (
                first.type == PrimitiveType.PLANE and o.type != PrimitiveType.UNKNOWN):
            return None
        group = _off_group(first, points, _params_at(params, noise, points))
        if group is None:
            return None
        second = fit_second(group)
    else:
        first, second = o, fit_second(group)
    in_second = group
    kept = None  # the last pair of typed models fitted each to its own part
    if not _typed(second) or _one_body(first, second, params.angle_tolerance) \
            or _parts_of_one_box(kind, first, second, points, params, noise) \
            or _part_in_body(first, second, in_second, points, params, noise):
        return None
    if kind == "footprint":  # the line's parts are final
        kept = (first, second, in_second)
    for k in range(0 if kind == "footprint" else SPLIT_ROUNDS):
        nearer = surface_distance(second, points) < surface_distance(first, points)
        size = int(np.count_nonzero(nearer))
        if min(size, len(points) - size) < params.seg_min_cluster_points:
            return None
        if k and np.count_nonzero(nearer != in_second) < SPLIT_SETTLED * len(points):
            break
        in_second = nearer
        refit = fit_both(in_second, k)
        if _typed(*refit):
            kept = (*refit, in_second)
        # A part's refit that fails (it still holds some of the other body's points)
        # leaves the part its last model for the next round's hand-off.
        first, second = (new if _typed(new) else old
                         for new, old in zip(refit, (first, second)))
    if kept is None or not _two_bodies(*kept, points, params, noise) or \
            _parts_of_one_box(kind, kept[0], kept[1], points, params, noise):
        return None
    return kept


def _parts_of_one_box(kind: str, first: Primitive, second: Primitive,
                      points: NDArray[np.float64], params: ModelingParams,
                      noise: NoiseEstimate | None) -> bool:
    """Tell whether two models of parts modeled apart may be parts of one box, or no pair.

    Only for the ``kind`` of :data:`APART`. A level across one box (its lower part
    narrower to the sensor behind an object in front) cuts it into two layers
    (:func:`_layers_of_a_box`). The footprint's line was sought for two rectangles: its
    parts are two boxes or no pair (the end of a box whose model reached too far, cut
    off, comes back as a cylinder: kinect-real seed 136), and two boxes turned against
    each other (:func:`_parallel_boxes`): a box cut across its own sides comes back as two
    of one heading, neither seen through once points have changed hands (Kinect-class
    seeds 8 and 30: boxes of 92 x 111 x 54 and 99 x 111 x 58 mm cut in two).
    """
    if kind == "footprint":
        return first.type != PrimitiveType.CUBOID or second.type != PrimitiveType.CUBOID \
            or _parallel_boxes(first, second, params.angle_tolerance)
    return kind == "level" and _layers_of_a_box(
        first, second, params.angle_tolerance, _params_at(params, noise, points).ransac_threshold)


def _parallel_boxes(first: Primitive, second: Primitive, angle_tolerance: float) -> bool:
    """Tell whether two models are cuboids with parallel axes (within ``angle_tolerance``)."""
    if first.type != PrimitiveType.CUBOID or second.type != PrimitiveType.CUBOID:
        return False
    turn = np.abs(first.rotation.T @ second.rotation)  # |cos| between the axes
    return bool(np.all(turn.max(axis=1) >= math.cos(angle_tolerance)))


def _layers_of_a_box(first: Primitive, second: Primitive, angle_tolerance: float,
                     threshold: float) -> bool:
    """Tell whether two cuboids may be two layers of one box.

    Their axes parallel (within ``angle_tolerance`` [rad]) and the faces of one within
    ``threshold`` [m] of the other's along two of its axes: one section, the two on top
    of each other or side by side.
    """
    if not _parallel_boxes(first, second, angle_tolerance):
        return False
    turn = np.abs(first.rotation.T @ second.rotation)
    names = ("length", "width", "height")
    half1 = 0.5 * np.array([first.dimensions[k] for k in names])
    half2 = 0.5 * np.array([second.dimensions[k] for k in names])[turn.argmax(axis=1)]
    off = first.rotation.T @ (second.center - first.center)
    same = (np.abs(off - half2 + half1) <= threshold) & (np.abs(off + half2 - half1) <= threshold)
    return int(np.count_nonzero(same)) >= 2


def _typed(*prims: Primitive) -> bool:
    """Tell whether none of ``prims`` is ``unknown``."""
    return all(p.type != PrimitiveType.UNKNOWN for p in prims)


def _one_body(first: Primitive, second: Primitive, angle_tolerance: float) -> bool:
    """Tell whether two models are faces of one box or bands of one round body's side.

    (:func:`_faces_of_a_box`, :func:`_bands_of_a_round_body`.) Such a pair is no split
    (:func:`_two_bodies`); when the hand-off starts from one, there is no second body to
    hand points to, and its refits (2-6 fits of a part, 100-800 ms on osd_learn's cans)
    are not made.
    """
    return _faces_of_a_box(first, second, angle_tolerance) or \
        _bands_of_a_round_body(first, second, angle_tolerance)


def _faces_of_a_box(first: Primitive, second: Primitive, angle_tolerance: float) -> bool:
    """Tell whether two models may be faces of one box.

    Two planes, or a plane and a cuboid one of whose faces the plane parallels (within
    ``angle_tolerance`` [rad]).
    """
    kinds = {first.type, second.type}
    if kinds == {PrimitiveType.PLANE}:
        return True
    if kinds != {PrimitiveType.PLANE, PrimitiveType.CUBOID}:
        return False
    plane, box = (first, second) if first.type == PrimitiveType.PLANE else (second, first)
    return bool(np.max(np.abs(box.rotation.T @ plane.rotation[:, 2]))
                >= math.cos(angle_tolerance))


def _bands_of_a_round_body(first: Primitive, second: Primitive, angle_tolerance: float
                           ) -> bool:
    """Tell whether two round models may be bands of one round body's side.

    Both cylinders, cones or frustums whose axes are parallel (within ``angle_tolerance``
    [rad]) and one line: each centre within half the smaller largest radius of the other's
    axis (a cup's wall, taken apart at a face border, is a frustum below a cylinder on
    its axis). Round bodies side by side stand at least the sum of their radii apart.
    """
    outlines = [round_outline(p) for p in (first, second)]
    if any(o is None for o in outlines):  # no solid of revolution about an axis
        return False
    a, b = first.rotation[:, 2], second.rotation[:, 2]
    if abs(float(a @ b)) < math.cos(angle_tolerance):
        return False
    reach = 0.5 * min(o[2] for o in outlines)
    off = second.center - first.center
    return bool(np.linalg.norm(off - (off @ a) * a) <= reach
                and np.linalg.norm(off - (off @ b) * b) <= reach)


def _two_bodies(first: Primitive, second: Primitive, in_second: NDArray[np.bool_],
                points: NDArray[np.float64], params: ModelingParams,
                noise: NoiseEstimate | None) -> bool:
    """Tell whether two models of one segment's parts are two bodies.

    Not faces of one box (:func:`_faces_of_a_box`: two planes are a box's whose cuboid
    fitted badly, noise-free clutter seed 22, a box of inlier ratio 0.74, came apart into
    its two faces; a box no model fitted, kinect-real seed 127, into a cuboid and a plane
    along one of its faces), nor bands of one round body's side
    (:func:`_bands_of_a_round_body`: noise-free seed 13's cup from the models of its
    faces, a frustum below a cylinder); each explains its own part (inlier ratio within its
    ``ransac_threshold`` at least ``min_inlier_ratio``) and neither part lies in the
    other's body (:func:`_in_body`).
    """
    if _one_body(first, second, params.angle_tolerance):
        return False
    sides = ((first, points[~in_second]), (second, points[in_second]))
    tolerances = [_params_at(params, noise, p) for _, p in sides]
    for (prim, own), tol in zip(sides, tolerances):
        if estimate_confidence(prim, own, tol.ransac_threshold).inlier_ratio \
                < params.min_inlier_ratio:
            return False
    return not _part_in_body(first, second, in_second, points, params, noise)


def _part_in_body(first: Primitive, second: Primitive, in_second: NDArray[np.bool_],
                  points: NDArray[np.float64], params: ModelingParams,
                  noise: NoiseEstimate | None) -> bool:
    """Tell whether either part of ``points`` lies in the other part's model's body.

    ``in_second`` (n,) marks ``second``'s part, the rest is ``first``'s (:func:`_in_body`,
    within the ``ransac_threshold`` at the part's range): a can's lid, rim or inner floor
    is no body of its own.
    """
    for prim, other in ((first, points[in_second]), (second, points[~in_second])):
        if _in_body(prim, other, _params_at(params, noise, other).ransac_threshold):
            return True
    return False


def _in_body(p: Primitive, points: NDArray[np.float64], threshold: float) -> bool:
    """Tell whether ``points`` (n, 3) [m] belong to the body of the model ``p``.

    More than SLIVER_SHARE of them lie inside its solid, deeper than
    :data:`INSIDE_DEPTH_FACTOR` ``threshold`` [m]; or at least :data:`CAP_SHARE` of them
    lie on it: for a box within its solid grown by :data:`INSIDE_DEPTH_FACTOR`
    ``threshold`` (a face of it: a can's side taken for a box leaves its lid on the box's
    top), for a round body within its outline widened by :data:`CAP_RIM` radii plus
    ``threshold``, no farther than a radius beyond its ends (its cap, rim or inner floor).
    Planes have no body.
    """
    if p.type in (PrimitiveType.PLANE, PrimitiveType.UNKNOWN):
        return False
    dist = surface_distance(p, points)
    deep = dist > INSIDE_DEPTH_FACTOR * threshold
    if p.type == PrimitiveType.SPHERE:
        inside = np.linalg.norm(points - p.center, axis=1) < p.dimensions["radius"]
        return bool(np.mean(inside & deep) > SLIVER_SHARE)
    local = (points - p.center) @ p.rotation
    if p.type == PrimitiveType.CUBOID:
        half = 0.5 * np.array([p.dimensions[k] for k in ("length", "width", "height")])
        inside = np.all(np.abs(local) < half, axis=1)
        if np.mean(inside & deep) > SLIVER_SHARE:
            return True
        on = np.all(np.abs(local) < half + INSIDE_DEPTH_FACTOR * threshold, axis=1)
        return bool(np.mean(on) >= CAP_SHARE)
    outline = round_outline(p)
    if outline is None:
        return False
    half_height, radius_at, reach = outline
    z = local[:, 2]
    rho = np.hypot(local[:, 0], local[:, 1])
    r = radius_at(np.clip(z, -half_height, half_height))
    inside = (np.abs(z) < half_height) & (rho < r)
    if np.mean(inside & deep) > SLIVER_SHARE:
        return True
    cap = (rho < (1.0 + CAP_RIM) * r + threshold) & (np.abs(z) < half_height + reach)
    return bool(np.mean(cap) >= CAP_SHARE)
