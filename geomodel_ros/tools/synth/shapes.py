"""Analytic solid shapes with vectorised ray intersection.

Every shape is a frozen dataclass posed by ``center`` (3,) [m] and ``rotation``
(3, 3) whose COLUMNS are the shape's local x, y, z axes expressed in the parent
(camera) frame, so that ``p_camera = center + rotation @ p_local`` and
``p_local = (p_camera - center) @ rotation`` for row-stacked points.

All shapes provide

* ``intersect(origins, directions, eps=1e-9)`` -> (M,) ray parameter of the
  nearest hit with ``t > eps`` (``inf`` for a miss), vectorised over rays;
* ``signed_distance(points)`` -> (M,) distance to the surface [m], negative
  inside solids (the thin :class:`Rectangle` has no inside, its distance is
  unsigned);
* ``support(direction)`` -> ``max_p p . direction`` over the shape [m] (the
  support function, exact and analytic);
* ``bounding_radius`` -> radius [m] of a sphere about ``center`` that encloses
  the shape;
* ``ground_truth(id)`` -> :class:`geomodel_ros.tools.synth.scenes.GroundTruthObject`.

The shapes are ROS-free and depend on numpy only.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np

__all__ = [
    "Shape",
    "Rectangle",
    "Box",
    "Cylinder",
    "Cone",
    "Frustum",
    "Sphere",
    "Torus",
    "DEFAULT_EPS",
]

#: Default minimum ray parameter [m] accepted as a hit.
DEFAULT_EPS = 1e-9

_ROTATION_TOL = 1e-6


# --------------------------------------------------------------------------- helpers
def _as_center(center) -> np.ndarray:
    c = np.array(center, dtype=np.float64).reshape(-1)
    if c.shape != (3,) or not np.all(np.isfinite(c)):
        raise ValueError(f"center must be a finite (3,) vector [m], got {center!r}")
    c.setflags(write=False)
    return c


def _as_rotation(rotation) -> np.ndarray:
    r = np.array(rotation, dtype=np.float64)
    if r.shape != (3, 3) or not np.all(np.isfinite(r)):
        raise ValueError("rotation must be a finite (3, 3) matrix whose columns are the local axes")
    if np.abs(r.T @ r - np.eye(3)).max() > _ROTATION_TOL or np.linalg.det(r) <= 0.0:
        raise ValueError(
            "rotation must be a proper rotation (orthonormal columns, det = +1, "
            f"tolerance {_ROTATION_TOL})"
        )
    # Polish to machine-precision orthonormality (changes at most ~1e-6).
    u, _, vt = np.linalg.svd(r)
    r = u @ vt
    r.setflags(write=False)
    return r


def _positive(name: str, value) -> float:
    v = float(value)
    if not np.isfinite(v) or v <= 0.0:
        raise ValueError(f"{name} must be a finite length in (0, inf) [m], got {value!r}")
    return v


def _quadratic_roots(a: np.ndarray, b: np.ndarray, c: np.ndarray):
    """Real roots of ``a t^2 + 2 b t + c = 0`` (note the factor 2 on ``b``).

    Numerically stable form (no cancellation); copes with ``a == 0`` (linear
    equation, one finite root).  Missing roots are NaN or +-inf.

    Returns
    -------
    t1, t2 : (M,) float64 arrays
    """
    disc = b * b - a * c
    with np.errstate(invalid="ignore", divide="ignore"):
        sq = np.sqrt(disc)  # NaN where disc < 0
        q = -(b + np.copysign(sq, b))
        t1 = q / a
        t2 = c / q
    return t1, t2


def _nearest_positive(candidates: np.ndarray, valid: np.ndarray, eps: float) -> np.ndarray:
    """Smallest candidate per row with ``valid`` and ``t > eps``; inf if none.

    Parameters
    ----------
    candidates : (M, K) float64 array
    valid : (M, K) bool array
    eps : float
    """
    with np.errstate(invalid="ignore"):
        ok = valid & np.isfinite(candidates) & (candidates > eps)
    return np.where(ok, candidates, np.inf).min(axis=1)


def _segment_distance_2d(px, py, ax, ay, bx, by):
    """Distance from 2-D points (px, py) to the segment a-b (vectorised over points)."""
    ex, ey = bx - ax, by - ay
    s = ((px - ax) * ex + (py - ay) * ey) / (ex * ex + ey * ey)
    s = np.clip(s, 0.0, 1.0)
    return np.hypot(px - (ax + s * ex), py - (ay + s * ey))


def _unit(v) -> np.ndarray:
    v = np.asarray(v, dtype=np.float64).reshape(3)
    n = np.linalg.norm(v)
    if not np.isfinite(n) or n == 0.0:
        raise ValueError("direction must be a finite non-zero (3,) vector")
    return v / n


# --------------------------------------------------------------------------- base
@dataclass(frozen=True, eq=False)
class Shape:
    """Base class: pose handling and the frame changes shared by all shapes.

    Parameters
    ----------
    center : (3,) float64 array [m]
        Shape centre in the camera frame (see each shape for its definition).
    rotation : (3, 3) float64 array
        Columns are the shape's x, y, z axes in the camera frame.
    """

    center: np.ndarray = field(default_factory=lambda: np.zeros(3), kw_only=True)
    rotation: np.ndarray = field(default_factory=lambda: np.eye(3), kw_only=True)

    #: Names of the size fields of a shape, each a finite length in (0, inf) [m].
    _LENGTHS: ClassVar[tuple[str, ...]] = ()

    def __post_init__(self) -> None:
        object.__setattr__(self, "center", _as_center(self.center))
        object.__setattr__(self, "rotation", _as_rotation(self.rotation))
        for name in self._LENGTHS:
            object.__setattr__(self, name, _positive(name, getattr(self, name)))

    # ---- frame changes
    def to_local(self, points: np.ndarray) -> np.ndarray:
        """Camera-frame points (M, 3) [m] -> local-frame points (M, 3) [m]."""
        return (np.asarray(points, dtype=np.float64) - self.center) @ self.rotation

    def to_world(self, points: np.ndarray) -> np.ndarray:
        """Local-frame points (M, 3) [m] -> camera-frame points (M, 3) [m]."""
        return np.asarray(points, dtype=np.float64) @ self.rotation.T + self.center

    @property
    def axes(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The local x, y, z axes (each (3,)) in the camera frame."""
        return self.rotation[:, 0], self.rotation[:, 1], self.rotation[:, 2]

    # ---- public API
    def intersect(self, origins, directions, eps: float = DEFAULT_EPS) -> np.ndarray:
        """Ray parameter of the nearest hit with ``t > eps``.

        Parameters
        ----------
        origins : (M, 3) or (3,) float64 array [m]
            Ray origins (a single (3,) origin is broadcast to all rays).
        directions : (M, 3) float64 array
            Ray directions; need not be unit length (``t`` is measured in units
            of the given direction, hit point = ``origin + t * direction``).
        eps : float, optional
            Minimum accepted ray parameter.

        Returns
        -------
        t : (M,) float64 array
            Nearest hit parameter, ``inf`` where the ray misses.
        """
        d = np.atleast_2d(np.asarray(directions, dtype=np.float64))
        if d.ndim != 2 or d.shape[1] != 3:
            raise ValueError("directions must be an (M, 3) array, got shape "
                             f"{np.shape(directions)}")
        o = np.broadcast_to(np.asarray(origins, dtype=np.float64), d.shape)
        norm = np.linalg.norm(d, axis=1)
        if np.any(norm == 0.0):
            raise ValueError("directions must be non-zero")
        o_l = (o - self.center) @ self.rotation
        d_l = (d / norm[:, None]) @ self.rotation
        t = self._intersect_local(o_l, d_l, float(eps))
        return t / norm

    def signed_distance(self, points) -> np.ndarray:
        """Distance [m] of points (M, 3) [m] to the surface; negative inside."""
        return self._sdf_local(self.to_local(np.atleast_2d(points)))

    def surface_distance(self, points) -> np.ndarray:
        """Unsigned distance [m] of points (M, 3) [m] to the surface, (M,)."""
        return np.abs(self.signed_distance(points))

    def support(self, direction) -> float:
        """Support function ``max_{p in shape} p . u`` [m] for a direction (3,).

        The direction is normalised first.  ``-support(-n)`` is therefore the
        lowest extent of the shape along ``n``.
        """
        u = _unit(direction)
        return float(self.center @ u + self._support_local(self.rotation.T @ u))

    # ---- to be provided by subclasses
    @property
    def bounding_radius(self) -> float:  # pragma: no cover - abstract
        raise NotImplementedError

    def _intersect_local(self, o, d, eps):  # pragma: no cover - abstract
        raise NotImplementedError

    def _sdf_local(self, p):  # pragma: no cover - abstract
        raise NotImplementedError

    def _support_local(self, u):  # pragma: no cover - abstract
        raise NotImplementedError

    def ground_truth(self, id: int):  # pragma: no cover - abstract
        raise NotImplementedError

    def _gt(self, id, type_, dims, rotation=None):
        from .scenes import GroundTruthObject  # lazy: scenes imports this module

        return GroundTruthObject(
            id=int(id),
            type=type_,
            center=self.center.copy(),
            rotation=(self.rotation if rotation is None else rotation).copy(),
            dimensions=dims,
        )


