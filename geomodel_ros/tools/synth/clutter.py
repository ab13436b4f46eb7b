"""Seeded random cluttered tabletop scenes with exact per-point ground truth.

A scene is 8-16 objects on a horizontal desk: boxes, standing and lying cylinders, open
containers (cups and bowls, :class:`OpenFrustum`), spheres and cones, placed apart,
touching (pushed against an object already on the desk until their footprints meet) or
stacked (standing on a box's top face). The camera looks at the table from 0.5-1.2 m at an
elevation of 25-75 degrees and a random azimuth, aimed off the group's centre so that some
objects are cut by the image border and nearer objects hide parts of farther ones.

Geometry is exact: every object rests on the desk (lowest point at desk height) or on the
top face of the box below it, and no two objects interpenetrate. Placement works on the
objects' footprints on the desk (rectangles and circles), which contain each object's
vertical extent, so footprints that do not overlap mean solids that do not overlap; a
stacked object's footprint lies inside its base's top face. Labels come from the ray
casting of :class:`geomodel_ros.tools.synth.PinholeCamera` (desk 0, objects 1..K) and
noise from :func:`geomodel_ros.tools.synth.apply_noise`.

Adding an object kind (e.g. a frustum shape) is one entry in :data:`KIND_BUILDERS`, a
function ``rng -> Placeable``.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Callable

import numpy as np
from numpy.typing import NDArray

from .camera import PinholeCamera
from .scenes import GROUND_TRUTH_TYPES, NoiseModel, Scene, apply_noise
from .shapes import (Box, Cone, Cylinder, Rectangle, Shape, Sphere, _AxialShape,
                     _nearest_positive, _quadratic_roots, _segment_distance_2d)

__all__ = ["OpenFrustum", "Footprint", "Placeable", "ClutterScene", "KINECT_CAMERA",
           "KINECT_NOISE", "KIND_BUILDERS", "camera_pose", "footprints_overlap", "make_box",
           "make_can", "make_cone", "make_container", "make_lying_can", "make_sphere",
           "clutter_layout", "render_clutter", "render_layout", "stack_on"]

#: A Kinect-class depth camera (640 x 480, 525 px focal length: 62 x 49 degrees).
KINECT_CAMERA = PinholeCamera(fx=525.0, fy=525.0, cx=319.5, cy=239.5, width=640, height=480)
#: Kinect-class depth noise: sigma 0.5 mm at 0.5 m growing with z^2 to 2 mm at 1 m, and 2 %
#: dropped pixels.
KINECT_NOISE = NoiseModel(sigma_at_0_5m=0.0005, dropout=0.02, holes=0)

#: Objects per scene, inclusive range (the issue's 8-16 objects of a cluttered table).
OBJECT_COUNT = (8, 16)
#: Desk [m] (length, width): larger than any view of the object area from 1.2 m, so the
#: table fills the background of most views, its edge showing in some.
DESK_EXTENT = (1.4, 1.0)
#: Free-standing objects' centres are drawn in this area [m] (x, y half extents) around
#: the desk centre: 8-16 objects of 4-16 cm in 0.6 x 0.45 m make a crowded table.
AREA_HALF = (0.30, 0.225)
#: Camera distance to its aim point [m] and elevation above the desk [rad].
CAMERA_DISTANCE = (0.5, 1.2)
CAMERA_ELEVATION = (np.radians(25.0), np.radians(75.0))
#: The aim point is drawn this far [m] (x, y) from the desk centre, so the object area
#: is cut by the image border in some views.
AIM_OFFSET = (0.10, 0.07)
#: Placement modes and their probabilities: apart, against an object, on a box.
MODE_WEIGHTS = {"apart": 0.45, "touch": 0.4, "stack": 0.15}
#: Tries to place an object before it is left out (a full table refuses more objects).
PLACEMENT_TRIES = 40
#: Bisection of the contact distance ends when the bracket is this short [m]: touching
#: objects are at most 1 micrometre apart.
CONTACT_TOLERANCE = 1e-6
#: Footprints overlap only when they overlap by more than this [m] (exact contact allowed).
OVERLAP_EPS = 1e-9
#: Kinds that may stand on a box's top face (flat-bottomed, stable).
_KINDS_ON_BOXES = ("box", "can", "cup")
#: Wall thickness of cups and bowls [m] (ceramic and plastic ware: 3-5 mm) ...
CONTAINER_WALL = 0.004
#: ... and of their bottom [m] (a mug's foot and base: 6-10 mm).
CONTAINER_FLOOR = 0.008


# --------------------------------------------------------------------------- open container
@dataclass(frozen=True, eq=False)
class OpenFrustum(_AxialShape):
    """Open container about local z with a wall: a cup (r0 ~ r1) or a bowl (r1 > r0).

    Parameters
    ----------
    bottom_radius, top_radius, height : float [m]
        Outer radius at the bottom (local z = -height/2) and at the rim (+height/2), and
        the height; each in (0, inf).
    wall, floor : float [m]
        Thickness of the wall (horizontally), in (0, bottom_radius), and of the bottom, in
        (0, height).
    center : (3,) float64 array [m]
        Midpoint of the axis segment.
    rotation : (3, 3) float64 array
        Columns = local x, y, z axes; z points bottom -> rim.

    Notes
    -----
    The solid is the outer frustum minus the inner one (radius ``wall`` smaller, floor
    ``floor`` above the bottom); a ray from outside enters it at its nearest boundary hit:
    outer wall, inner wall, rim annulus, bottom or inner floor. :meth:`signed_distance`
    is that of the outer frustum (negative inside the container's volume), so no other
    object may enter it.
    """

    bottom_radius: float
    top_radius: float
    height: float
    wall: float = CONTAINER_WALL
    floor: float = CONTAINER_FLOOR

    _LENGTHS = ("bottom_radius", "top_radius", "height", "wall", "floor")

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.wall >= self.bottom_radius or self.floor >= self.height:
            raise ValueError("wall must be in (0, bottom_radius) and floor in (0, height), got "
                             f"wall={self.wall}, floor={self.floor}")

    @property
    def bounding_radius(self) -> float:
        hh = 0.5 * self.height
        return float(max(np.hypot(self.bottom_radius, hh), np.hypot(self.top_radius, hh)))

    def _slope(self) -> tuple[float, float]:
        """Outer radius at mid-height [m] and its rate along z (rho = mid + k z)."""
        return 0.5 * (self.bottom_radius + self.top_radius), \
            (self.top_radius - self.bottom_radius) / self.height

    def _intersect_local(self, o, d, eps):
        mid, k = self._slope()
        hh, t, f = 0.5 * self.height, self.wall, self.floor
        outer = _cone_roots(o, d, mid, k)
        inner = _cone_roots(o, d, mid - t, k)
        with np.errstate(divide="ignore", invalid="ignore"):
            planes = np.stack([(z - o[:, 2]) / d[:, 2] for z in (hh, -hh, -hh + f)], axis=1)
        cand = np.concatenate([outer, inner, planes], axis=1)
        p = o[:, None, :] + cand[:, :, None] * d[:, None, :]
        rho, z = np.hypot(p[..., 0], p[..., 1]), p[..., 2]
        r_out = mid + k * z
        valid = np.stack([
            np.abs(z[:, 0]) <= hh, np.abs(z[:, 1]) <= hh,
            (z[:, 2] >= -hh + f) & (z[:, 2] <= hh), (z[:, 3] >= -hh + f) & (z[:, 3] <= hh),
            (rho[:, 4] <= r_out[:, 4]) & (rho[:, 4] >= r_out[:, 4] - t),
            rho[:, 5] <= self.bottom_radius,
            rho[:, 6] <= r_out[:, 6] - t], axis=1)
        return _nearest_positive(cand, valid, eps)

    def _sdf_local(self, p):
        hh = 0.5 * self.height
        rho, z = np.hypot(p[:, 0], p[:, 1]), p[:, 2]
        return _frustum_sdf(rho, z, self.bottom_radius, self.top_radius, -hh, hh)

    def surface_distance(self, points) -> np.ndarray:
        """Distance [m] of points (M, 3) [m] to the container's surface, (M,).

        The surface is the outer one (wall, bottom, rim) and the cavity's (inner wall and
        floor).
        """
        p = self.to_local(np.atleast_2d(points))
        mid, k = self._slope()
        hh, t, f = 0.5 * self.height, self.wall, self.floor
        rho, z = np.hypot(p[:, 0], p[:, 1]), p[:, 2]
        cavity = _frustum_sdf(rho, z, mid + k * (f - hh) - t, self.top_radius - t, f - hh, hh)
        return np.minimum(np.abs(self._sdf_local(p)), np.abs(cavity))

    def _support_local(self, u):
        hh, lateral = 0.5 * self.height, float(np.hypot(u[0], u[1]))
        return max(hh * u[2] + self.top_radius * lateral,
                   -hh * u[2] + self.bottom_radius * lateral)

    def ground_truth(self, id: int):
        """Return the ground truth: a ``frustum`` where that type exists, else a cylinder.

        Until the frustum type is known to the ground truth, the container is described
        by its enclosing cylinder (radius of the wider end).
        """
        if "frustum" in GROUND_TRUTH_TYPES:
            dims = {"radius": self.bottom_radius, "top_radius": self.top_radius,
                    "height": self.height}
            return self._gt(id, "frustum", dims)
        return self._gt(id, "cylinder", {"radius": max(self.bottom_radius, self.top_radius),
                                         "height": self.height})


def _frustum_sdf(rho, z, r_bottom: float, r_top: float, z_bottom: float, z_top: float):
    """Signed distance [m] of points (radius rho, height z; (M,) each) to a solid frustum."""
    d_wall = _segment_distance_2d(rho, z, r_bottom, z_bottom, r_top, z_top)
    d_base = _segment_distance_2d(rho, z, 0.0, z_bottom, r_bottom, z_bottom)
    d_top = _segment_distance_2d(rho, z, 0.0, z_top, r_top, z_top)
    dist = np.minimum(np.minimum(d_wall, d_base), d_top)
    radius = r_bottom + (r_top - r_bottom) * (z - z_bottom) / (z_top - z_bottom)
    inside = (z >= z_bottom) & (z <= z_top) & (rho <= radius)
    return np.where(inside, -dist, dist)


def _cone_roots(o, d, mid, k):
    """Ray parameters (M, 2) of the hits with the surface rho = mid + k z (local frame)."""
    w = mid + k * o[:, 2]
    a = d[:, 0] ** 2 + d[:, 1] ** 2 - k * k * d[:, 2] ** 2
    b = o[:, 0] * d[:, 0] + o[:, 1] * d[:, 1] - k * w * d[:, 2]
    c = o[:, 0] ** 2 + o[:, 1] ** 2 - w * w
    return np.stack(_quadratic_roots(a, b, c), axis=1)


# --------------------------------------------------------------------------- footprints
@dataclass(frozen=True)
class Footprint:
    """Region an object covers on the desk: a rectangle or (``half`` None) a circle.

    Attributes
    ----------
    center : (2,) float64 array [m]
        Centre in desk coordinates.
    half : (2,) float64 array [m] or None
        Rectangle half extents along its own axes.
    angle : float [rad]
        Rectangle's first axis from the desk's x axis.
    radius : float [m]
        Circle radius (rectangles: the circumradius).
    """

    center: NDArray[np.float64]
    half: NDArray[np.float64] | None
    angle: float
    radius: float

    def moved(self, center: NDArray[np.float64]) -> "Footprint":
        """Return the same footprint centred at ``center`` (2,) [m]."""
        return replace(self, center=np.asarray(center, dtype=np.float64))

    def axes(self) -> NDArray[np.float64]:
        """Return the rectangle's two unit axes as rows (2, 2)."""
        c, s = np.cos(self.angle), np.sin(self.angle)
        return np.array([[c, s], [-s, c]])

    def corners(self) -> NDArray[np.float64]:
        """Return the rectangle's four corners (4, 2) [m]."""
        signs = np.array([[1, 1], [1, -1], [-1, -1], [-1, 1]], dtype=np.float64)
        return self.center + (signs * self.half) @ self.axes()


