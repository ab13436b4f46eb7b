"""A solid the sensor saw through: two bodies side by side, parted by their footprints.

Two boxes standing against each other at different headings, their tops at one height
within the noise, show one smooth top and fronts that meet at a crease the noise hides;
the segmentation keeps them as one segment and one upright cuboid holds both (kinect-real
clutter seeds 75, 80 and 98: boxes turned 13-45 deg to each other, one cuboid of their
joint extents). No point lies off that model, but its solid holds free space: where the
two footprints leave the rectangle round both empty, the sensor looked through the solid
at the support or at objects behind it (:func:`seen_through`: 580-1,278 returns there,
under 70 for the boxes segmented alone whose models are right).

Two convex footprints side by side are parted by a straight line, and the line parallel
to a side of one of them that parts their points best leaves two rectangles of least
joint area (:func:`footprint_split`: a box cut in two keeps its area, two boxes turned to
each other lose what the rectangle round both held empty). The two sides are then modeled
apart and must pass every test of two bodies in one segment
(:func:`~geomodel_ros.core.compounds.split_compounds`), be two boxes, and leave no free
space inside either: a single box whose model reaches too far (its hidden side completed
too long, also seen through) keeps the excess in one of its parts and stays whole.

Two such boxes also come as one cylinder round both (kinect-real clutter seed 22 seen
from 15-25 deg: boxes of 51 x 92 x 85 and 125 x 67 x 82 mm in one cylinder of 176 mm
radius); the free space inside a cylinder or a frustum is counted in the cylinder of its
smaller radius (a cup's model, open at the top, holds none beside its narrower end).
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import ConvexHull, QhullError

from geomodel_ros.core.obb import hull_candidates, min_area_rectangle
from geomodel_ros.core.primitives import Primitive, PrimitiveType

__all__ = ["Returns", "SEEN_TYPES", "seen_through", "footprint_split"]

#: The hull's edges are gathered per this step of direction [rad]: a box's side seen
#: through the noise is traced by several edges a little apart.
ANGLE_STEP = math.radians(2.0)
#: The footprint is searched on about this many of the object's points (every k-th): the
#: rectangles are set by the outline, which a thousand points trace to a few mm.
SPLIT_SAMPLE = 1000
#: The rectangles' sides and the parting lines run along the hull's longest edges
#: (summed per direction step), at most this many directions, and across them.
LINE_DIRECTIONS = 4
#: The solid is shrunk by this share of the band: its faces are set by thousands of points,
#: far better than one point's noise, but its extents by the outermost ones. Over the
#: clutter benchmark's cuboids (kinect-real seeds 0-99), 150 or more returns were seen
#: through 30 of those segmented alone at a quarter band, 11 at half (models too large or
#: of the wrong type), 2 at a whole band; through 12 of those holding two objects' points
#: at half, 7 at a whole band.
SHRINK = 0.5
#: The free space inside a solid is counted on every this-many-th return (scaled back):
#: a solid's cone is tested against the whole frame, 1-2 ms per solid at 640 x 480 on all
#: of them; an object's worth of returns (``seg_min_cluster_points``, 150) is then known
#: to about 15 %.
SEEN_STEP = 4
#: Returns farther than 1000 km are garbage rows (float32 would overflow on them).
MAX_RANGE_SQUARED = 1e12
#: The models whose solids :func:`seen_through` looks into (:func:`_inner_solid`).
SEEN_TYPES = (PrimitiveType.CUBOID, PrimitiveType.CYLINDER, PrimitiveType.FRUSTUM)
_NAMES = ("length", "width", "height")


class Returns:
    """Every ``step``-th point of a cloud as float32 (n, 3), its squared range and row.

    The sensor is at the origin of the cloud's frame; rows that are not finite lie in no
    direction (every test on them is False). Set up once per frame; the free space inside
    a box is counted on these points and scaled by ``step`` (:data:`SEEN_STEP`).
    """

    def __init__(self, pts: NDArray[np.float64], step: int = 0) -> None:
        self.step = step or SEEN_STEP
        self.rows = np.arange(0, len(pts), self.step)
        taken = pts[::self.step]
        with np.errstate(over="ignore", invalid="ignore"):
            squared = np.einsum("ij,ij->i", taken, taken)
        # Rows beyond any sensor's reach (garbage) lie in no direction, as NaN rows do.
        far = ~(squared < MAX_RANGE_SQUARED)
        self.points = np.where(far[:, None], np.nan, taken).astype(np.float32)
        self.squared = np.where(far, np.nan, squared).astype(np.float32)


def seen_through(solid: Primitive, returns: Returns, labels: NDArray[np.int64],
                 w: float) -> int:
    """Count the returns the sensor saw through the model ``solid`` (of the sampled, scaled).

    Points not labelled ``solid.id`` (``labels`` (N,) of the cloud of ``returns``) whose
    rays cross its inner solid (:func:`_inner_solid`: a cuboid, or the cylinder inscribed in
    a cylinder or frustum, shrunk by half the band ``w`` [m]: rays grazing an edge and
    mixed pixels do not count) and that lie farther than ``w`` beyond where the ray
    enters it: the space in front of them was seen free. 0 for other types (cones,
    spheres, planes), solids thinner than the band or round the sensor. The points within
    the cone round the solid's bounding sphere are found in float32, the crossing (the ray
    parametrised 0 at the sensor, 1 at the point) in float64.
    """
    inner = _inner_solid(solid, w)
    if inner is None:
        return 0
    kind, half = inner
    dist = float(np.linalg.norm(solid.center))
    reach = float(np.linalg.norm(half))
    if np.any(half <= 0.0) or dist <= reach:
        return 0
    along = returns.points @ (solid.center / dist).astype(np.float32)
    cos2 = np.float32(1.0 - (reach / dist) ** 2)
    rows = np.flatnonzero((along > 0.0) & (along * along > cos2 * returns.squared))
    rows = rows[labels[returns.rows[rows]] != solid.id]
    if not len(rows):
        return 0
    origin = -solid.center @ solid.rotation
    step = returns.points[rows].astype(np.float64) @ solid.rotation
    step[np.abs(step) < 1e-12] = 1e-12
    t1, t2 = (-half - origin) / step, (half - origin) / step
    if kind == "box":  # slabs along the three axes
        enter = np.minimum(t1, t2).max(axis=1)
        leave = np.maximum(t1, t2).min(axis=1)
    else:  # slab along the axis, round side |xy(t)| = radius
        a = np.maximum(np.einsum("ij,ij->i", step[:, :2], step[:, :2]), 1e-18)
        b = 2.0 * (step[:, :2] @ origin[:2])
        disc = b * b - 4.0 * a * (float(origin[:2] @ origin[:2]) - half[0] ** 2)
        root = np.sqrt(np.maximum(disc, 0.0))
        enter = np.maximum(np.minimum(t1[:, 2], t2[:, 2]), (-b - root) / (2.0 * a))
        leave = np.minimum(np.maximum(t1[:, 2], t2[:, 2]), (-b + root) / (2.0 * a))
        leave[disc <= 0.0] = -np.inf  # the line misses the round side
    beyond = (1.0 - enter) * np.sqrt(returns.squared[rows].astype(np.float64))
    return returns.step * int(np.count_nonzero((enter < leave) & (enter > 0.0) & (beyond > w)))


def _inner_solid(p: Primitive, w: float) -> tuple[str, NDArray[np.float64]] | None:
    """Return the solid inside model ``p`` shrunk by ``w / 2`` [m], in ``p``'s frame; or None.

    As ``("box", half extents (3,))`` for a cuboid, ``("cylinder", (radius, radius, half
    height))`` for the cylinder inscribed in a cylinder or frustum (the smaller of its
    radii: a cup's model, open at its top, holds no free space beside its narrower end).
    """
    if p.type == PrimitiveType.CUBOID:
        return "box", 0.5 * np.array([p.dimensions[k] for k in _NAMES]) - SHRINK * w
    if p.type == PrimitiveType.CYLINDER:
        radius = p.dimensions["radius"]
    elif p.type == PrimitiveType.FRUSTUM:
        radius = min(p.dimensions["radius"], p.dimensions["top_radius"])
    else:
        return None
    return "cylinder", np.array([radius, radius, 0.5 * p.dimensions["height"]]) - SHRINK * w


def footprint_split(xy: NDArray[np.float64], min_points: int, min_turn: float = 0.0
                    ) -> NDArray[np.bool_] | None:
    """Part a footprint's points ``xy`` (n, 2) [m] by the line leaving least rectangle area.

    Returns the mask (n,) of one side, None when fewer than twice ``min_points`` are given,
    no line leaves ``min_points`` on each side, or the two sides' least rectangles are
    turned less than ``min_turn`` [rad] against each other (a box cut across its own
    sides leaves two of one heading). The sides of the rectangles and the
    lines run along and across the hull's longest edges (:func:`_hull_directions`): a
    box's sides seen round the footprint are edges of its hull. Each side's area is that
    of its least rectangle over those directions, for all parting positions along a line
    at once (running extremes of the points sorted across it). The line's direction is
    chosen on about :data:`SPLIT_SAMPLE` of the points (directions tied there each tried
    again), its position on all of them. The turn is tested on the sample's sides first
    (two sides of one heading there: no placement on all the points), then on the
    placed line's.
    """
    n = len(xy)
    if n < 2 * min_points:
        return None
    sample = xy[::max(1, n // SPLIT_SAMPLE)]
    angles = _hull_directions(sample)
    if not len(angles):
        return None
    turns = np.concatenate([angles, angles + 0.5 * math.pi])  # each side and the one across
    basis = np.stack([np.cos(turns), np.sin(turns)])
    least = max(1, int(math.ceil(min_points * len(sample) / n)))
    projected = sample @ basis
    cuts = [_best_cut(projected, j, least) for j in range(len(turns))]
    areas = np.array([area for area, _ in cuts])
    if not np.isfinite(areas.min()):
        return None
    tied = np.flatnonzero(areas == areas.min())
    # Two sides of one heading on the sample: no line is placed on all the points.
    if min_turn > 0.0 and all(_turn(sample, cuts[j][1]) < min_turn for j in tied):
        return None
    # Lines of different directions may part the sample alike (a tie); each is placed
    # on all the points, where they differ.
    full = xy @ basis
    found = [_best_cut(full, int(j), min_points) for j in tied]
    side = min(found, key=lambda f: f[0])[1]
    if side is None:
        return None
    return side if min_turn <= 0.0 or _turn(xy, side) >= min_turn else None


def _turn(xy: NDArray[np.float64], side: NDArray[np.bool_]) -> float:
    """Return the turn [rad] in [0, pi / 4] between the least rectangles of two sides.

    The sides of ``xy`` (n, 2) are ``side`` (n,) and the rest; the rectangles by rotating
    calipers, their headings compared modulo a quarter turn.
    """
    heading = [math.atan2(d[1], d[0]) for d, _ in (min_area_rectangle(xy[side]),
                                                   min_area_rectangle(xy[~side]))]
    turn = abs(heading[0] - heading[1]) % (0.5 * math.pi)
    return min(turn, 0.5 * math.pi - turn)


def _best_cut(proj: NDArray[np.float64], j: int, least: int
              ) -> tuple[float, NDArray[np.bool_] | None]:
    """Best parting of points by a line along direction ``j``: joint area and one side.

    ``proj`` (m, 2k): the points' coordinates along k directions then across each; the
    line runs along column ``j``, so the points are sorted by their coordinate across it.
    Each side keeps at least ``least`` points; (inf, None) when none can.
    """
    m, k = proj.shape[0], proj.shape[1] // 2
    cuts = np.arange(least - 1, m - least)  # side one: sorted points [0, c]
    if not len(cuts):
        return math.inf, None
    order = np.argsort(proj[:, (j + k) % (2 * k)], kind="stable")
    p = proj[order]
    head = _areas(np.minimum.accumulate(p), np.maximum.accumulate(p), k)
    tail = _areas(np.minimum.accumulate(p[::-1])[::-1], np.maximum.accumulate(p[::-1])[::-1], k)
    total = head[cuts] + tail[cuts + 1]
    i = int(np.argmin(total))
    side = np.zeros(m, dtype=bool)
    side[order[:cuts[i] + 1]] = True
    return float(total[i]), side


def _areas(lo: NDArray[np.float64], hi: NDArray[np.float64], k: int) -> NDArray[np.float64]:
    """Least rectangle area (m,) of each row's extents ``lo``, ``hi`` (m, 2k).

    Column i and column i + k are the extents along a direction and across it.
    """
    width = hi - lo
    return np.min(width[:, :k] * width[:, k:], axis=1)


def _hull_directions(xy: NDArray[np.float64]) -> NDArray[np.float64]:
    """Return the directions [rad] (k,) of the longest edges of the hull of ``xy`` (m, 2).

    The edges are gathered per :data:`ANGLE_STEP` of direction (modulo a quarter turn: a
    rectangle's sides), their lengths summed; of the :data:`LINE_DIRECTIONS` longest
    gatherings each gives the direction of its longest edge.
    """
    try:
        cand = hull_candidates(xy)
        hull = cand[ConvexHull(cand).vertices]
    except (QhullError, ValueError):
        return np.zeros(0)
    edges = np.roll(hull, -1, axis=0) - hull
    length = np.hypot(edges[:, 0], edges[:, 1])
    angle = np.mod(np.arctan2(edges[:, 1], edges[:, 0]), 0.5 * math.pi)
    steps = int(round(0.5 * math.pi / ANGLE_STEP))
    step = np.minimum((angle / ANGLE_STEP).astype(np.int64), steps - 1)
    total = np.bincount(step, weights=length, minlength=steps)
    top = [i for i in np.argsort(-total, kind="stable")[:LINE_DIRECTIONS] if total[i] > 0]
    return np.array([angle[step == i][np.argmax(length[step == i])] for i in top])