@dataclass(frozen=True, eq=False)
class _AxialShape(Shape):
    """A shape symmetric about its local z axis (cylinder, cone, frustum, torus)."""

    @property
    def axis(self) -> np.ndarray:
        """Unit symmetry axis (3,) = local z (a cone's and frustum's points base -> apex)."""
        return self.rotation[:, 2]


# --------------------------------------------------------------------------- shapes
@dataclass(frozen=True, eq=False)
class Rectangle(Shape):
    """Thin rectangle (a desk) in the local z = 0 plane; both sides are hit.

    Parameters
    ----------
    length, width : float [m]
        Side lengths along local x and y, each in (0, inf).
    center : (3,) float64 array [m]
        Rectangle centre.
    rotation : (3, 3) float64 array
        Columns = local x, y, z axes; z is the normal.
    """

    length: float
    width: float

    _LENGTHS = ("length", "width")

    @property
    def normal(self) -> np.ndarray:
        """Unit normal (3,) = local z axis."""
        return self.rotation[:, 2]

    @property
    def bounding_radius(self) -> float:
        return 0.5 * float(np.hypot(self.length, self.width))

    def _intersect_local(self, o, d, eps):
        with np.errstate(divide="ignore", invalid="ignore"):
            t = -o[:, 2] / d[:, 2]
            x = o[:, 0] + t * d[:, 0]
            y = o[:, 1] + t * d[:, 1]
            ok = (
                np.isfinite(t)
                & (t > eps)
                & (np.abs(x) <= 0.5 * self.length)
                & (np.abs(y) <= 0.5 * self.width)
            )
        return np.where(ok, t, np.inf)

    def _sdf_local(self, p):
        qx = np.maximum(np.abs(p[:, 0]) - 0.5 * self.length, 0.0)
        qy = np.maximum(np.abs(p[:, 1]) - 0.5 * self.width, 0.0)
        return np.sqrt(qx * qx + qy * qy + p[:, 2] ** 2)

    def _support_local(self, u):
        return 0.5 * self.length * abs(u[0]) + 0.5 * self.width * abs(u[1])

    def ground_truth(self, id: int):
        """Return the ground truth, of type ``"plane"``.

        Its z (normal) faces the camera (``normal . center < 0``), flipping y and z if needed.
        """
        rot = np.array(self.rotation)
        if rot[:, 2] @ self.center > 0.0:
            rot[:, 1:] *= -1.0
        return self._gt(id, "plane", {"length": self.length, "width": self.width}, rot)


