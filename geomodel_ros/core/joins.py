"""Joining parts into objects: the three join decisions of the scene segmentation.

- :func:`merge_patches`: smooth patches -> objects from the convexity votes along their
  common borders (local convexity, as in LCCP, Stein et al. 2014).
- :func:`join_occluded_parts`: two visible parts of one surface cut by a nearer occluder.
- :func:`join_contained_parts`: the inner wall of an open round container (bowl, cup, pot)
  and its outer wall, which meet only at the hidden back rim.
- :func:`contained_floors`: the floor of an open container seen through its opening, which
  lies in the support's band under a real sensor's noise, back from the support to it.
- :func:`join_terraces`: the terraces of constant depth into which a camera's disparity
  quantisation cuts a far surface.

Each join loops over pairs of patches or segments (tens to hundreds), never over points.
All three keep their groups in one :class:`DisjointSets`: the label a group carries is the
root of its union-find tree, and that root depends on the order of the joins. The label
values set the order of the objects (ties in size are broken by label, and the modeling
spawns one random stream per object in label order), so the joins are replayed in their
fixed order rather than handed to :func:`scipy.sparse.csgraph.connected_components`,
whose component numbers follow the smallest member instead.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Hashable, Iterable
from dataclasses import dataclass
from functools import cached_property
from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from geomodel_ros.core.confidence import estimate_confidence
from geomodel_ros.core.fastmath import (group_by_label, link_components, pair_components,
                                        row_norms, take_rows)
from geomodel_ros.core.geometry import perpendicular_basis
from geomodel_ros.core.noise import NoiseEstimate
from geomodel_ros.core.params import ModelingParams
from geomodel_ros.core.primitives import Primitive, PrimitiveType
from geomodel_ros.core.ransac import PlaneModel

__all__ = ["DisjointSets", "merge_patches", "join_occluded_parts", "join_contained_parts",
           "contained_floors", "join_terraces"]

#: Guard against division by a zero length.
_TINY = 1e-12

# --- merge_patches: convexity votes along patch borders -----------------------------------
#: Two patches are joined when at least this share of the neighbour links across their
#: border vote flat or convex (a simple majority of the local evidence).
JOIN_MIN_CONVEX_SHARE = 0.5
#: ... and when their border is long enough to be an edge shared by two faces, not a point
#: contact: at least this many votes per sqrt(points of the smaller patch) (the side, in
#: working points, of a square patch of that size). Two faces of one object share an edge
#: of about a side, crossed by several links per border point; two objects touching at a
#: point (a box's corner against a cup, two boxes' edges) border along a few links only
#: (1-10 votes between patches of 300-1000 points in the clutter scenes). Measured on the
#: clutter benchmark (``python -m geomodel_ros.tools.bench_clutter``, 20 scenes,
#: noise-free / Kinect noise, IoU >= 0.8 and under-segmented): without the test 93.2 / 6.4
#: and 88.8 / 4.0 %; 0.5 and 1 vote per side 95.2 / 4.8 and 88.8 / 4.0 %; 2 votes 94.8 /
#: 4.8 and 89.2 / 3.2 %. osd_learn (defaults) the same with and without it.
JOIN_MIN_BORDER_VOTES = 1.0
#: A border is a clear concave crease (two objects meeting, or an object on another) when
#: it holds at least this many votes (links of neighbouring working points, so a border
#: of a few points at least: fewer are too little evidence to forbid a join) ...
CREASE_MIN_VOTES = 20
#: ... and fewer than this share of them are flat or convex (well below the majority
#: that joins: a crease seen through noise still has a minority of convex votes).
CREASE_MAX_CONVEX_SHARE = 0.3

# --- join_occluded_parts: one surface seen on both sides of an occluder -------------------
#: The surface direction at a part's end is the mean normal within this many link lengths
#: (``seg_max_edge_factor`` voxels) of the end point: the normals of boundary points are
#: unreliable (their neighbourhoods are one-sided), a ball of three links (30 mm with the
#: defaults) reaches well inside the part.
OCCLUSION_NORMAL_RADIUS_LINKS = 3.0
#: The surface continues across the gap when the mean normals at both ends agree within
#: this angle [rad] (20 degrees: the two ends of one smooth surface, a few centimetres
#: apart, are nearly parallel; two objects' faces at random orientations rarely are) ...
OCCLUSION_MAX_NORMAL_ANGLE = math.radians(20.0)
#: ... and both lie across the gap direction: the gap direction is within this angle [rad]
#: of each end's tangent plane (15 degrees: the gap runs along the surface, not off it
#: towards another surface).
OCCLUSION_MAX_GAP_TILT = math.radians(15.0)
#: Positions along the gap (0 = the end on one part, 1 = on the other) where the viewing
#: ray is checked for an occluder: 8 samples over the inner 70 %, the ends left out
#: because next to them the rays meet the parts' own boundary points.
OCCLUSION_GAP_SAMPLES = np.linspace(0.15, 0.85, 8)
OCCLUSION_GAP_SAMPLES.setflags(write=False)
#: The nearest points of two segments are sought among the points of the smaller one in
#: cells of this many link lengths (:func:`_gap_candidates`): a cell's representative
#: bounds all its points' distances, so only the few cells facing the other segment are
#: searched point by point (2: cells of 2 cm with the defaults, tens of points each).
GAP_CELL_LINKS = 2.0
#: ... unless the smaller segment has at most this many points: then all of them are
#: searched at once, as the cells' own search costs about as much (measured on the pairs
#: of osd_learn learn0/20/40 and the paper's scene3: 0.05-0.3 ms a pair either way below
#: 330 points; above 1000 the cells took 2-2.5 ms where the search of all took 12-13 ms).
GAP_DIRECT_POINTS = 400
#: Every this many rows of a segment searched point by point are searched first
#: (:func:`_closest_gap`): the nearest distance they reach bounds the search of all rows.
GAP_PROBE_STRIDE = 8
#: Distances within this [m] of the nearest are kept as candidates: far above the
#: rounding of a distance between points metres from the origin (about 1e-15 m).
GAP_MARGIN = 1e-9
#: A measured point lies on a sample's viewing ray when it is within this many voxels of
#: the ray at the sample's depth (the working cloud holds a point every voxel wherever a
#: surface was measured, so a measured ray always has one within 1.5 voxels).
OCCLUSION_RAY_TOLERANCE_VOXELS = 1.5
#: A point on the ray hides the gap when it is nearer to the sensor than the sample by
#: more than this many voxels (beyond voxel quantisation and depth noise); a point at or
#: behind the gap means the gap is seen open.
OCCLUSION_NEARER_MARGIN_VOXELS = 2.0
#: The directions that may lie within the ray tolerance of a gap's samples are taken from
#: the samples' box grown by the tolerance and this margin (far above the rounding of a
#: unit vector's coordinates, about 1e-16), so none is left out by rounding.
RAY_BOX_MARGIN = 1e-9
#: At least this share of the samples must meet a measured point (5 of 8): rays into holes
#: and sensor shadows are no evidence either way, and a gap mostly unmeasured proves
#: nothing.
OCCLUSION_MIN_SEEN_SHARE = 0.6

#: Least share of each part's points within the band of the model of two round parts
#: joined across an occluder: the part lies on that surface rather than off it. Measured
#: (working points, ``ransac_threshold``): the two parts of one can 97-99 % in clutter,
#: 73 and 100 % on a real Kinect frame (osd_learn learn30, the can's slow errors); a
#: cup's piece 105 mm from a can (noise-free clutter seed 47) and a box's 148 mm from a
#: can (kinect-real seed 121) none, the can's cylinder verified on the two together.
ROUND_PART_SHARE = 0.5

#: Types whose surface turns everywhere. Parallel normals at the two ends of a gap are
#: evidence of one surface for flat parts; a round part and another are one surface only
#: when the model graph models the two together as the shape of one of them
#: (:func:`_one_round_surface`).
ROUND_TYPES = frozenset({PrimitiveType.CYLINDER, PrimitiveType.CONE, PrimitiveType.FRUSTUM,
                         PrimitiveType.SPHERE})

# --- join_contained_parts: the inner and outer walls of an open round container ----------
#: Segments with fewer working points take no part in the container join (too few to fit
#: a circle or to place a footprint: 30 voxels are about 5 cm^2 at 4 mm).
CONTAINED_MIN_POINTS = 30
#: Round footprint: the median distance of the footprint points from the fitted wall of
#: revolution (:class:`_Wall`: its radius at each point's height) is below this share of
#: its radius (a wall of revolution seen with depth noise; a flat face seen as part of a
#: huge circle spreads more) ...
ROUND_MAX_SPREAD = 0.08
#: ... the horizontal normals point along the circle's radii: median |cos| between them
#: above this (within about 32 degrees: normals of a wall of revolution are radial) ...
ROUND_MIN_RADIAL_ALIGNMENT = 0.85
#: ... the radius is container-sized [m] (a flat face fits a circle of huge radius;
#: bowls, cups and pots are at most 50 cm across) ...
ROUND_MAX_RADIUS = 0.25
#: ... seen over a real arc [rad] (60 degrees: a short arc fits circles of any radius) ...
ROUND_MIN_ARC = math.radians(60.0)
#: ... and the normals turn continuously: their azimuths in bins of this width [deg] ...
AZIMUTH_BIN_DEG = 10.0
AZIMUTH_BINS = 36  # 360 degrees / AZIMUTH_BIN_DEG
#: ... fill at least this many bins (60 degrees of turning; a box's faces give one or two
#: directions each, so at most a few bins) ...
ROUND_MIN_TURNING_BINS = 6
#: ... where a bin counts when it holds at least this share of the normals (a few stray
#: normals at edges do not make a turning wall).
AZIMUTH_BIN_MIN_SHARE = 0.02
#: A segment lies inside a round segment (a container's wall) when at least this share of
#: its points lies within the wall's footprint circle (and its median height is below the
#: wall's rim, :data:`RIM_HEIGHT_QUANTILE`). A simple majority:
#: solids do not interpenetrate, so an object beside the wall has at most a sliver inside
#: the circle, while the inner wall of a cup seen together with its handle (the PCL mug:
#: 61 % of the segment inside; a required 90 % left the mug as two cylinders) or a
#: spoon sticking out of a pot holds the majority.
CONTAINED_MIN_INSIDE_SHARE = 0.5
#: The rim of a round segment is the height above the support below which this share of its
#: points lie: robust to the few points of an object resting on the container that joined
#: its wall (osd_learn learn41: 7 % of the wall's segment were of the box stacked on it,
#: whose footprint lies 88 % inside the wall's circle; its median height is above the rim,
#: so it is no content of the container).
RIM_HEIGHT_QUANTILE = 0.9
#: ... points inside lie within this factor of the wall's radius at their height (5 % for
#: the wall's thickness and the fit's error).
CONTAINED_RADIUS_MARGIN = 1.05
#: ... plus, when the frame's depth noise is known, this many sigma of it at the wall's
#: range, projected onto the support plane: the inner back wall and the outer front wall
#: lie in different parts of the image and carry the frame's slowly varying range error
#: independently, and the wall's centre comes from its own points; the difference of two
#: such errors has sigma sqrt(2) sigma, of which the one-sided 95 % bound is 1.645 of it
#: (the suite's cup at 1.5 m under kinect-real: its inner back wall lay 10 mm beyond the
#: outer wall's circle of 35 mm at a frame sigma of 6.9 mm).
CONTAINED_NOISE_SIGMAS = 1.645 * math.sqrt(2.0)
# --- contained_floors: a container's floor taken by the support ---------------------------
#: A support point is seen through the opening of a round object (:func:`contained_floors`)
#: when its ray from the sensor crosses the plane of the object's rim inside the rim's
#: circle by at least the wall's allowance for the range error (:func:`_noise_reach`). A
#: point's own range error moves it along its ray and leaves the ray unchanged; the error
#: is in the rim's circle, fitted on the wall's points.
#: The connected parts of those points are the container's floor when the container holds
#: at least this share of the links that leave them towards a support or an object (links
#: to points of no object, noise, are left out): a simple majority. Its floor is bounded
#: by the container's inner wall, except where the front wall is seen thin and the floor
#: touches the desk through it (kinect-real clutter seed 15, bowl 13: the bowl holds 73 %
#: of the links), while a support piece seen between objects is bounded by the support
#: and by several objects.
FLOOR_MIN_BORDER_SHARE = 0.5


class _Wall(NamedTuple):
    """A round segment's wall of revolution about the support normal (:func:`_round_footprint`).

    Its footprint circle has ``center`` (2,) [m] in the support plane's coordinates and a
    radius that changes linearly with the height above the support: ``radius`` [m] at the
    ``mean_height`` [m] of the segment's points and ``taper`` [m/m] per metre of height (0:
    a cylinder's wall; a flared cup's or a pot's otherwise), over the heights ``low`` ..
    ``high`` [m] its points span.
    """

    center: NDArray[np.float64]
    radius: float
    taper: float
    mean_height: float
    low: float
    high: float

    def radius_at(self, height: NDArray[np.float64]) -> NDArray[np.float64]:
        """Return the wall's radius [m] at ``height`` (P,) [m], held beyond its own heights."""
        return self.radius + self.taper * (np.clip(height, self.low, self.high)
                                           - self.mean_height)