def _rect_circle_distance(rect: Footprint, center: NDArray[np.float64]) -> float:
    """Signed distance [m] of a point (2,) from a rectangle footprint (negative inside)."""
    q = np.abs(rect.axes() @ (center - rect.center)) - rect.half
    return float(np.linalg.norm(np.maximum(q, 0.0)) + min(q.max(), 0.0))


def _rects_overlap(a: Footprint, b: Footprint) -> bool:
    """Separating-axis test of two rectangles (overlap deeper than :data:`OVERLAP_EPS`)."""
    ca, cb = a.corners(), b.corners()
    for axis in np.vstack([a.axes(), b.axes()]):
        pa, pb = ca @ axis, cb @ axis
        if pa.max() <= pb.min() + OVERLAP_EPS or pb.max() <= pa.min() + OVERLAP_EPS:
            return False
    return True


def footprints_overlap(a: Footprint, b: Footprint) -> bool:
    """Whether two footprints overlap (touching footprints do not)."""
    if a.half is None and b.half is None:
        return bool(np.linalg.norm(a.center - b.center) < a.radius + b.radius - OVERLAP_EPS)
    if a.half is None:
        a, b = b, a
    if b.half is None:
        return _rect_circle_distance(a, b.center) < b.radius - OVERLAP_EPS
    return _rects_overlap(a, b)