@dataclass(frozen=True, eq=False)
class Box(Shape):
    """Solid box (6 faces); ``center`` is the box centre.

    Parameters
    ----------
    length, width, height : float [m]
        Extents along local x, y, z, each in (0, inf).
    center : (3,) float64 array [m]
    rotation : (3, 3) float64 array
        Columns = local x, y, z axes in the camera frame.
    """

    length: float
    width: float
    height: float

    _LENGTHS = ("length", "width", "height")

    @property
    def half_extents(self) -> np.ndarray:
        """(3,) half extents [m] along local x, y, z."""
        return 0.5 * np.array([self.length, self.width, self.height])

    @property
    def bounding_radius(self) -> float:
        return float(np.linalg.norm(self.half_extents))

    def _intersect_local(self, o, d, eps):
        h = self.half_extents
        with np.errstate(divide="ignore", invalid="ignore"):
            inv = 1.0 / d
            t1 = (-h - o) * inv
            t2 = (h - o) * inv
        # fmin/fmax ignore the NaN of 0 * inf (ray in a face plane).
        t_near = np.fmax.reduce(np.fmin(t1, t2), axis=1)
        t_far = np.fmin.reduce(np.fmax(t1, t2), axis=1)
        hit = t_near <= t_far
        t = np.where(t_near > eps, t_near, np.where(t_far > eps, t_far, np.inf))
        return np.where(hit, t, np.inf)

    def _sdf_local(self, p):
        q = np.abs(p) - self.half_extents
        outside = np.linalg.norm(np.maximum(q, 0.0), axis=1)
        inside = np.minimum(q.max(axis=1), 0.0)
        return outside + inside

    def _support_local(self, u):
        return float(self.half_extents @ np.abs(u))

    def ground_truth(self, id: int):
        dims = {"length": self.length, "width": self.width, "height": self.height}
        return self._gt(id, "cuboid", dims)