class DisjointSets:
    """Union-find over ids whose group label is the root chosen by the order of joins.

    ``union(keep, absorb)`` hangs the root of ``absorb``'s group under the root of
    ``keep``'s group, so the joined group keeps the label of ``keep``'s group.

    Parameters
    ----------
    ids : iterable of hashable
        The elements, each in its own group.
    """

    def __init__(self, ids: Iterable[Hashable]) -> None:
        self.parent = {i: i for i in ids}

    def find(self, x: Hashable) -> Hashable:
        """Return the root (label) of ``x``'s group."""
        parent = self.parent
        while parent[x] != x:
            parent[x] = parent[parent[x]]  # path halving: the roots stay the same
            x = parent[x]
        return x

    def union(self, keep: Hashable, absorb: Hashable) -> None:
        """Join the groups of ``keep`` and ``absorb`` under the root of ``keep``'s group."""
        self.parent[self.find(absorb)] = self.find(keep)

    def relabel(self, comp: NDArray[np.int64], valid: NDArray[np.bool_]) -> NDArray[np.int64]:
        """Return a copy of ``comp`` (M,) with every ``valid`` entry replaced by its root.

        The ids are the values of ``comp[valid]``.
        """
        lut = np.arange(int(comp.max()) + 1, dtype=comp.dtype)
        for i in self.parent:
            lut[i] = self.find(i)
        out = comp.copy()
        out[valid] = lut[comp[valid]]
        return out


# ------------------------------------------------------------------------------------------
# Patches -> objects (local convexity)
# ------------------------------------------------------------------------------------------

def merge_patches(n: int, a: NDArray[np.int64], b: NDArray[np.int64], votes: NDArray,
                  yes: NDArray, sizes: NDArray | None = None,
                  exact: NDArray[np.bool_] | None = None,
                  creased: NDArray[np.bool_] | None = None,
                  pass_rate: float = 1.0) -> NDArray[np.int64]:
    """Group patches into objects from their border votes.

    Parameters
    ----------
    n : int
        Number of patches (ids 0 .. n-1).
    a, b : (P,) int64 arrays
        The two patches of each adjacent pair, ``a < b``.
    votes, yes : (P,) arrays
        Neighbour links across each pair's border, and how many of them are flat or convex.
    sizes : (n,) array, optional
        Points of every patch; with them a pair joins only across a border of at least
        :data:`JOIN_MIN_BORDER_VOTES` sqrt(points of the smaller patch) votes.
    exact : (n,) bool array, optional
        Patches whose links were tested exactly (the frame's measured noise below the
        fixed step floor at every point); default none (fixed tolerances: noise unknown).
    creased : (P,) bool array, optional
        Borders found to hold a crease along their whole length (e.g. from the median of
        their links, :func:`geomodel_ros.core.segmentation._creased_borders`): never
        joined, whatever their votes, and clear creases for the test below.
    pass_rate : float
        Share (0, 1] of the links on one smooth surface that vote flat or convex in this
        frame (e.g. :func:`geomodel_ros.core.segmentation._surface_pass_rate`: under noise
        the link tests fail by chance); the share of yes votes of every border not between
        two ``exact`` patches is taken relative to it, so the tests below compare the
        border with what one surface gives. 1 (the default): the shares as counted.

    Returns
    -------
    (n,) int64 array
        Object id of every patch, 0 .. K-1, numbered in the order of the group roots.

    Notes
    -----
    Pairs with at least :data:`JOIN_MIN_CONVEX_SHARE` of their votes flat or convex are
    joined, strongest evidence (most convex votes) first; a join is refused when the two
    groups already share a clear crease (:data:`CREASE_MIN_VOTES`,
    :data:`CREASE_MAX_CONVEX_SHARE`), and, across a border of two ``exact`` patches, when
    the votes summed over every border of the two groups hold no more than that share
    (:class:`_GroupContacts`). Both refusals depend on the joins made before them, so the
    pairs are joined one by one in order of evidence.
    """
    summed = np.zeros(len(a), dtype=bool) if exact is None else \
        np.take(exact, a) & np.take(exact, b)
    # Where both patches were tested exactly, a failed link meets a real edge, not noise.
    share = yes / (np.maximum(votes, 1) * np.where(summed, 1.0, pass_rate))
    crease = (votes >= CREASE_MIN_VOTES) & (share < CREASE_MAX_CONVEX_SHARE)
    joinable = share >= JOIN_MIN_CONVEX_SHARE
    if creased is not None:
        crease |= creased
        joinable &= ~creased
    creases = _crease_partners(a, b, crease)
    if sizes is not None:
        smaller = np.minimum(np.take(sizes, a), np.take(sizes, b))
        joinable &= votes >= JOIN_MIN_BORDER_VOTES * np.sqrt(smaller)
    sets = DisjointSets(range(n))
    members: dict[int, set[int]] = {}
    contact = _GroupContacts(a, b, votes, yes)
    order = np.argsort(-yes, kind="stable")
    for e in order[joinable[order]].tolist():
        ra, rb = sets.find(int(a[e])), sets.find(int(b[e]))
        if ra == rb:
            continue
        ma, mb = members.get(ra, {ra}), members.get(rb, {rb})
        if any(creases.get(x, set()) & mb for x in ma) or \
                (summed[e] and contact.share(ra, rb) <= JOIN_MIN_CONVEX_SHARE):
            continue
        sets.union(ra, rb)
        contact.union(ra, rb)
        members[ra] = ma | mb
        members.pop(rb, None)
    roots = np.array([sets.find(i) for i in range(n)])
    return np.unique(roots, return_inverse=True)[1].ravel()


class _GroupContacts:
    """Border votes summed over every pair of patch groups, kept up to date as groups join.

    Two groups of patches may border along several patch borders (a flared cup standing
    against a box: its rim touches the box's side along one border that votes convex by a
    narrow majority, 28 of 54 links in clutter scene 5, while its wall meets the box at a
    concave crease that the patches cut into short borders, 7 convex of 23); the join of
    the two groups is decided on all of them together (35 of 77: apart), and needs more
    than half of them (a tie is no evidence for the join: a sphere against a lying can in
    clutter scene 4, 54 of 108; two touching boxes whose tops differ by 12 mm, 17 of 34).
    Only where the link tests are exact: where noise sets the step, a link on one surface
    fails its test by chance (29-38 % of the links inside smooth patches on noisy synthetic
    frames), so the sum over a long border of one surface falls to about half, and summing
    refused joins of one box's faces under Kinect-class noise (clutter benchmark, Kinect row
    89.2 -> 87.2 % with IoU >= 0.8). With fixed tolerances the noise is unknown and nothing
    is summed (on real frames with ``noise_model: fixed`` it exceeds the floor; summing
    there cut the PCL mug scene into 57 segments instead of 53).

    Parameters
    ----------
    a, b : (P,) int64 arrays
        The two patches of each adjacent pair.
    votes, yes : (P,) arrays
        Links across each border and the flat or convex ones among them.
    """

    def __init__(self, a: NDArray[np.int64], b: NDArray[np.int64], votes: NDArray,
                 yes: NDArray) -> None:
        self.tally: dict[int, dict[int, list[float]]] = {}
        for x, y, v, w in zip(a.tolist(), b.tolist(), np.asarray(votes, float).tolist(),
                              np.asarray(yes, float).tolist()):
            self.tally.setdefault(x, {})[y] = [v, w]
            self.tally.setdefault(y, {})[x] = [v, w]

    def share(self, ra: int, rb: int) -> float:
        """Return the share of flat or convex votes over all borders of groups ``ra``, ``rb``."""
        v, w = self.tally.get(ra, {}).get(rb, (0.0, 0.0))
        return w / v if v > 0 else 1.0

    def union(self, keep: int, absorb: int) -> None:
        """Fold group ``absorb``'s borders into group ``keep``'s (the roots of a join)."""
        mine = self.tally.setdefault(keep, {})
        for other, (v, w) in self.tally.pop(absorb, {}).items():
            theirs = self.tally[other]
            del theirs[absorb]
            if other == keep:
                continue
            tv = mine.setdefault(other, [0.0, 0.0])
            tv[0] += v
            tv[1] += w
            theirs[keep] = tv