def _contains(outer: Footprint, inner: Footprint) -> bool:
    """Whether the footprint ``inner`` lies inside the rectangle ``outer``."""
    pts = inner.corners() if inner.half is not None else inner.center[None, :]
    margin = 0.0 if inner.half is not None else inner.radius
    return all(_rect_circle_distance(outer, p) <= -margin for p in pts)


# --------------------------------------------------------------------------- objects
@dataclass(frozen=True)
class Placeable:
    """An object before placement: its shape at the desk origin and its footprint.

    Attributes
    ----------
    kind : str
        Object kind (a key of :data:`KIND_BUILDERS`).
    shape : Shape
        Posed in desk coordinates (desk plane z = 0, normal +z) with its footprint centred
        at the origin and its lowest point at z = 0.
    footprint : Footprint
        Centred at the origin.
    """

    kind: str
    shape: Shape
    footprint: Footprint

    def at(self, xy: NDArray[np.float64], z: float = 0.0) -> "Placeable":
        """Return the object moved to desk position ``xy`` (2,) [m], lifted by ``z`` [m]."""
        shift = np.array([xy[0], xy[1], z])
        return Placeable(self.kind, replace(self.shape, center=self.shape.center + shift),
                         self.footprint.moved(self.footprint.center + np.asarray(xy)))