@dataclass(frozen=True, eq=False)
class Cylinder(_AxialShape):
    """Solid capped cylinder about local z.

    Parameters
    ----------
    radius, height : float [m]
        Radius and length along local z (the axis), each in (0, inf).
    center : (3,) float64 array [m]
        Midpoint of the axis segment.
    rotation : (3, 3) float64 array
        Columns = local x, y, z axes; z is the axis.
    """

    radius: float
    height: float

    _LENGTHS = ("radius", "height")

    @property
    def bounding_radius(self) -> float:
        return float(np.hypot(self.radius, 0.5 * self.height))

    def _intersect_local(self, o, d, eps):
        r, hh = self.radius, 0.5 * self.height
        a = d[:, 0] ** 2 + d[:, 1] ** 2
        b = o[:, 0] * d[:, 0] + o[:, 1] * d[:, 1]
        c = o[:, 0] ** 2 + o[:, 1] ** 2 - r * r
        t1, t2 = _quadratic_roots(a, b, c)
        with np.errstate(divide="ignore", invalid="ignore"):
            tc1 = (-hh - o[:, 2]) / d[:, 2]
            tc2 = (hh - o[:, 2]) / d[:, 2]
            cand = np.stack([t1, t2, tc1, tc2], axis=1)
            p = o[:, None, :] + cand[:, :, None] * d[:, None, :]
            side_ok = np.abs(p[:, :2, 2]) <= hh
            cap_ok = p[:, 2:, 0] ** 2 + p[:, 2:, 1] ** 2 <= r * r
        return _nearest_positive(cand, np.concatenate([side_ok, cap_ok], axis=1), eps)

    def _sdf_local(self, p):
        d_rho = np.hypot(p[:, 0], p[:, 1]) - self.radius
        d_z = np.abs(p[:, 2]) - 0.5 * self.height
        inside = np.minimum(np.maximum(d_rho, d_z), 0.0)
        outside = np.hypot(np.maximum(d_rho, 0.0), np.maximum(d_z, 0.0))
        return inside + outside

    def _support_local(self, u):
        return 0.5 * self.height * abs(u[2]) + self.radius * float(np.hypot(u[0], u[1]))

    def ground_truth(self, id: int):
        return self._gt(id, "cylinder", {"radius": self.radius, "height": self.height})