def _crease_partners(a: NDArray[np.int64], b: NDArray[np.int64], crease: NDArray[np.bool_]
                     ) -> dict[int, set[int]]:
    """Map each patch to the patches it meets at a clear crease (both directions)."""
    partners: dict[int, set[int]] = {}
    for x, y in zip(a[crease].tolist(), b[crease].tolist()):
        partners.setdefault(x, set()).add(y)
        partners.setdefault(y, set()).add(x)
    return partners


# ------------------------------------------------------------------------------------------
# Parts of one surface cut by an occluder
# ------------------------------------------------------------------------------------------

def segment_members(comp: NDArray[np.int64], valid: NDArray[np.bool_]
                    ) -> dict[int, NDArray[np.int64]]:
    """Map every segment id of ``comp[valid]`` (>= 0) to its ``valid`` rows, in increasing order.

    ``comp`` (M,) holds the segment ids, ``valid`` (M,) the rows that take part. One
    grouping of all rows (:func:`~geomodel_ros.core.fastmath.group_by_label`) gives the same
    arrays as ``np.flatnonzero(valid & (comp == i))`` for each id ``i``, at the cost of one
    pass instead of one per segment.
    """
    rows = np.flatnonzero(valid)
    if not len(rows):
        return {}
    order, ids, starts, ends = group_by_label(rows, comp[rows])
    return {int(i): order[s:e] for i, s, e in zip(ids.tolist(), starts.tolist(), ends.tolist())}


class _Segments:
    """Working points of the segments to join, with KD-trees built on first use.

    Parameters
    ----------
    points : (M, 3) float64 array [m]
        Working cloud, sensor at the origin.
    comp : (M,) int64 array
        Segment id of every working point.
    valid : (M,) bool array
        Points of the segments that take part (the others are noise).
    """

    def __init__(self, points: NDArray[np.float64], comp: NDArray[np.int64],
                 valid: NDArray[np.bool_]) -> None:
        self.points = points
        self.comp = comp
        self.members = segment_members(comp, valid)
        self._trees: dict[int, cKDTree] = {}
        self._cells: dict[int, _Cells] = {}
        self._ray_tree: cKDTree | None = None  # most scenes never need it
        self._rays: NDArray[np.float64] | None = None
        #: Mean normals around gap ends, by (segment, point, radius) (:func:`_mean_normal`).
        self.mean_normals: dict[tuple[int, int, float], NDArray[np.float64]] = {}
        #: Each segment's modeled type, once asked (:func:`_one_round_surface`).
        self.model_types: dict[int, PrimitiveType] = {}

    @cached_property
    def depth(self) -> NDArray[np.float64]:
        """Return every working point's range (M,) [m] (only gaps and terraces need it)."""
        return row_norms(self.points)

    def tree(self, seg: int) -> cKDTree:
        """Return the KD-tree of segment ``seg``'s points."""
        if seg not in self._trees:
            self._trees[seg] = cKDTree(self.points[self.members[seg]])
        return self._trees[seg]

    def cells(self, seg: int, cell: float) -> _Cells:
        """Return segment ``seg``'s points grouped in cells of side ``cell`` [m] (:func:`_cells`).

        Built once per segment: a segment is the smaller of many pairs, always with the same
        ``cell``.
        """
        if seg not in self._cells:
            self._cells[seg] = _cells(self.points[self.members[seg]], cell)
        return self._cells[seg]

    def rays(self) -> NDArray[np.float64]:
        """Return all working points' viewing directions (M, 3) (unit vectors)."""
        if self._rays is None:
            self._rays = self.points / np.maximum(self.depth, _TINY)[:, None]
        return self._rays

    def ray_tree(self) -> cKDTree:
        """Return the KD-tree of all working points' viewing directions (:meth:`rays`)."""
        if self._ray_tree is None:
            self._ray_tree = cKDTree(self.rays())
        return self._ray_tree


@dataclass(frozen=True)
class _Gap:
    """The gap between two segments.

    Its ends are the closest points ``pa`` (working-point index, on segment ``small``) and
    ``pb`` (on segment ``big``), ``length`` [m] apart; ``u`` (3,) is the unit direction from
    pa to pb.
    """

    small: int
    big: int
    pa: int
    pb: int
    length: float
    u: NDArray[np.float64]


def join_occluded_parts(points: NDArray[np.float64], normals: NDArray[np.float64],
                        comp: NDArray[np.int64], valid: NDArray[np.bool_],
                        params: ModelingParams) -> NDArray[np.int64]:
    """Join segments that are two visible parts of one surface cut by an occluder.

    Parameters
    ----------
    points, normals : (M, 3) float64 arrays
        Working cloud [m] (sensor at the origin) and its unit normals.
    comp : (M,) int64 array
        Segment id of every working point.
    valid : (M,) bool array
        Points of the segments that take part (the others keep their ids).
    params : ModelingParams
        ``seg_voxel_size``, ``seg_max_edge_factor`` and ``seg_max_occlusion_gap`` are used.

    Returns
    -------
    (M,) int64 array
        ``comp`` with each joined group labelled by its root segment.

    Notes
    -----
    Two segments are joined when their closest points are farther apart than a link (they
    do not touch) but closer than ``seg_max_occlusion_gap`` (:func:`_closest_gap`), the
    surface continues across the gap (:func:`_surface_continues`), the gap is hidden
    behind a nearer third object, neither of the two (:func:`_gap_is_hidden`), and, when
    either segment is modeled as a round shape, the two together are one
    (:func:`_one_round_surface`). Pairs are visited in the order of their segment ids; a
    pair already in one group is not tested again.
    """
    segs = _Segments(points, comp, valid)
    if len(segs.members) < 2:
        return comp
    centers = {i: points[m].mean(axis=0) for i, m in segs.members.items()}
    radius = {i: float(np.linalg.norm(points[m] - centers[i], axis=1).max())
              for i, m in segs.members.items()}
    sets = DisjointSets(segs.members)
    keys = sorted(segs.members)
    for ai, a in enumerate(keys):
        for b in keys[ai + 1:]:
            # Bounding spheres farther apart than the largest gap: no closer points either.
            reach = float(np.linalg.norm(centers[a] - centers[b])) - radius[a] - radius[b]
            if reach > params.seg_max_occlusion_gap or sets.find(a) == sets.find(b):
                continue
            gap = _closest_gap(segs, a, b, params)
            if (gap is not None and _surface_continues(segs, normals, gap, params)
                    and _gap_is_hidden(segs, gap, params.seg_voxel_size)
                    and _one_round_surface(segs, gap, params)):
                sets.union(a, b)
    return sets.relabel(comp, valid)


def _closest_gap(segs: _Segments, a: int, b: int, params: ModelingParams) -> _Gap | None:
    """Find the gap between segments ``a`` and ``b`` (their closest points).

    None unless the closest points are farther apart than a link (else the segments would
    touch) and at most ``seg_max_occlusion_gap`` apart.
    """
    link = params.seg_max_edge_factor * params.seg_voxel_size
    max_gap = params.seg_max_occlusion_gap
    small, big = (a, b) if len(segs.members[a]) <= len(segs.members[b]) else (b, a)
    rows = segs.members[small]
    # Only gaps up to seg_max_occlusion_gap matter: farther pairs come back inf.
    if len(rows) > GAP_DIRECT_POINTS:
        picked, reached = _gap_candidates(segs.points[rows], segs.tree(big),
                                          GAP_CELL_LINKS * link, max_gap,
                                          segs.cells(small, GAP_CELL_LINKS * link))
        # A distance reached bounds the nearest from above: within a link, they touch.
        if not len(picked) or reached <= link:
            return None
        rows = rows[picked]
        # Rows farther than the distance reached are not the nearest (they come back inf).
        max_gap = min(max_gap, reached + GAP_MARGIN)
    else:
        # A few rows first: the distance they reach bounds the nearest from above.
        probe, _ = segs.tree(big).query(segs.points[rows[::GAP_PROBE_STRIDE]], k=1,
                                        distance_upper_bound=max_gap)
        reached = float(probe.min())
        if reached <= link:
            return None
        max_gap = min(max_gap, reached + GAP_MARGIN)
    d, j = segs.tree(big).query(segs.points[rows], k=1, distance_upper_bound=max_gap)
    k = int(np.argmin(d))
    length = float(d[k])
    if length <= link or length > params.seg_max_occlusion_gap:
        return None
    pa = int(rows[k])
    pb = int(segs.members[big][int(j[k])])
    return _Gap(small, big, pa, pb, length, (segs.points[pb] - segs.points[pa]) / length)


class _Cells(NamedTuple):
    """Points grouped in cubic cells: each cell's first point stands for it.

    ``first`` (C,) holds the row of each cell's first point, ``inv`` (Q,) the cell of every
    row, ``reach`` (C,) [m] the farthest of a cell's rows from its first one.
    """

    first: NDArray[np.int64]
    inv: NDArray[np.int64]
    reach: NDArray[np.float64]


def _cells(q: NDArray[np.float64], cell: float) -> _Cells:
    """Group the rows of ``q`` (Q, 3) [m] in cubic cells of side ``cell`` [m]."""
    key = np.floor(q / cell).astype(np.int64)
    key -= key.min(axis=0)
    span = key.max(axis=0) + 1
    _, first, inv = np.unique((key[:, 0] * span[1] + key[:, 1]) * span[2] + key[:, 2],
                              return_index=True, return_inverse=True)
    inv = inv.ravel()
    reach = np.zeros(len(first))
    np.maximum.at(reach, inv, row_norms(q - q[first][inv]))
    return _Cells(first, inv, reach)


def _gap_candidates(q: NDArray[np.float64], tree: cKDTree, cell: float, max_gap: float,
                    cells: _Cells | None = None) -> tuple[NDArray[np.int64], float]:
    """Rows of ``q`` (Q, 3) [m] that may be the nearest of them to the points of ``tree``.

    The rows are grouped in cubic cells of side ``cell`` [m] (:func:`_cells`, or ``cells``
    when given, grouped so before); each cell's first row stands for it, and r is the
    farthest of the cell's rows from it. A row p of a cell whose
    representative s lies at distance D from the tree's points is at least D - r from
    them (triangle inequality), and the nearest representative's D_min is a distance
    reached: only the cells with D - r <= D_min can hold the nearest row (every row
    nearest to within the float margin :data:`GAP_MARGIN` is kept). Cells whose
    representative lies beyond ``max_gap`` [m] + r hold no row within ``max_gap`` [m].

    Returns
    -------
    rows : (C,) int64 array
        Increasing row indices (the candidates keep their order, so the first of equally
        near rows is the same as among all rows); empty when no row is within ``max_gap``.
    reached : float
        D_min [m], the distance of a row from the tree's points (inf when the rows are
        empty): the nearest row is at most this far.
    """
    first, inv, reach = _cells(q, cell) if cells is None else cells
    dist, _ = tree.query(q[first], k=1,
                         distance_upper_bound=max_gap + float(reach.max()) + GAP_MARGIN)
    best = float(dist.min())
    if not math.isfinite(best):
        return np.zeros(0, dtype=np.int64), math.inf
    return np.flatnonzero((dist - reach <= best + GAP_MARGIN)[inv]), best