def _yaw_rotation(yaw: float) -> NDArray[np.float64]:
    c, s = np.cos(yaw), np.sin(yaw)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _upright(kind: str, shape: Shape, radius: float) -> Placeable:
    """Upright round object of footprint ``radius`` [m] (shape already at the origin)."""
    return Placeable(kind, shape, Footprint(np.zeros(2), None, 0.0, radius))


def make_box(length: float, width: float, height: float, yaw: float = 0.0) -> Placeable:
    """Box standing on the desk origin, its length turned ``yaw`` [rad] from the desk's x."""
    shape = Box(length, width, height, center=[0.0, 0.0, 0.5 * height],
                rotation=_yaw_rotation(yaw))
    half = np.array([0.5 * length, 0.5 * width])
    return Placeable("box", shape, Footprint(np.zeros(2), half, yaw, float(np.hypot(*half))))


def make_can(radius: float, height: float) -> Placeable:
    """Upright cylinder (a can, a tin) standing on the desk origin."""
    return _upright("can", Cylinder(radius, height, center=[0.0, 0.0, 0.5 * height]), radius)


def make_lying_can(radius: float, length: float, yaw: float = 0.0) -> Placeable:
    """Cylinder lying on the desk origin, its axis turned ``yaw`` [rad] from the desk's x."""
    axis = np.array([np.cos(yaw), np.sin(yaw), 0.0])
    up = np.array([0.0, 0.0, 1.0])
    rotation = np.stack([up, np.cross(axis, up), axis], axis=1)
    shape = Cylinder(radius, length, center=[0.0, 0.0, radius], rotation=rotation)
    half = np.array([0.5 * length, radius])
    return Placeable("lying_can", shape,
                     Footprint(np.zeros(2), half, yaw, float(np.hypot(*half))))