@dataclass(frozen=True, eq=False)
class Cone(_AxialShape):
    """Solid cone with a capped base.

    Parameters
    ----------
    radius, height : float [m]
        Base radius and base-to-apex height, each in (0, inf).
    center : (3,) float64 array [m]
        Midpoint of the axis segment: base centre at local z = -height/2,
        apex at local z = +height/2.
    rotation : (3, 3) float64 array
        Columns = local x, y, z axes; z points base -> apex.
    """

    radius: float
    height: float

    _LENGTHS = ("radius", "height")

    @property
    def apex(self) -> np.ndarray:
        """Apex (3,) [m] in the camera frame."""
        return self.center + 0.5 * self.height * self.axis

    @property
    def base_center(self) -> np.ndarray:
        """Base centre (3,) [m] in the camera frame."""
        return self.center - 0.5 * self.height * self.axis

    @property
    def bounding_radius(self) -> float:
        return float(max(np.hypot(self.radius, 0.5 * self.height), 0.5 * self.height))

    def _intersect_local(self, o, d, eps):
        r, h = self.radius, self.height
        hh = 0.5 * h
        k2 = (r / h) ** 2
        w0 = hh - o[:, 2]  # distance below the apex along the axis
        a = d[:, 0] ** 2 + d[:, 1] ** 2 - k2 * d[:, 2] ** 2
        b = o[:, 0] * d[:, 0] + o[:, 1] * d[:, 1] + k2 * w0 * d[:, 2]
        c = o[:, 0] ** 2 + o[:, 1] ** 2 - k2 * w0 * w0
        t1, t2 = _quadratic_roots(a, b, c)
        with np.errstate(divide="ignore", invalid="ignore"):
            tb = (-hh - o[:, 2]) / d[:, 2]
            cand = np.stack([t1, t2, tb], axis=1)
            p = o[:, None, :] + cand[:, :, None] * d[:, None, :]
            z_side = p[:, :2, 2]
            side_ok = (z_side >= -hh) & (z_side <= hh)  # rejects the mirror nappe
            base_ok = p[:, 2:, 0] ** 2 + p[:, 2:, 1] ** 2 <= r * r
        return _nearest_positive(cand, np.concatenate([side_ok, base_ok], axis=1), eps)

    def _sdf_local(self, p):
        r, hh = self.radius, 0.5 * self.height
        rho = np.hypot(p[:, 0], p[:, 1])
        z = p[:, 2]
        d_base = _segment_distance_2d(rho, z, 0.0, -hh, r, -hh)
        d_side = _segment_distance_2d(rho, z, r, -hh, 0.0, hh)
        dist = np.minimum(d_base, d_side)
        inside = (z >= -hh) & (z <= hh) & (rho <= r * (hh - z) / self.height)
        return np.where(inside, -dist, dist)

    def _support_local(self, u):
        hh = 0.5 * self.height
        return max(hh * u[2], -hh * u[2] + self.radius * float(np.hypot(u[0], u[1])))

    def ground_truth(self, id: int):
        return self._gt(id, "cone", {"radius": self.radius, "height": self.height})