def _surface_continues(segs: _Segments, normals: NDArray[np.float64], gap: _Gap,
                       params: ModelingParams) -> bool:
    """Whether the mean normals around both ends of the gap agree and lie across it."""
    link = params.seg_max_edge_factor * params.seg_voxel_size
    radius = OCCLUSION_NORMAL_RADIUS_LINKS * link
    max_tilt = math.sin(OCCLUSION_MAX_GAP_TILT)
    # One end's normal decides alone when it lies off the gap; the other is not needed then.
    na = _mean_normal(segs, normals, gap.small, gap.pa, radius)
    if abs(float(na @ gap.u)) > max_tilt:
        return False
    nb = _mean_normal(segs, normals, gap.big, gap.pb, radius)
    return not (abs(float(na @ nb)) < math.cos(OCCLUSION_MAX_NORMAL_ANGLE)
                or abs(float(nb @ gap.u)) > max_tilt)


def _mean_normal(segs: _Segments, normals: NDArray[np.float64], seg: int, at: int,
                 radius: float) -> NDArray[np.float64]:
    """Return the unit mean normal (3,) of segment ``seg`` around its point ``at``.

    The normals within ``radius`` [m] of ``at`` are averaged, each flipped to the side of
    ``at``'s own normal. A point is the end of several gaps (a segment's corner nearest
    to several others), so each mean is kept in ``segs`` for the frame's ``normals``.
    """
    key = (seg, at, radius)
    if key not in segs.mean_normals:
        near = segs.members[seg][segs.tree(seg).query_ball_point(segs.points[at], radius)]
        nrm = normals[near]
        nrm = nrm * np.sign(nrm @ normals[at])[:, None]
        mean = nrm.sum(axis=0)
        segs.mean_normals[key] = mean / max(float(np.linalg.norm(mean)), _TINY)
    return segs.mean_normals[key]


def _gap_is_hidden(segs: _Segments, gap: _Gap, voxel: float) -> bool:
    """Whether the gap is hidden behind nearer points and nowhere seen open.

    On the viewing ray (sensor at the origin) of each sample of the gap
    (:data:`OCCLUSION_GAP_SAMPLES`) the nearest measured direction is looked up. A ray with
    a measured point is *seen*; it is hidden when that point is nearer than the sample by
    more than :data:`OCCLUSION_NEARER_MARGIN_VOXELS` and belongs to neither of the gap's
    two segments, and open otherwise. The gap is hidden when enough samples are seen and
    none of them is open.
    """
    p = segs.points
    samples = p[gap.pa] + OCCLUSION_GAP_SAMPLES[:, None] * (p[gap.pb] - p[gap.pa])
    s_depth = np.linalg.norm(samples, axis=1)
    tol = OCCLUSION_RAY_TOLERANCE_VOXELS * voxel / s_depth
    dist, hit = _nearest_rays(segs, samples / s_depth[:, None], tol)
    seen = dist <= tol
    nearer = segs.depth[hit] < s_depth - OCCLUSION_NEARER_MARGIN_VOXELS * voxel
    # Only a third object occludes: a part in front of the gap itself (a container's wall
    # in front of its own floor) bounds its surface there instead of hiding its continuation.
    nearer &= (segs.comp[hit] != segs.comp[gap.pa]) & (segs.comp[hit] != segs.comp[gap.pb])
    return bool(np.all(nearer[seen])
                and seen.sum() >= OCCLUSION_MIN_SEEN_SHARE * len(OCCLUSION_GAP_SAMPLES))


def _one_round_surface(segs: _Segments, gap: _Gap, params: ModelingParams) -> bool:
    """Whether the gap's two segments may be one surface by the shapes they are modeled as.

    Equal normals at the two ends are the evidence of one surface continuing behind an
    occluder when the surface is flat: a plane's or a box face's normals are equal
    everywhere. A round surface (:data:`ROUND_TYPES`) turns everywhere, so the facing
    parts of two different round objects (two cans side by side, a sphere beside a can)
    have equal normals at their closest points as often as one object's parts do. When
    either segment alone is modeled as a round shape, the two together must be modeled as
    the shape of one of them, and that model must hold each part: at least
    :data:`ROUND_PART_SHARE` of its points within ``ransac_threshold`` (one can's two
    visible parts are one cylinder; two cans, or a can and a box, are none of their
    shapes; a piece of a box taken for a frustum and the rest of the box are one cuboid).
    A model verified on the two together may leave the smaller part off it altogether.
    The models are the modeling's own (:func:`geomodel_ros.core.modeling.model_object`
    on the working points), asked only for the pairs that passed the other tests.
    """
    from geomodel_ros.core.modeling import model_object  # it imports the segmentation

    def model(points: NDArray[np.float64]) -> Primitive:
        rng = np.random.default_rng(params.seed)
        return model_object(points, 0, params, rng, params.seg_voxel_size)

    parts = [segs.points[segs.members[s]] for s in (gap.small, gap.big)]
    for s, pts in zip((gap.small, gap.big), parts):
        if s not in segs.model_types:
            segs.model_types[s] = model(pts).type
    types = {segs.model_types[s] for s in (gap.small, gap.big)}
    if not types & ROUND_TYPES:
        return True
    union = model(np.vstack(parts))
    return union.type is not PrimitiveType.UNKNOWN and union.type in types and all(
        estimate_confidence(union, pts, params.ransac_threshold).inlier_ratio
        >= ROUND_PART_SHARE for pts in parts)


def _nearest_rays(segs: _Segments, dirs: NDArray[np.float64], tol: NDArray[np.float64]
                  ) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
    """Return the nearest working point's direction to each of ``dirs`` (S, 3) (unit vectors).

    The distances (S,) and rows (S,) are those of ``segs.ray_tree().query(dirs, k=1)``
    wherever the distance is within ``tol`` (S,); elsewhere the distance is also beyond
    ``tol`` and the row is any. Only the directions inside the box of ``dirs`` grown by the
    largest ``tol`` (:data:`RAY_BOX_MARGIN`) can be within ``tol``, so a tree of those
    (a gap's few hundred instead of the frame's tens of thousands) finds the same nearest
    point, unless two are equally near: then the frame's tree decides, as before.
    """
    rays = segs.rays()
    grow = float(tol.max()) + RAY_BOX_MARGIN
    lo, hi = dirs.min(axis=0) - grow, dirs.max(axis=0) + grow
    # The box's first side over all directions, the other two over the few inside it.
    near = np.flatnonzero((rays[:, 0] >= lo[0]) & (rays[:, 0] <= hi[0]))
    inside = rays[near, 1:]
    near = near[np.all((inside >= lo[1:]) & (inside <= hi[1:]), axis=1)]
    if not len(near):
        return np.full(len(dirs), np.inf), np.zeros(len(dirs), dtype=np.int64)
    dist, idx = cKDTree(rays[near]).query(dirs, k=2)
    if np.any((dist[:, 0] <= tol) & (dist[:, 0] == dist[:, 1])):
        dist, hit = segs.ray_tree().query(dirs, k=1)
        return dist, np.minimum(hit, len(rays) - 1)
    return dist[:, 0], near[np.minimum(idx[:, 0], len(near) - 1)]


# ------------------------------------------------------------------------------------------
# The inner and outer walls of an open round container
# ------------------------------------------------------------------------------------------

def join_contained_parts(points: NDArray[np.float64], normals: NDArray[np.float64],
                         comp: NDArray[np.int64], valid: NDArray[np.bool_],
                         support: PlaneModel, noise: NoiseEstimate | None = None,
                         patches: tuple[NDArray[np.int64],
                                        Callable[[NDArray[np.int64]], NDArray[np.bool_]]]
                         | None = None, link: tuple[float, float] | None = None
                         ) -> NDArray[np.int64]:
    """Join the inner wall of an open round container (bowl, cup, pot) to its outer wall.

    Parameters
    ----------
    points, normals : (M, 3) float64 arrays
        Working cloud [m] and its unit normals.
    comp : (M,) int64 array
        Segment id of every working point.
    valid : (M,) bool array
        Points of the segments that take part (the others keep their ids).
    support : PlaneModel
        The plane the container stands on.
    noise : NoiseEstimate, optional
        The frame's depth noise; when given, a wall's radius is widened by
        :data:`CONTAINED_NOISE_SIGMAS` of it (:func:`_noise_reach`).
    patches : (labels, concave), optional
        The smooth patch of every point ((M,) int64, ids >= 0; -1: none) and a function
        that, given patch ids (Q,), tells which patches are concave as seen from the sensor
        (a bool array indexed by patch id; e.g. from
        :func:`geomodel_ros.core.segmentation._convex_objects`); with them a concave patch
        is judged on its own (Notes).
    link : (link, stand), optional
        The longest link between neighbours of one surface [m] and the height [m] above
        the support within which an object stands on it; with them and ``patches``, what
        touches a container's rim from outside first parts from its inside
        (:func:`_part_at_rims`).

    Returns
    -------
    (M,) int64 array
        ``comp`` with each joined group labelled by its root segment.

    Notes
    -----
    Seen from above an open container shows its outer front wall and, behind the rim, its
    inner back wall; they meet only at the hidden back rim, so local convexity keeps them
    apart. A segment is joined to a round segment (:func:`_round_footprint`: a wall of
    revolution about the support normal, straight or tapered) when most of its points lie
    inside that wall, within its radius at their own heights, its median height above the
    support is below the round segment's rim (:data:`CONTAINED_MIN_INSIDE_SHARE`,
    :data:`RIM_HEIGHT_QUANTILE`) and their heights overlap. Round segments are visited
    largest first.

    A container's inner back wall ends at its back rim, and whatever is seen beyond the rim
    lies behind the container, often touching it (a can or a box against its back): there
    the thin rim leaves no depth jump and the two surfaces' normals agree, so the inner
    wall may join that object by the border votes before this join (kinect-real clutter
    seeds 4 and 18: a cup's inner wall of 290 and 270 points in a segment of 830 and 893,
    the rest a can; its inside share 0.45 and 0.37). So, with ``patches``, each concave
    patch of :data:`CONTAINED_MIN_POINTS` or more points is judged on its own points (the
    footprint test, and its median height within the round segment's heights:
    :func:`_move_concave_inside`) and, when it lies inside a round segment of another
    group, leaves its segment for the round one's. A container's inside is the one
    surface seen concave from outside it, an object seen from outside is convex or flat
    (:func:`geomodel_ros.core.segmentation._concave_patches`), and two solids do not
    interpenetrate: a concave surface inside a round wall and within its heights is that
    container's inside (its inner wall, or its floor with the curve up into the wall: on
    the Kinect-noise clutter a cup's floor of 257 points had joined points of the desk, another
    of 170 the cup beside it). Convex content (a fruit, a spoon) is judged as a segment
    only.
    """
    n = support.normal
    basis = np.column_stack(perpendicular_basis(n))
    if patches is not None and link is not None:
        comp = _part_at_rims(comp, valid, *patches, points, points @ basis,
                             normals @ basis, np.abs(points @ n + support.d), n, noise, *link)
    ids = [int(i) for i in np.unique(comp[valid])]
    if len(ids) < 2:
        return comp
    members = segment_members(comp, valid)
    foot = {i: points[m] @ basis for i, m in members.items()}
    height = {i: np.abs(points[m] @ n + support.d) for i, m in members.items()}
    walls = {}
    for i, xy in foot.items():
        if len(xy) >= CONTAINED_MIN_POINTS:
            wall = _round_footprint(xy, normals[members[i]] @ basis, height[i])
            if wall is not None:
                walls[i] = (wall, _noise_reach(points[members[i]], n, noise))
    if not walls:
        return comp
    sets = DisjointSets(ids)
    order = sorted(walls.items(), key=lambda kv: -len(members[kv[0]]))
    _join_inside(sets, [i for i in ids if len(members[i]) >= CONTAINED_MIN_POINTS], foot,
                 height, order)
    out = sets.relabel(comp, valid)
    if patches is not None:
        _move_concave_inside(out, valid, *patches, points @ basis,
                             np.abs(points @ n + support.d),
                             [(sets.find(i), w, height[i]) for i, w in order])
    return out