def make_container(bottom_radius: float, top_radius: float, height: float,
                   kind: str = "cup") -> Placeable:
    """Open container (:class:`OpenFrustum`) standing on the desk origin."""
    shape = OpenFrustum(bottom_radius, top_radius, height, center=[0.0, 0.0, 0.5 * height])
    return _upright(kind, shape, max(bottom_radius, top_radius))


def make_sphere(radius: float) -> Placeable:
    """Ball resting on the desk origin."""
    return _upright("sphere", Sphere(radius, center=[0.0, 0.0, radius]), radius)


def make_cone(radius: float, height: float) -> Placeable:
    """Cone standing on its base on the desk origin."""
    return _upright("cone", Cone(radius, height, center=[0.0, 0.0, 0.5 * height]), radius)


def _box(rng: np.random.Generator) -> Placeable:
    return make_box(*rng.uniform([0.04, 0.04, 0.03], [0.16, 0.12, 0.15]),
                    yaw=rng.uniform(0.0, np.pi))


def _can(rng: np.random.Generator) -> Placeable:
    return make_can(*rng.uniform([0.025, 0.06], [0.05, 0.16]))


def _lying_can(rng: np.random.Generator) -> Placeable:
    return make_lying_can(*rng.uniform([0.02, 0.08], [0.04, 0.16]),
                          yaw=rng.uniform(0.0, np.pi))


def _cup(rng: np.random.Generator) -> Placeable:
    bottom, height = rng.uniform([0.03, 0.06], [0.05, 0.12])
    return make_container(bottom, bottom * rng.uniform(1.0, 1.3), height, "cup")


def _bowl(rng: np.random.Generator) -> Placeable:
    bottom, height = rng.uniform([0.035, 0.04], [0.055, 0.07])
    return make_container(bottom, bottom * rng.uniform(1.6, 2.0), height, "bowl")


def _ball(rng: np.random.Generator) -> Placeable:
    return make_sphere(rng.uniform(0.025, 0.06))


def _cone(rng: np.random.Generator) -> Placeable:
    return make_cone(*rng.uniform([0.03, 0.05], [0.05, 0.12]))


#: Object kinds: builder of a random object at the desk origin, and the kind's weight.
KIND_BUILDERS: dict[str, tuple[Callable[[np.random.Generator], Placeable], float]] = {
    "box": (_box, 0.28),
    "can": (_can, 0.2),
    "lying_can": (_lying_can, 0.12),
    "cup": (_cup, 0.12),
    "bowl": (_bowl, 0.08),
    "sphere": (_ball, 0.1),
    "cone": (_cone, 0.1),
}