@dataclass(frozen=True, eq=False)
class Frustum(_AxialShape):
    """Truncated cone (cup, bowl, flower pot, bucket), closed or open at either end.

    Parameters
    ----------
    radius : float [m]
        Radius of the base, the larger circle, at local z = -height/2.
    top_radius : float [m]
        Radius of the smaller circle at local z = +height/2, in (0, radius).
    height : float [m]
        Distance between the two circles along local z, in (0, inf).
    base_cap, top_cap : bool
        Whether the base / top disc is closed. An open end shows the inside of the side
        (a zero-thickness wall: an upright cup or bowl is ``Frustum(..., base_cap=False)``
        turned so that z points down, its rim the base).
    center : (3,) float64 array [m]
        Midpoint of the axis segment.
    rotation : (3, 3) float64 array
        Columns = local x, y, z axes; z points base -> top (towards the apex of the cone
        the frustum is cut from).

    Notes
    -----
    With an open end the shape is a shell: ``signed_distance`` is then unsigned (as for
    :class:`Rectangle`). ``support`` and ``bounding_radius`` are those of the solid.
    """

    radius: float
    top_radius: float
    height: float
    base_cap: bool = True
    top_cap: bool = True

    _LENGTHS = ("radius", "top_radius", "height")

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.top_radius >= self.radius:
            raise ValueError("top_radius must lie in (0, radius) (the base is the larger "
                             f"circle), got top_radius={self.top_radius}, radius={self.radius}")

    @property
    def closed(self) -> bool:
        """Whether both ends are capped (a solid)."""
        return bool(self.base_cap and self.top_cap)

    @property
    def bounding_radius(self) -> float:
        return float(np.hypot(self.radius, 0.5 * self.height))

    def _intersect_local(self, o, d, eps):
        r, rt, hh = self.radius, self.top_radius, 0.5 * self.height
        k = (r - rt) / self.height  # radius lost per metre along z
        w0 = r / k - hh - o[:, 2]  # distance below the apex (z = r / k - hh) along the axis
        k2 = k * k
        a = d[:, 0] ** 2 + d[:, 1] ** 2 - k2 * d[:, 2] ** 2
        b = o[:, 0] * d[:, 0] + o[:, 1] * d[:, 1] + k2 * w0 * d[:, 2]
        c = o[:, 0] ** 2 + o[:, 1] ** 2 - k2 * w0 * w0
        t1, t2 = _quadratic_roots(a, b, c)
        with np.errstate(divide="ignore", invalid="ignore"):
            tb = (-hh - o[:, 2]) / d[:, 2]
            tt = (hh - o[:, 2]) / d[:, 2]
            cand = np.stack([t1, t2, tb, tt], axis=1)
            p = o[:, None, :] + cand[:, :, None] * d[:, None, :]
            z_side = p[:, :2, 2]
            side_ok = (z_side >= -hh) & (z_side <= hh)  # rejects the mirror nappe
            rho2 = p[:, 2:, 0] ** 2 + p[:, 2:, 1] ** 2
            base_ok = (rho2[:, :1] <= r * r) & self.base_cap
            top_ok = (rho2[:, 1:] <= rt * rt) & self.top_cap
        return _nearest_positive(cand, np.concatenate([side_ok, base_ok, top_ok], axis=1), eps)

    def _sdf_local(self, p):
        r, rt, hh = self.radius, self.top_radius, 0.5 * self.height
        rho = np.hypot(p[:, 0], p[:, 1])
        z = p[:, 2]
        dist = _segment_distance_2d(rho, z, r, -hh, rt, hh)
        if self.base_cap:
            dist = np.minimum(dist, _segment_distance_2d(rho, z, 0.0, -hh, r, -hh))
        if self.top_cap:
            dist = np.minimum(dist, _segment_distance_2d(rho, z, 0.0, hh, rt, hh))
        if not self.closed:
            return dist
        inside = (z >= -hh) & (z <= hh) & (rho <= r - (r - rt) * (z + hh) / self.height)
        return np.where(inside, -dist, dist)

    def _support_local(self, u):
        hh, across = 0.5 * self.height, float(np.hypot(u[0], u[1]))
        return max(-hh * u[2] + self.radius * across, hh * u[2] + self.top_radius * across)

    def ground_truth(self, id: int):
        dims = {"radius": self.radius, "top_radius": self.top_radius, "height": self.height}
        return self._gt(id, "frustum", dims)


@dataclass(frozen=True, eq=False)
class Sphere(Shape):
    """Solid sphere.

    Parameters
    ----------
    radius : float [m]
        In (0, inf).
    center : (3,) float64 array [m]
    rotation : (3, 3) float64 array
        Only carried into the ground truth.
    """

    radius: float

    _LENGTHS = ("radius",)

    @property
    def bounding_radius(self) -> float:
        return self.radius

    def _intersect_local(self, o, d, eps):
        a = np.einsum("ij,ij->i", d, d)
        b = np.einsum("ij,ij->i", o, d)
        c = np.einsum("ij,ij->i", o, o) - self.radius**2
        t1, t2 = _quadratic_roots(a, b, c)
        cand = np.stack([t1, t2], axis=1)
        return _nearest_positive(cand, np.ones(cand.shape, dtype=bool), eps)

    def _sdf_local(self, p):
        return np.linalg.norm(p, axis=1) - self.radius

    def _support_local(self, _u):
        return self.radius  # the same in every direction

    def ground_truth(self, id: int):
        return self._gt(id, "sphere", {"radius": self.radius})