def _part_at_rims(comp: NDArray[np.int64], valid: NDArray[np.bool_],
                  labels: NDArray[np.int64],
                  concave: Callable[[NDArray[np.int64]], NDArray[np.bool_]],
                  points: NDArray[np.float64], xy: NDArray[np.float64],
                  n_xy: NDArray[np.float64], up: NDArray[np.float64], normal: NDArray[np.float64],
                  noise: NoiseEstimate | None, link: float, stand: float
                  ) -> NDArray[np.int64]:
    """Part from a container's inside what its segment holds beyond its rim only through it.

    A patch seen concave from the sensor whose points lie on a wall of revolution about
    the support normal (:func:`_round_footprint`) is an open container's inside. Where
    another object touches its rim from outside (a box's face, a can), the inside bends
    away from that object like the far side of a ridge and the border votes join the two
    (noise-free clutter seed 46: a bowl's inside against the front face of the box its
    rim touches, 24 of 43 links convex; seed 48: a lying can in front of a bowl's near
    rim, 29 of 53); locally that ridge is the container's own rim (a cup's inner wall
    meets its outer wall across it with the same votes, seed 18: 28 of 48). Two solids do
    not interpenetrate: what lies outside the container's wall belongs to it only as its
    outer wall (a wall of revolution holding the inside, :func:`_join_inside`'s test) or
    what is attached to that (a handle). So the segment's points other than the inside
    are linked among themselves (neighbours within ``link`` [m]); each group of them that
    lies outside the inside's wall (:data:`CONTAINED_MIN_INSIDE_SHARE` of it beyond
    :data:`CONTAINED_RADIUS_MARGIN` times its radius at their heights plus the range
    error, :func:`_noise_reach`, plus a link: the container's own outer wall, linked to
    the inside across the rim, lies within a link of it; kinect-real clutter seed 20 cup
    5, whose outer wall is no round wall under that noise), touches the inside over its
    rim (:func:`_over_rim`), holds no such outer wall and reaches down to the support
    (its lowest point at most ``stand`` [m] above it: an object of its own stands there,
    while a handle hangs on its container, PCL mug scene) leaves it as a segment of its
    own. Patches of
    :data:`CONTAINED_MIN_POINTS` or more points that share their segment are tested,
    largest first; ``labels``, ``concave``, ``xy``, ``up`` as in
    :func:`_move_concave_inside`, ``n_xy`` (M, 2) the normals in the support plane's
    coordinates, ``normal`` (3,) the support's, ``noise`` the frame's. Returns the new
    segment ids (``comp`` is not changed in place).
    """
    on = np.flatnonzero(valid & (labels >= 0))
    if not len(on):
        return comp
    order, ids, starts, ends = group_by_label(on, labels[on])
    size = ends - starts
    top = int(comp.max()) + 1
    seg = comp[order[starts]]
    seg_size = np.bincount(comp[on], minlength=top)
    # The rest of a patch's segment holds enough points, some of them down at the support
    # (the tests of the loop below before any parting, which only takes points away): only
    # then is the patch asked whether it is concave.
    member = valid & (comp >= 0)
    low = member & (up <= stand)
    low_before = np.concatenate([[0], np.cumsum(low[order])])
    shared = np.flatnonzero((size >= CONTAINED_MIN_POINTS) & (seg_size[seg] > size)
                            & (np.bincount(comp[member], minlength=top)[seg] - size
                               >= CONTAINED_MIN_POINTS)
                            & (np.bincount(comp[low], minlength=top)[seg]
                               > low_before[ends] - low_before[starts]))
    if not len(shared):
        return comp
    bent = concave(ids[shared])
    inner = [int(q) for q in shared[np.argsort(-size[shared], kind="stable")]
             if bent[ids[q]]]
    out = comp.copy()
    fresh = int(comp.max()) + 1
    # Each segment's rows; a parted group leaves its segment for a new one of its own.
    members = segment_members(comp, valid & (comp >= 0)) if inner else {}
    for q in inner:
        rows = order[starts[q]:ends[q]]
        at = int(out[rows[0]])
        if np.any(out[rows] != at):
            continue
        rest = members[at]
        rest = rest[(out[rest] == at) & (labels[rest] != ids[q])]
        # Only a group that reaches down to the support leaves (:func:`_parts_beyond_rim`):
        # where nothing else in the segment does, the wall need not be fitted.
        if len(rest) < CONTAINED_MIN_POINTS or up[rest].min() > stand:
            continue
        wall = _round_footprint(xy[rows], n_xy[rows], up[rows])
        if wall is None:
            continue
        reach = _noise_reach(points[rows], normal, noise)
        for part in _parts_beyond_rim(points, xy, n_xy, up, labels, rows, rest, wall, reach,
                                      link, stand):
            out[part] = fresh
            members[fresh] = part
            fresh += 1
    return out


def _parts_beyond_rim(points: NDArray[np.float64], xy: NDArray[np.float64],
                      n_xy: NDArray[np.float64], up: NDArray[np.float64],
                      labels: NDArray[np.int64], inside: NDArray[np.int64],
                      rest: NDArray[np.int64], wall: _Wall, reach: float, link: float,
                      stand: float) -> list[NDArray[np.int64]]:
    """Return the linked groups of ``rest`` that leave the container (:func:`_part_at_rims`).

    ``inside`` are the rows of the container's inside, ``wall`` its round footprint and
    ``reach`` its range-error allowance [m]; the other arguments as there.
    """
    # The container's own outer wall is linked to its inside across the rim: it lies
    # within a link beyond the inside's wall.
    beyond = (np.linalg.norm(xy[rest] - wall.center, axis=1)
              > CONTAINED_RADIUS_MARGIN * wall.radius_at(up[rest]) + reach + link)
    if not beyond.any():
        return []
    pairs = cKDTree(points[rest]).query_pairs(link, output_type="ndarray")
    group = pair_components(len(rest), pairs)
    parts = []
    for g in np.unique(group).tolist():
        part = rest[group == g]
        if len(part) < CONTAINED_MIN_POINTS or \
                beyond[group == g].mean() < CONTAINED_MIN_INSIDE_SHARE:
            continue
        if up[part].min() > stand or not _over_rim(points, up, inside, part, link) or \
                _holds_inside(part, labels, xy, n_xy, up, inside, reach):
            continue
        parts.append(part)
    return parts


def _over_rim(points: NDArray[np.float64], up: NDArray[np.float64], inside: NDArray[np.int64],
              part: NDArray[np.int64], link: float) -> bool:
    """Whether ``part`` touches the ``inside`` rows of a container over its rim.

    An object outside a container meets its inside only across the rim, the upper end of
    its wall: the inside's points within ``link`` [m] of the part lie, in the median, at
    least as high above the support (``up`` (M,) [m]) as the inside's own points do.
    Measured on the partings of the clutter benchmark (a box's face, a can, a lying can
    against a bowl's or a cup's rim; seeds 12-57, noise-free and kinect-real): the points
    touched lie at the 0.81-0.98 quantile of the inside's heights, in the median; on the
    PCL office frame a folded cloth seen concave (radius 16 cm) touched the rest of the
    cloth along its lower edge, at the 0.36 quantile: one surface, not over a rim.
    """
    near, _ = cKDTree(points[part]).query(points[inside], distance_upper_bound=link)
    touched = inside[np.isfinite(near)]
    return bool(len(touched)) and np.median(up[touched]) >= np.median(up[inside])


def _holds_inside(part: NDArray[np.int64], labels: NDArray[np.int64], xy: NDArray[np.float64],
                  n_xy: NDArray[np.float64], up: NDArray[np.float64],
                  inside: NDArray[np.int64], reach: float) -> bool:
    """Whether a patch of ``part`` is a wall of revolution that holds the ``inside`` rows.

    The test of :func:`_join_inside` (:data:`CONTAINED_MIN_INSIDE_SHARE` of the inside's
    points within :data:`CONTAINED_RADIUS_MARGIN` times the wall's radius plus ``reach``
    [m]) on each patch of :data:`CONTAINED_MIN_POINTS` or more points of ``part``, with
    each wall it lies on (:func:`_round_walls`).
    """
    for p in np.unique(labels[part]).tolist():
        rows = part[labels[part] == p]
        if len(rows) < CONTAINED_MIN_POINTS:
            continue
        for wall in _round_walls(xy[rows], n_xy[rows], up[rows]):
            within = (np.linalg.norm(xy[inside] - wall.center, axis=1)
                      <= CONTAINED_RADIUS_MARGIN * wall.radius_at(up[inside]) + reach)
            if within.mean() >= CONTAINED_MIN_INSIDE_SHARE:
                return True
    return False