# --------------------------------------------------------------------------- placement
@dataclass
class _Table:
    """Objects placed so far: ``items[i]`` stands on ``bases[i]`` (0 desk, k object k)."""

    items: list[Placeable] = field(default_factory=list)
    bases: list[int] = field(default_factory=list)

    def free(self, fp: Footprint, base: int) -> bool:
        """Whether ``fp`` overlaps no object standing on ``base``."""
        return not any(b == base and footprints_overlap(fp, it.footprint)
                       for it, b in zip(self.items, self.bases))


def _place_apart(table: _Table, obj: Placeable, rng: np.random.Generator) -> Placeable | None:
    xy = rng.uniform(-np.array(AREA_HALF), AREA_HALF)
    fp = obj.footprint.moved(xy)
    return obj.at(xy) if table.free(fp, 0) else None


def _place_touching(table: _Table, obj: Placeable, rng: np.random.Generator
                    ) -> Placeable | None:
    """Push ``obj`` from a random desk object's centre along a random direction to contact.

    The footprints of two convex objects overlap on an interval of distances from 0 to the
    contact distance, which bisection finds to :data:`CONTACT_TOLERANCE`.
    """
    on_desk = [i for i, b in enumerate(table.bases) if b == 0]
    if not on_desk:
        return None
    other = table.items[int(rng.choice(on_desk))].footprint
    phi = rng.uniform(0.0, 2.0 * np.pi)
    direction = np.array([np.cos(phi), np.sin(phi)])
    lo, hi = 0.0, other.radius + obj.footprint.radius + CONTACT_TOLERANCE
    while hi - lo > CONTACT_TOLERANCE:
        mid = 0.5 * (lo + hi)
        if footprints_overlap(other, obj.footprint.moved(other.center + mid * direction)):
            lo = mid
        else:
            hi = mid
    xy = other.center + hi * direction
    return obj.at(xy) if table.free(obj.footprint.moved(xy), 0) else None


def _place_stacked(table: _Table, obj: Placeable, rng: np.random.Generator
                   ) -> Placeable | None:
    """Stand ``obj`` on the top face of a random box standing on the desk."""
    boxes = [i for i, (it, b) in enumerate(zip(table.items, table.bases))
             if it.kind == "box" and b == 0]
    if not boxes or obj.kind not in _KINDS_ON_BOXES:
        return None
    k = int(rng.choice(boxes))
    base = table.items[k]
    xy = base.footprint.center + rng.uniform(-1.0, 1.0, 2) * base.footprint.half \
        @ base.footprint.axes() * 0.5
    fp = obj.footprint.moved(xy)
    if not _contains(base.footprint, fp) or not table.free(fp, k + 1):
        return None
    return stack_on(obj, base, xy)


_PLACERS = {"apart": _place_apart, "touch": _place_touching, "stack": _place_stacked}


def _place_objects(rng: np.random.Generator) -> _Table:
    """Draw and place 8-16 objects (an object that finds no place is left out)."""
    table = _Table()
    kinds = list(KIND_BUILDERS)
    weights = np.array([KIND_BUILDERS[k][1] for k in kinds])
    modes = list(MODE_WEIGHTS)
    mode_p = np.array([MODE_WEIGHTS[m] for m in modes])
    for _ in range(int(rng.integers(OBJECT_COUNT[0], OBJECT_COUNT[1] + 1))):
        obj = KIND_BUILDERS[kinds[rng.choice(len(kinds), p=weights / weights.sum())]][0](rng)
        mode = modes[rng.choice(len(modes), p=mode_p)]
        # The drawn mode first; an object that finds no such place stands apart.
        for try_mode in (mode, "apart"):
            placed = _try_place(table, obj, try_mode, rng)
            if placed is not None:
                table.items.append(placed)
                table.bases.append(_base_of(table, placed) if try_mode == "stack" else 0)
                break
    return table