@dataclass(frozen=True, eq=False)
class Torus(_AxialShape):
    """Solid ring torus about local z.

    Parameters
    ----------
    major_radius : float [m]
        R, radius of the tube's centre circle, in (0, inf).
    minor_radius : float [m]
        r, tube radius, in (0, major_radius).
    center : (3,) float64 array [m]
        Torus centre.
    rotation : (3, 3) float64 array
        Columns = local x, y, z axes; z is the symmetry axis.

    Notes
    -----
    Ray intersection solves the quartic ``(|p|^2 + R^2 - r^2)^2 = 4 R^2 (x^2 + y^2)``
    for the rays that hit the bounding sphere only, in batch, through the
    eigenvalues of (M, 4, 4) companion matrices, followed by a vectorised Newton
    polish and a surface-distance check of every accepted root.
    """

    major_radius: float
    minor_radius: float

    #: acceptance tolerance [m] on |signed distance| of a polished quartic root
    _ACCEPT_TOL = 1e-10

    _LENGTHS = ("major_radius", "minor_radius")

    def __post_init__(self) -> None:
        super().__post_init__()
        big, small = self.major_radius, self.minor_radius
        if small >= big:
            raise ValueError(
                "minor_radius must lie in (0, major_radius) (ring torus), got "
                f"minor_radius={small}, major_radius={big}"
            )

    @property
    def bounding_radius(self) -> float:
        return self.major_radius + self.minor_radius

    def _intersect_local(self, o, d, eps):
        big, small = self.major_radius, self.minor_radius
        rho = big + small
        out = np.full(o.shape[0], np.inf)
        # 1) bounding sphere: only those rays need the quartic.
        b = np.einsum("ij,ij->i", o, d)
        c = np.einsum("ij,ij->i", o, o) - rho * rho
        disc = b * b - c
        with np.errstate(invalid="ignore"):
            sq = np.sqrt(disc)
        sel = np.flatnonzero((disc > 0.0) & (-b + sq > eps))
        if sel.size == 0:
            return out
        t0 = np.maximum(-b[sel] - sq[sel], 0.0)
        # 2) dimensionless quartic in s, with the origin moved to the sphere entry.
        dd = d[sel]
        oo = (o[sel] + t0[:, None] * dd) / rho
        R, r = big / rho, small / rho
        bb = np.einsum("ij,ij->i", oo, dd)
        cc = np.einsum("ij,ij->i", oo, oo) + R * R - r * r
        a2 = dd[:, 0] ** 2 + dd[:, 1] ** 2
        a1 = oo[:, 0] * dd[:, 0] + oo[:, 1] * dd[:, 1]
        a0 = oo[:, 0] ** 2 + oo[:, 1] ** 2
        c3 = 4.0 * bb
        c2 = 4.0 * bb * bb + 2.0 * cc - 4.0 * R * R * a2
        c1 = 4.0 * bb * cc - 8.0 * R * R * a1
        c0 = cc * cc - 4.0 * R * R * a0
        m = sel.size
        comp = np.zeros((m, 4, 4))
        comp[:, 0, 0], comp[:, 0, 1], comp[:, 0, 2], comp[:, 0, 3] = -c3, -c2, -c1, -c0
        comp[:, 1, 0] = comp[:, 2, 1] = comp[:, 3, 2] = 1.0
        roots = np.linalg.eigvals(comp)  # (m, 4) complex
        s = roots.real.copy()
        near_real = np.abs(roots.imag) <= 1e-6
        # 3) Newton polish of every candidate on the quartic (vectorised).
        coef = np.stack([np.ones(m), c3, c2, c1, c0], axis=1)[:, :, None]  # (m, 5, 1)
        for _ in range(4):
            f = (((coef[:, 0] * s + coef[:, 1]) * s + coef[:, 2]) * s + coef[:, 3]) * s + coef[:, 4]
            df = ((4.0 * coef[:, 0] * s + 3.0 * coef[:, 1]) * s + 2.0 * coef[:, 2]) * s + coef[:, 3]
            with np.errstate(divide="ignore", invalid="ignore"):
                step = np.where(np.abs(df) > 1e-300, f / df, 0.0)
            step = np.clip(np.nan_to_num(step), -1e-3, 1e-3)
            s = s - step
        t = t0[:, None] + rho * s  # (m, 4) metres along the unit ray
        # 4) accept roots that really are on the surface.
        p = o[sel][:, None, :] + t[:, :, None] * dd[:, None, :]
        dist = np.abs(
            np.hypot(np.hypot(p[..., 0], p[..., 1]) - big, p[..., 2]) - small
        )
        valid = near_real & (dist <= self._ACCEPT_TOL)
        out[sel] = _nearest_positive(t, valid, eps)
        return out

    def _sdf_local(self, p):
        rho = np.hypot(p[:, 0], p[:, 1])
        return np.hypot(rho - self.major_radius, p[:, 2]) - self.minor_radius

    def _support_local(self, u):
        return self.major_radius * float(np.hypot(u[0], u[1])) + self.minor_radius

    def ground_truth(self, id: int):
        dims = {"major_radius": self.major_radius, "minor_radius": self.minor_radius}
        return self._gt(id, "torus", dims)