def _round_walls(xy: NDArray[np.float64], n_xy: NDArray[np.float64],
                 height: NDArray[np.float64]) -> list[_Wall]:
    """Return every wall of revolution, straight and tapered, that a footprint lies on.

    The tests of :func:`_round_footprint` (arguments alike), without stopping at the
    straight wall: over the near side of a flared cup's outer wall a circle fits too, but
    its radius is the wall's at no height (clutter seed 18: 32.7 mm for a taper from
    35 to 45 mm), and only the tapered wall holds the cup's inside.
    """
    n_xy = n_xy / np.maximum(np.linalg.norm(n_xy, axis=1), _TINY)[:, None]
    if _turning_bins(n_xy) < ROUND_MIN_TURNING_BINS:
        return []
    walls = []
    for tapered in (False, True):
        wall = _fit_wall(xy, height, tapered)
        if wall is not None and _is_round(wall, xy, n_xy, height) and \
                (not tapered or _closer_than_plane(wall, xy, height)):
            walls.append(wall)
    return walls


def _move_concave_inside(comp: NDArray[np.int64], valid: NDArray[np.bool_],
                         labels: NDArray[np.int64],
                         concave: Callable[[NDArray[np.int64]], NDArray[np.bool_]],
                         xy: NDArray[np.float64], up: NDArray[np.float64],
                         walls: list[tuple[int, tuple[_Wall, float], NDArray[np.float64]]]
                         ) -> None:
    """Move, in ``comp``, each concave patch inside a round wall to the wall's segment.

    ``comp`` (M,) the segments after the container join (``valid`` the points that take
    part), ``labels`` (M,) the smooth patch of every point (-1: none) and ``concave`` the
    test of patches (:func:`join_contained_parts`), ``xy`` (M, 2) [m] and ``up`` (M,) [m]
    every point in the support plane's coordinates and above it; ``walls`` the round
    segments in the order visited, each as (its segment's label in ``comp``, (its wall,
    allowance for the range error), its points' heights). A patch of
    :data:`CONTAINED_MIN_POINTS` or more points is held by the first wall for which the
    footprint test of :func:`_join_inside` holds on its points and its median height lies
    between the wall's lowest point and its rim (a container's inside lies within its
    wall's heights; a face of a box that a sphere rests on lies below the sphere). It
    moves there when it lies in another segment and is concave; only those patches are
    tested for concavity (the test walks every link inside a patch).
    """
    on = np.flatnonzero(valid & (labels >= 0))
    if not len(on) or not walls:
        return
    order, ids, starts, ends = group_by_label(on, labels[on])
    # Each patch's bounding box in the support plane: only patches whose box meets a
    # wall's are tested point by point.
    lo = np.minimum.reduceat(xy[order], starts, axis=0)
    hi = np.maximum.reduceat(xy[order], starts, axis=0)
    big = ends - starts >= CONTAINED_MIN_POINTS
    held = np.full(len(ids), -1)  # the first wall that holds each patch
    for w, (_, (wall, reach), wall_height) in enumerate(walls):
        far = CONTAINED_RADIUS_MARGIN * float(
            wall.radius_at(np.array([wall.low, wall.high])).max()) + reach
        near = np.flatnonzero(big & (held < 0) & (lo <= wall.center + far).all(axis=1)
                              & (hi >= wall.center - far).all(axis=1))
        rim = np.quantile(wall_height, RIM_HEIGHT_QUANTILE)
        for q in near.tolist():
            rows = order[starts[q]:ends[q]]
            h = up[rows]
            inside = (np.linalg.norm(xy[rows] - wall.center, axis=1)
                      <= CONTAINED_RADIUS_MARGIN * wall.radius_at(h) + reach)
            if inside.mean() >= CONTAINED_MIN_INSIDE_SHARE and \
                    wall.low <= np.median(h) <= rim:
                held[q] = w
    label_of = np.array([w[0] for w in walls])
    moving = [q for q in np.flatnonzero(held >= 0).tolist()
              if comp[order[starts[q]]] != label_of[held[q]]]
    if not moving:
        return
    bent = concave(ids[moving])
    for q in moving:
        if bent[ids[q]]:
            comp[order[starts[q]:ends[q]]] = label_of[held[q]]


def contained_floors(points: NDArray[np.float64], normals: NDArray[np.float64],
                     comp: NDArray[np.int64], valid: NDArray[np.bool_],
                     support: NDArray[np.int64], plane: PlaneModel, in_support: NDArray[np.bool_],
                     neighbors: NDArray[np.int64], sqdist: NDArray[np.float64], link: float,
                     stand: float, noise: NoiseEstimate | None = None
                     ) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """Find the support points that are the floor of an open container, and its segment.

    Parameters
    ----------
    points, normals : (M, 3) float64 arrays
        Working cloud [m] (sensor at the origin) and its unit normals.
    comp : (M,) int64 array
        Segment (object) id of every working point.
    valid : (M,) bool array
        Points of the objects (the others are supports or noise).
    support : (S,) int64 array
        Working points of one support.
    plane : PlaneModel
        That support's plane.
    in_support : (M,) bool array
        Points of any support.
    neighbors, sqdist : (M, k) arrays
        Nearest neighbours of every working point and their squared distances [m^2].
    link : float
        Two points closer than this [m] are linked (as the support's pieces are).
    stand : float
        An object stands on the support when its lowest point is at most this [m] above it.
    noise : NoiseEstimate, optional
        The frame's depth noise: the rim's circle is narrowed by :func:`_noise_reach`.

    Returns
    -------
    taken : (T,) int64 array
        Working points of ``support`` that are a container's floor.
    owner : (T,) int64 array
        The container's segment id for each.

    Notes
    -----
    Under a real sensor's noise the support's band (four sigma of a single point, the
    frame's slowly varying error included) is 10-14 mm thick, and the floor of a bowl a few
    millimetres above the desk lies in it; when large enough it stays a piece of the
    support, alone or linked to the desk where the bowl's front wall is seen thin. Its
    height cannot tell it from the desk (the slow error of its mean against the desk
    around it has no known correlation length); its place does. The objects that stand on
    the support (lowest point within ``stand``) and whose footprint is a wall of
    revolution (:func:`_round_footprint`) are visited largest first; a support point is
    seen through such a wall's opening when its ray from the sensor crosses the height of
    the rim (:data:`RIM_HEIGHT_QUANTILE` of the wall's heights) inside the rim's circle,
    narrowed by the wall's range error (:func:`_noise_reach`). A solid closed on top
    (a can) hides every such point, and the support seen beside or behind an object has a
    ray that passes outside its rim. The connected parts of the points seen through one
    opening are its floor when they are bounded mostly by the container itself
    (:data:`FLOOR_MIN_BORDER_SHARE`), not by the support and other objects. The floor of a
    ring without one (a roll of tape lying flat) cannot be told from the support seen
    through it, and is taken too.
    """
    empty = np.zeros(0, dtype=np.int64)
    if not len(support) or not valid.any():
        return empty, empty
    n, d = plane.normal, plane.d
    if d < 0:  # normal towards the sensor (at the origin): its height is d
        n, d = -n, -d
    basis = np.column_stack(perpendicular_basis(n))
    walls = _standing_walls(points, normals, comp, valid, n, d, basis, stand, noise)
    if not walls:
        return empty, empty
    sp = take_rows(points, support)
    sh = sp @ n + d
    sx, sy = sp @ basis[:, 0], sp @ basis[:, 1]
    free = np.ones(len(support), dtype=bool)
    taken, owner = [], []
    for _, i, center, rim, opening in sorted(walls, key=lambda w: (-w[0], w[1])):
        seen = free & (sh < rim) & _through_opening(sx, sy, sh, d, center, rim, opening)
        cand = support[seen]
        if not len(cand):
            continue
        floor = _bounded_by(cand, i, comp, valid, in_support, neighbors, sqdist, link)
        if floor.any():
            taken.append(cand[floor])
            owner.append(np.full(int(floor.sum()), i, dtype=np.int64))
            free[np.flatnonzero(seen)[floor]] = False
    if not taken:
        return empty, empty
    return np.concatenate(taken), np.concatenate(owner)


def own_floors(points: NDArray[np.float64], normals: NDArray[np.float64],
               comp: NDArray[np.int64], valid: NDArray[np.bool_], plane: PlaneModel,
               stand: float, noise: NoiseEstimate | None = None) -> NDArray[np.int64]:
    """Find the points of open containers that are their own floor in a support's band.

    A container whose floor never left it (the floor, a few millimetres above the
    support, was linked to its wall rather than to the support) still holds it in the
    support's band, where the contact rims' claim would take it from the container at a
    real sensor's noise (kinect-real clutter: a cup or bowl lost 20-40 % of its points,
    its whole floor). The test of :func:`contained_floors` on the container's own points:
    each segment that stands on the plane (lowest point within ``stand`` [m]) and whose
    points higher than ``stand`` (its wall, without the floor) are a wall of revolution
    (:func:`_round_footprint`); its points up to ``stand`` high that are seen through the
    wall's opening (the ray from the sensor crosses the rim's height inside the rim's
    circle, narrowed by :func:`_noise_reach`) are its floor. A solid closed on top has no
    point seen through its top's circle that low, and the support and the wall's own foot
    lie outside it.

    Parameters
    ----------
    points, normals : (M, 3) float64 arrays
        Working cloud [m] (sensor at the origin) and its unit normals.
    comp : (M,) int64 array
        Segment (object) id of every working point.
    valid : (M,) bool array
        Points of the objects.
    plane : PlaneModel
        The support's plane.
    stand : float
        Height [m] of the support's band with its voxel (as in :func:`contained_floors`).
    noise : NoiseEstimate, optional

    Returns
    -------
    (F,) int64 array
        The floors' working points.
    """
    n, d = plane.normal, plane.d
    if d < 0:  # normal towards the sensor (at the origin): its height is d
        n, d = -n, -d
    basis = np.column_stack(perpendicular_basis(n))
    height = points @ n + d
    walls = _standing_walls(points, normals, comp, valid & (height > stand), n, d, basis,
                            stand, noise, valid & (height <= stand))
    found = []
    for _, i, center, rim, opening in walls:
        low = np.flatnonzero(valid & (comp == i) & (height <= stand))
        lp = take_rows(points, low)
        found.append(low[_through_opening(lp @ basis[:, 0], lp @ basis[:, 1], height[low], d,
                                          center, rim, opening)])
    return np.concatenate(found) if found else np.zeros(0, dtype=np.int64)