def _try_place(table: _Table, obj: Placeable, mode: str, rng: np.random.Generator
               ) -> Placeable | None:
    """Place ``obj`` in ``mode``, or None after :data:`PLACEMENT_TRIES` failures."""
    for _ in range(PLACEMENT_TRIES):
        placed = _PLACERS[mode](table, obj, rng)
        if placed is not None:
            return placed
    return None


def _base_of(table: _Table, placed: Placeable) -> int:
    """Id (1..) of the box whose top face ``placed`` stands on."""
    lowest = -placed.shape.support(np.array([0.0, 0.0, -1.0]))
    for i, (it, b) in enumerate(zip(table.items, table.bases)):
        if b == 0 and it.kind == "box" and _contains(it.footprint, placed.footprint) \
                and abs(it.shape.support(np.array([0.0, 0.0, 1.0])) - lowest) < OVERLAP_EPS:
            return i + 1
    raise AssertionError("a stacked object stands on a box")  # pragma: no cover


# --------------------------------------------------------------------------- camera
def camera_pose(distance: float, elevation: float, azimuth: float,
                aim: tuple[float, float] = (0.0, 0.0)
                ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Pose of a camera looking at the desk point ``aim`` (x, y) [m].

    Parameters
    ----------
    distance : float
        Distance [m] from the camera to the aim point.
    elevation, azimuth : float
        Direction [rad] from the aim point to the camera: angle above the desk, and angle
        about the desk normal from the desk's x axis.
    aim : (2,) floats
        Desk point the camera looks at.

    Returns
    -------
    rotation : (3, 3) float64 array
        Desk frame -> optical frame (REP 103: z along the view, x right, y down).
    position : (3,) float64 array
        Camera position [m] in the desk frame.
    """
    target = np.array([aim[0], aim[1], 0.0])
    position = target + distance * np.array([np.cos(elevation) * np.cos(azimuth),
                                             np.cos(elevation) * np.sin(azimuth),
                                             np.sin(elevation)])
    forward = (target - position) / distance
    right = np.cross(forward, [0.0, 0.0, 1.0])
    right /= np.linalg.norm(right)
    down = np.cross(forward, right)
    return np.stack([right, down, forward]), position


def _camera_pose(rng: np.random.Generator,
                 elevation_range: tuple[float, float] = CAMERA_ELEVATION
                 ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    distance = rng.uniform(*CAMERA_DISTANCE)
    elevation = rng.uniform(*elevation_range)
    azimuth = rng.uniform(0.0, 2.0 * np.pi)
    aim = rng.uniform(-np.array(AIM_OFFSET), AIM_OFFSET)
    return camera_pose(distance, elevation, azimuth, (aim[0], aim[1]))


def _to_camera(shape: Shape, rotation: NDArray[np.float64], position: NDArray[np.float64]
               ) -> Shape:
    return replace(shape, center=rotation @ (shape.center - position),
                   rotation=rotation @ shape.rotation)


# --------------------------------------------------------------------------- scenes
@dataclass
class ClutterScene(Scene):
    """A rendered clutter scene (see :class:`geomodel_ros.tools.synth.Scene`).

    Attributes
    ----------
    shapes : list of Shape
        Desk (id 0) and objects (id k at index k), posed in the optical frame.
    kinds : list of str
        Kind of each shape (``"desk"`` first).
    bases : list of int
        What each object stands on: 0 the desk, k > 0 object k (the desk's entry is -1).
    desk_normal : (3,) float64 array
        Unit desk normal (up) in the optical frame.
    """

    shapes: list = field(default_factory=list)
    kinds: list = field(default_factory=list)
    bases: list = field(default_factory=list)
    desk_normal: NDArray[np.float64] = field(default_factory=lambda: np.zeros(3))


def stack_on(obj: Placeable, base: Placeable, xy: tuple[float, float] | None = None
             ) -> Placeable:
    """Return ``obj`` standing on the top of the box ``base`` at ``xy`` (default its centre)."""
    at = base.footprint.center if xy is None else np.asarray(xy, dtype=np.float64)
    return obj.at(at, base.shape.support(np.array([0.0, 0.0, 1.0])))


def render_layout(items: list[Placeable], bases: list[int], pose, *,
                  noise: NoiseModel | None = None, rng=None,
                  camera: PinholeCamera = KINECT_CAMERA, name: str = "layout") -> ClutterScene:
    """Render placed objects on the desk seen from ``pose`` (see :func:`camera_pose`).

    Parameters
    ----------
    items : list of Placeable
        Objects placed in desk coordinates (:meth:`Placeable.at`, :func:`stack_on`); the
        caller makes sure they rest on the desk or on each other without overlapping.
    bases : list of int
        What each item stands on: 0 the desk, k the k-th item (1-based).
    pose : (rotation (3, 3), position (3,))
        Camera pose from :func:`camera_pose`.
    noise : NoiseModel, optional
        Sensor degradations; None gives the exact cloud.
    rng : None, int or Generator
        Randomness of the noise.
    camera : PinholeCamera
        Intrinsics (identity pose).
    name : str
        Scene name.

    Returns
    -------
    ClutterScene
        Labels: desk 0, item k at id k, -1 no return.
    """
    rotation, position = pose
    shapes = [_to_camera(s, rotation, position)
              for s in [Rectangle(*DESK_EXTENT)] + [i.shape for i in items]]
    organized, labels = camera.render(shapes)
    if noise is not None:
        organized, labels = apply_noise(organized, labels, noise, rng)
    objects = [s.ground_truth(i) for i, s in enumerate(shapes)]
    return ClutterScene(name, organized, labels, objects, camera.intrinsics, shapes,
                        ["desk"] + [i.kind for i in items], [-1] + list(bases),
                        rotation[:, 2].copy())


def clutter_layout(seed: int, elevation: tuple[float, float] = CAMERA_ELEVATION
                   ) -> tuple[list[Placeable], list[int], tuple]:
    """Objects, their bases and the camera pose of clutter scene ``seed`` (not rendered).

    ``elevation``: the range [rad] the camera's elevation above the desk is drawn from
    (default :data:`CAMERA_ELEVATION`); the objects, and the camera's distance, azimuth
    and aim, are the same for any range (one draw each, in the same order).

    Returns
    -------
    items : list of Placeable
        8-16 objects placed in desk coordinates (desk plane z = 0, normal +z).
    bases : list of int
        What each stands on: 0 the desk, k the k-th item (1-based).
    pose : (rotation (3, 3), position (3,))
        Camera pose (:func:`camera_pose`).
    """
    rng = np.random.default_rng(seed)
    table = _place_objects(rng)
    return table.items, table.bases, _camera_pose(rng, elevation)


def render_clutter(seed: int, noise: NoiseModel | None = None,
                   camera: PinholeCamera = KINECT_CAMERA,
                   elevation: tuple[float, float] = CAMERA_ELEVATION) -> ClutterScene:
    """Render clutter scene ``seed`` (the same seed gives the same scene and noise).

    Parameters
    ----------
    seed : int
        Seed of the scene's layout, camera and noise.
    noise : NoiseModel, optional
        Sensor degradations (e.g. :data:`KINECT_NOISE`); None gives the exact cloud.
    camera : PinholeCamera
        Intrinsics (its pose must be the identity; the scene is posed in front of it).
    elevation : (float, float)
        Range [rad] of the camera's elevation above the desk (:func:`clutter_layout`).

    Returns
    -------
    ClutterScene
        Labels: desk 0, objects 1..K, -1 no return.
    """
    items, bases, pose = clutter_layout(seed, elevation)
    return render_layout(items, bases, pose, noise=noise,
                         rng=np.random.default_rng([seed, 1]), camera=camera,
                         name=f"clutter{seed}")