def _through_opening(x: NDArray[np.float64], y: NDArray[np.float64], h: NDArray[np.float64],
                     d: float, center: NDArray[np.float64], rim: float, opening: float
                     ) -> NDArray[np.bool_]:
    """Tell which points are seen through a round opening: their ray crosses it.

    ``x``, ``y`` (P,) [m] are the points in the support plane's coordinates, ``h`` (P,)
    [m] their heights above it, ``d`` [m] the sensor's height (the sensor's foot is the
    plane's origin): the ray from a point meets the rim's height ``rim`` [m] at the point's
    own coordinates scaled by (d - rim) / (d - h), and that must lie within ``opening``
    [m] of the opening's ``center`` (2,).
    """
    scale = (d - rim) / (d - h)
    return (x * scale - center[0]) ** 2 + (y * scale - center[1]) ** 2 <= opening * opening


def _standing_walls(points: NDArray[np.float64], normals: NDArray[np.float64],
                    comp: NDArray[np.int64], valid: NDArray[np.bool_], n: NDArray[np.float64],
                    d: float, basis: NDArray[np.float64], stand: float, noise,
                    feet: NDArray[np.bool_] | None = None
                    ) -> list[tuple[int, int, NDArray[np.float64], float, float]]:
    """Return the round walls standing on the plane n . x + d = 0 (normal to the sensor).

    One entry per segment of ``comp`` (``valid`` points) of at least
    :data:`CONTAINED_MIN_POINTS` whose lowest point lies within ``stand`` [m] of the plane
    and whose footprint in ``basis`` (3, 2) is a wall of revolution
    (:func:`_round_footprint`): (points, segment id, the wall's centre (2,), the rim's
    height [m], the opening's radius [m] narrowed by :func:`_noise_reach`). With ``feet``
    (M,) a segment also stands when any of its points there does (the wall is then
    ``valid``, the foot is not).
    """
    walls = []
    standing = None if feet is None else set(np.unique(comp[feet]).tolist())
    for i, m in segment_members(comp, valid).items():
        if len(m) < CONTAINED_MIN_POINTS:
            continue
        pts = take_rows(points, m)
        height = pts @ n + d
        if height.min() > stand and (standing is None or i not in standing):
            continue
        wall = _round_footprint(pts @ basis, take_rows(normals, m) @ basis, height)
        if wall is not None:
            rim = float(np.quantile(height, RIM_HEIGHT_QUANTILE))
            opening = float(wall.radius_at(np.array([rim]))[0]) - _noise_reach(pts, n, noise)
            if 0.0 < rim < d and opening > 0.0:
                walls.append((len(m), i, wall.center, rim, opening))
    return walls


def _bounded_by(cand: NDArray[np.int64], owner: int, comp: NDArray[np.int64],
                valid: NDArray[np.bool_], in_support: NDArray[np.bool_],
                neighbors: NDArray[np.int64], sqdist: NDArray[np.float64], link: float
                ) -> NDArray[np.bool_]:
    """Tell which points ``cand`` lie in connected parts bounded mostly by segment ``owner``.

    The parts are the components of the links shorter than ``link`` [m] among ``cand``;
    each link from a part to a point outside it counts for ``owner`` when that point is
    one of its (``comp``, ``valid``), against it when the point is of a support
    (``in_support``) or of another object, and not at all when it is noise.

    Returns
    -------
    (C,) bool array
    """
    local = np.full(len(comp), -1, dtype=np.int64)
    local[cand] = np.arange(len(cand))
    nb = take_rows(neighbors, cand)
    close = take_rows(sqdist, cand) <= link * link
    inner = close & (local[nb] >= 0)
    n_parts, part = link_components(local[nb], inner)
    out = close & ~inner
    other = nb[out]
    rows = np.broadcast_to(part[:, None], nb.shape)[out]
    mine = valid[other] & (comp[other] == owner)
    against = in_support[other] | (valid[other] & ~mine)
    yes = np.bincount(rows, weights=mine, minlength=n_parts)
    no = np.bincount(rows, weights=against, minlength=n_parts)
    ok = (yes > 0) & (yes >= FLOOR_MIN_BORDER_SHARE * (yes + no))
    return ok[part]


def _noise_reach(points: NDArray[np.float64], up: NDArray[np.float64],
                 noise: NoiseEstimate | None) -> float:
    """Return the allowance [m] beyond a wall's radius for the frame's range error.

    0 without a noise, else :data:`CONTAINED_NOISE_SIGMAS` sigma of the noise along the
    ray at the median range of the wall's ``points`` (P, 3) [m] (sensor at the origin),
    times the median share of the rays that lies in the support plane (normal ``up``
    (3,)): an error along a ray moves a point's footprint by its component across the
    normal (none for a view from straight above).
    """
    if noise is None:
        return 0.0
    rng = row_norms(points)
    along = (points @ up) / np.maximum(rng, _TINY)
    across = float(np.median(np.sqrt(np.clip(1.0 - along * along, 0.0, 1.0))))
    return CONTAINED_NOISE_SIGMAS * float(noise.sigma(float(np.median(rng)))) * across


def _join_inside(sets: DisjointSets, eligible: list[int], foot: dict[int, NDArray[np.float64]],
                 height: dict[int, NDArray[np.float64]],
                 walls: list[tuple[int, tuple[_Wall, float]]]) -> None:
    """Join in ``sets`` every ``eligible`` segment that lies inside a round one.

    ``foot`` (P, 2) [m] and ``height`` (P,) [m] hold each segment's points in the support
    plane's coordinates and above it; ``walls`` the round segments' walls, each with its
    allowance [m] for the range error (:func:`_noise_reach`), in the order they are
    visited. The tests of :func:`join_contained_parts`; each segment's heights are
    summarised once (the pairs test them again and again) and a pair's height tests come
    before the footprint's pass over the points.
    """
    low = {i: height[i].min() for i in eligible}
    high = {i: height[i].max() for i in eligible}
    middle = {i: np.median(height[i]) for i in eligible}
    for a_id, (wall, reach) in walls:
        rim = np.quantile(height[a_id], RIM_HEIGHT_QUANTILE)
        for b_id in eligible:
            if sets.find(a_id) == sets.find(b_id):
                continue
            overlap = min(high[a_id], high[b_id]) - max(low[a_id], low[b_id])
            if not (overlap > 0 and middle[b_id] <= rim):
                continue
            inside = (np.linalg.norm(foot[b_id] - wall.center, axis=1)
                      <= CONTAINED_RADIUS_MARGIN * wall.radius_at(height[b_id]) + reach)
            if inside.mean() >= CONTAINED_MIN_INSIDE_SHARE:
                sets.union(a_id, b_id)


def _round_footprint(xy: NDArray[np.float64], n_xy: NDArray[np.float64],
                     height: NDArray[np.float64]) -> _Wall | None:
    """Return the wall of revolution a segment's footprint lies on, or None when none.

    Parameters
    ----------
    xy : (P, 2) float64 array [m]
        The segment's points in the support plane's coordinates.
    n_xy : (P, 2) float64 array
        Their normals in the same coordinates (not normalised).
    height : (P,) float64 array [m]
        Their heights above the support plane.

    Notes
    -----
    A straight wall (a circle, as a cylinder's) is tried first and, when it is no round
    wall, a tapered one (:func:`_fit_wall`): the footprint of a tapered wall (a flared
    cup, a pot) is a ring from its base radius to its top radius, which no single circle
    describes, while at each height it is as round as a cylinder's. The simpler wall is
    kept wherever it holds, so a footprint round as a circle keeps its circle (a can's
    side with the lid's rounded edge, whose points pull a free taper off its straight
    side). The normals must turn continuously (:func:`_turning_bins`, tested first: it
    needs no fit), each wall is judged by the other tests of a wall of revolution
    (:func:`_is_round`), and a tapered wall must also lie closer to the points than their
    plane does (:func:`_closer_than_plane`): a flat face tilted from the support normal
    is, over part of a circle, a tapered wall of large radius whose taper is the tilt.
    """
    n_xy = n_xy / np.maximum(np.linalg.norm(n_xy, axis=1), _TINY)[:, None]
    if _turning_bins(n_xy) < ROUND_MIN_TURNING_BINS:
        return None
    for tapered in (False, True):
        wall = _fit_wall(xy, height, tapered)
        if wall is not None and _is_round(wall, xy, n_xy, height) and \
                (not tapered or _closer_than_plane(wall, xy, height)):
            return wall
    return None


def _closer_than_plane(wall: _Wall, xy: NDArray[np.float64], height: NDArray[np.float64]
                       ) -> bool:
    """Whether ``wall`` lies closer to the points than the plane that fits them best.

    ``xy`` (P, 2) [m] and ``height`` (P,) [m] as in :func:`_round_footprint`; the median
    distance of the points from the wall (at their heights) against their median distance
    from their total-least-squares plane. A tilted flat face fits a tapered wall of large
    radius within the spread bound (which grows with the radius), but its plane fits it
    closer (the PCL mug scene's background at 2 m: a strip 21 cm long, 2.6 mm from its
    plane, 7.9 mm from a wall of radius 119 mm and taper -0.16); a wall seen over a real
    arc lies far from any plane (the suite's cups: 1-2.5 mm from the wall, 2-17 mm from
    the plane).
    """
    pts = np.column_stack([xy, height])
    centred = pts - pts.mean(axis=0)
    normal = np.linalg.svd(centred, full_matrices=False)[2][2]
    off_wall = np.abs(np.linalg.norm(xy - wall.center, axis=1) - wall.radius_at(height))
    return bool(np.median(off_wall) < np.median(np.abs(centred @ normal)))


def _is_round(wall: _Wall, xy: NDArray[np.float64], n_xy: NDArray[np.float64],
              height: NDArray[np.float64]) -> bool:
    """Whether a footprint lies on ``wall``: the tests of a wall of revolution that need it.

    ``xy`` (P, 2) [m], unit normals ``n_xy`` (P, 2) and ``height`` (P,) [m] as in
    :func:`_round_footprint`. A container-sized radius, the points close to the wall at
    their heights, the normals along its radii (a cone's horizontal normals are radial
    too) and a real arc; in order of their cost, the first that fails decides.
    """
    ends = wall.radius_at(np.array([wall.low, wall.high]))
    if not (ends.min() > 0.0 and ends.max() < ROUND_MAX_RADIUS):
        return False
    offsets = xy - wall.center
    dist = np.linalg.norm(offsets, axis=1)
    radial = offsets / np.maximum(dist, _TINY)[:, None]
    if not np.median(np.abs(dist - wall.radius_at(height))) < ROUND_MAX_SPREAD * wall.radius:
        return False
    if not np.median(np.abs(np.einsum("ij,ij->i", n_xy, radial))) > ROUND_MIN_RADIAL_ALIGNMENT:
        return False
    ang = np.arctan2(radial[:, 1], radial[:, 0])
    arc = np.ptp(np.unwrap(np.sort(ang))) if len(ang) > 1 else 0.0
    return bool(arc > ROUND_MIN_ARC)


def _fit_wall(xy: NDArray[np.float64], height: NDArray[np.float64], tapered: bool
              ) -> _Wall | None:
    """Fit a wall of revolution about the support normal to a footprint, or None.

    Parameters
    ----------
    xy : (P, 2) float64 array [m]
        Points in the support plane's coordinates.
    height : (P,) float64 array [m]
        Their heights above the support plane.
    tapered : bool
        Whether the radius may change linearly with height (else a straight wall).

    Notes
    -----
    The algebraic circle fit (Kasa) x^2 + y^2 + a x + b y + e = 0 and, when ``tapered``,
    its extension to a cone: the wall |xy - c| = r + k (h - h_mean) squared is
    x^2 + y^2 = 2 c.xy + (r^2 - |c|^2) + 2 r k (h - h_mean) + k^2 (h - h_mean)^2,
    linear in its five coefficients when the last is left free (least squares, as the
    circle's). The centre c, the radius r at the mean height and the taper k follow from
    the first four. None when the radius is not real.
    """
    mean_height = float(height.mean())
    columns = [xy, np.ones(len(xy))]
    if tapered:
        dh = height - mean_height
        columns += [dh, dh * dh]
    sol, *_ = np.linalg.lstsq(np.column_stack(columns), -(xy * xy).sum(axis=1), rcond=None)
    center = -0.5 * sol[:2]
    r2 = center @ center - sol[2]
    if not r2 > 0:
        return None
    radius = float(np.sqrt(r2))
    taper = float(-sol[3] / (2.0 * radius)) if tapered else 0.0
    return _Wall(center, radius, taper, mean_height, float(height.min()),
                 float(height.max()))


def _turning_bins(n_xy: NDArray[np.float64]) -> int:
    """Return the number of azimuth bins holding a fair share of the unit normals (P, 2)."""
    azimuth = np.degrees(np.arctan2(n_xy[:, 1], n_xy[:, 0]))
    hist = np.bincount(((azimuth + 180.0) // AZIMUTH_BIN_DEG).astype(int) % AZIMUTH_BINS,
                       minlength=AZIMUTH_BINS)
    return int(np.sum(hist >= AZIMUTH_BIN_MIN_SHARE * len(azimuth)))


# ------------------------------------------------------------------------------------------
# Terraces of one far surface cut by the disparity quantisation
# ------------------------------------------------------------------------------------------
#: A segment is one terrace when the 1/z of its points between these percentiles spans less
#: than :data:`TERRACE_MAX_SPREAD_STEPS` steps: its points share one disparity level but a
#: few working points at its border are voxel centroids of two levels.
TERRACE_PERCENTILES = (5.0, 95.0)
#: Half a step: a segment on two levels spans a whole step.
TERRACE_MAX_SPREAD_STEPS = 0.5
#: Neighbours on the next level differ by one step in 1/z: between half a step and one and
#: a half (the working points' voxel centroids shift the levels by less than half a step).
NEXT_LEVEL_STEPS = (0.5, 1.5)
#: Two segments border along at least this many next-level links per sqrt(working points of
#: the smaller) (its side, as :data:`JOIN_MIN_BORDER_VOTES`): terraces of one surface share
#: an edge, a terrace touching a nearer object at a corner only a few links.
TERRACE_MIN_BORDER_LINKS = 1.0
#: The joined terraces are one plane when this percentile of their points' distances from
#: their fitted plane, along the viewing ray, is within one disparity step (a plane seen
#: through the quantisation lies within half a step of every level it crosses; the rest is
#: voxel centroids and depth noise).
TERRACE_PLANE_PERCENTILE = 95.0
TERRACE_PLANE_STEPS = 1.0
#: With the frame's noise known, a point may also lie within half a step (the
#: quantisation) and this many sigmas of the depth noise that is not quantisation, at its
#: range (the frame's sigma includes the slow error that bends a far wall and the
#: quantisation's own step / sqrt(12), which is taken out).
TERRACE_NOISE_SIGMAS = 2.0


def join_terraces(points: NDArray[np.float64], comp: NDArray[np.int64],
                  valid: NDArray[np.bool_], step: float | None,
                  params: ModelingParams, noise: NoiseEstimate | None = None
                  ) -> NDArray[np.int64]:
    """Join the terraces of constant depth into which disparity steps cut a far plane.

    Parameters
    ----------
    points : (M, 3) float64 array
        Working cloud [m], sensor at the origin, optical axis along +z or -z.
    comp : (M,) int64 array
        Segment id of every working point.
    valid : (M,) bool array
        Points of the segments that take part (the others keep their ids).
    step : float or None
        The frame's disparity step in 1/z [1/m] (:func:`geomodel_ros.core.noise.
        disparity_step`); None (an unquantised frame) joins nothing.
    params : ModelingParams
        ``seg_voxel_size`` and ``seg_max_edge_factor`` (the link length) are used.
    noise : NoiseEstimate, optional
        The frame's depth noise: the union's plane test allows for it
        (:data:`TERRACE_NOISE_SIGMAS`); without it, for one step only.

    Returns
    -------
    (M,) int64 array
        ``comp`` with each joined group labelled by its largest segment's root.

    Notes
    -----
    Only where a depth step (``step * z**2``) is longer than a link does the quantisation
    part a surface the links cannot cross. A segment is a terrace there when its points
    share one level (:data:`TERRACE_MAX_SPREAD_STEPS`); a terrace and a segment it borders
    on the next level (:func:`_next_level_links`) are joined, pairs with the most links
    first, when the union of their groups is one plane within a step (:func:`_one_plane`).
    """
    if step is None or step <= 0.0 or not valid.any():
        return comp
    link = params.seg_max_edge_factor * params.seg_voxel_size
    if step * float(np.abs(points[valid, 2]).max()) ** 2 <= link:
        return comp  # every step is shorter than a link: the links cross them
    segs = _Segments(points, comp, valid)
    inv = 1.0 / np.maximum(np.abs(points[:, 2]), _TINY)
    terraces = [i for i, m in segs.members.items() if _is_terrace(inv[m], step, link)]
    if not terraces:
        return comp
    pairs, links = _next_level_links(segs, comp, inv, terraces, step, link)
    sets = DisjointSets(segs.members)
    for k in np.argsort(-links, kind="stable"):
        a, b = (int(x) for x in pairs[k])
        small = min(len(segs.members[a]), len(segs.members[b]))
        if links[k] < TERRACE_MIN_BORDER_LINKS * math.sqrt(small) or \
                sets.find(a) == sets.find(b):
            continue
        group = [i for i in segs.members if sets.find(i) in (sets.find(a), sets.find(b))]
        if _one_plane(points[np.concatenate([segs.members[i] for i in group])], step, noise):
            big, other = (a, b) if len(segs.members[a]) >= len(segs.members[b]) else (b, a)
            sets.union(big, other)
    return sets.relabel(comp, valid)


def _is_terrace(inv: NDArray[np.float64], step: float, link: float) -> bool:
    """Whether points with 1/z ``inv`` (n,) [1/m] are one level whose step exceeds a link."""
    lo, hi = np.percentile(inv, TERRACE_PERCENTILES)
    return bool(hi - lo < TERRACE_MAX_SPREAD_STEPS * step
                and step / float(np.median(inv)) ** 2 > link)


def _next_level_links(segs: _Segments, comp: NDArray[np.int64], inv: NDArray[np.float64],
                      terraces: list[int], step: float, link: float
                      ) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """Count the links from each terrace to the other segments' points on the next level.

    A link joins a terrace point and a point of another segment whose viewing rays are
    within a link length at the terrace point's range (neighbours in the image) and whose
    1/z differ by :data:`NEXT_LEVEL_STEPS`.

    Returns
    -------
    pairs : (P, 2) int64 array
        Segment pairs (lower id first) with at least one link.
    links : (P,) int64 array
        Links of each pair.
    """
    own = np.concatenate([segs.members[t] for t in terraces])
    rays = segs.points / np.maximum(segs.depth, _TINY)[:, None]
    radius = link / segs.depth[own]
    dist = segs.ray_tree().sparse_distance_matrix(
        cKDTree(rays[own]), float(radius.max()), output_type="ndarray")
    other, mine = dist["i"].astype(np.int64), own[dist["j"]]
    member = np.zeros(len(comp), dtype=bool)
    for m in segs.members.values():
        member[m] = True
    dinv = np.abs(inv[other] - inv[mine]) / step
    keep = ((dist["v"] <= radius[dist["j"]]) & member[other] & (comp[other] != comp[mine])
            & (dinv >= NEXT_LEVEL_STEPS[0]) & (dinv <= NEXT_LEVEL_STEPS[1]))
    a, b = comp[mine[keep]], comp[other[keep]]
    width = int(comp.max()) + 1
    keys, links = np.unique(np.minimum(a, b) * width + np.maximum(a, b), return_counts=True)
    return np.stack([keys // width, keys % width], axis=1), links


def _one_plane(pts: NDArray[np.float64], step: float, noise: NoiseEstimate | None = None
               ) -> bool:
    """Whether ``pts`` (n, 3) [m] lie on one plane within a disparity step along their rays.

    A point at depth z and range r is one step (``step`` in 1/z [1/m]) off along its ray at
    ``step * z * r`` [m]; the plane is the total-least-squares fit. With ``noise`` a point
    may instead lie within half a step and :data:`TERRACE_NOISE_SIGMAS` of the noise at its
    range that is not quantisation, where that is farther.
    """
    c = pts.mean(axis=0)
    _, vecs = np.linalg.eigh((pts - c).T @ (pts - c))
    n = vecs[:, 0]
    r = row_norms(pts)
    cos = np.abs(pts @ n) / np.maximum(r, _TINY)
    along = np.abs((pts - c) @ n) / np.maximum(cos, _TINY)
    one_step = step * np.abs(pts[:, 2]) * r
    bound = TERRACE_PLANE_STEPS * one_step
    if noise is not None:  # an empty estimate's sigma is 0: one step, as without it
        sigma = np.sqrt(np.maximum(np.square(noise.sigma(r)) - np.square(one_step) / 12.0,
                                   0.0))
        bound = np.maximum(bound, 0.5 * one_step + TERRACE_NOISE_SIGMAS * sigma)
    return bool(np.percentile(along / bound, TERRACE_PLANE_PERCENTILE) <= 1.0)
