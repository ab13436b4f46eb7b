"""The pinhole camera model of the tools: ray casting of analytic shapes and projection.

One class, :class:`PinholeCamera`, serves both the synthetic depth camera (it ray-casts
analytic shapes, :meth:`PinholeCamera.render`) and the picture renderer
(:mod:`geomodel_ros.tools.render`, which splats points through :meth:`PinholeCamera.project`).

Frames follow REP 103's optical convention (x right, y down, z forward).  Pixel
``(row v, column u)`` looks along the unit direction of ``((u - cx) / fx, (v - cy) / fy,
1)`` in the camera frame, pixel centres at integer coordinates.  A camera's pose maps a
scene point ``p`` [m] to ``rotation @ p + translation`` in its optical frame; the default
(identity) pose is the sensor's own view.  Ray casting intersects every ray with every
shape analytically and keeps the nearest positive hit, which gives exact occlusion and
self-occlusion.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Sequence

import numpy as np
from numpy.typing import NDArray

from .shapes import DEFAULT_EPS, Shape

__all__ = ["PinholeCamera", "DEFAULT_CHUNK_SIZE"]

#: Rays processed at once by :meth:`PinholeCamera.render` (bounds the memory).
DEFAULT_CHUNK_SIZE = 1 << 15


def _frozen(a: NDArray[np.float64]) -> NDArray[np.float64]:
    a.setflags(write=False)
    return a


@dataclass(frozen=True, eq=False)
class PinholeCamera:
    """Ideal pinhole camera with a pose.

    Parameters
    ----------
    fx, fy : float
        Focal lengths [px], in (0, inf).
    cx, cy : float
        Principal point [px] (column, row), finite.
    width, height : int
        Image size [px], in [1, inf).
    rotation : (3, 3) float64 array, optional
        Rotation from the scene frame to the camera's optical frame (default identity).
    translation : (3,) float64 array [m], optional
        ``p_camera = rotation @ p + translation`` (default zero).

    Cameras are equal when their intrinsics and poses are equal.
    """

    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int
    rotation: NDArray[np.float64] = field(default_factory=lambda: np.eye(3), repr=False)
    translation: NDArray[np.float64] = field(default_factory=lambda: np.zeros(3), repr=False)

    def __post_init__(self) -> None:
        for name in ("fx", "fy"):
            v = float(getattr(self, name))
            if not np.isfinite(v) or v <= 0.0:
                raise ValueError(f"{name} must be a finite focal length in (0, inf) [px], "
                                 f"got {v!r}")
            object.__setattr__(self, name, v)
        for name in ("cx", "cy"):
            v = float(getattr(self, name))
            if not np.isfinite(v):
                raise ValueError(f"{name} must be a finite principal-point coordinate [px], "
                                 f"got {v!r}")
            object.__setattr__(self, name, v)
        for name in ("width", "height"):
            v = getattr(self, name)
            if isinstance(v, bool) or int(v) != v or int(v) < 1:
                raise ValueError(f"{name} must be an integer in [1, inf) [px], got {v!r}")
            object.__setattr__(self, name, int(v))
        r = np.array(self.rotation, dtype=np.float64)
        t = np.array(self.translation, dtype=np.float64)
        if r.shape != (3, 3) or not np.isfinite(r).all():
            raise ValueError(f"rotation must be a finite (3, 3) array, got shape {r.shape}")
        if t.shape != (3,) or not np.isfinite(t).all():
            raise ValueError(f"translation must be a finite (3,) array, got shape {t.shape}")
        object.__setattr__(self, "rotation", _frozen(r))
        object.__setattr__(self, "translation", _frozen(t))

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, PinholeCamera):
            return NotImplemented
        return (self.intrinsics == other.intrinsics
                and np.array_equal(self.rotation, other.rotation)
                and np.array_equal(self.translation, other.translation))

    def __hash__(self) -> int:
        return hash((tuple(self.intrinsics.values()), self.rotation.tobytes(),
                     self.translation.tobytes()))

    # ------------------------------------------------------------------ helpers
    @property
    def intrinsics(self) -> dict:
        """``{"fx", "fy", "cx", "cy", "width", "height"}`` as plain Python numbers."""
        return {
            "fx": self.fx,
            "fy": self.fy,
            "cx": self.cx,
            "cy": self.cy,
            "width": self.width,
            "height": self.height,
        }

    @property
    def num_pixels(self) -> int:
        """``width * height``."""
        return self.width * self.height

    def scaled(self, factor: float) -> "PinholeCamera":
        """Return the same view at ``factor`` times the resolution (factor in (0, inf)).

        Pixel centres map as ``u' + 0.5 = factor * (u + 0.5)``; the pose is kept.
        """
        f = float(factor)
        if not np.isfinite(f) or f <= 0.0:
            raise ValueError(f"factor must be in (0, inf), got {factor!r}")
        return dataclasses.replace(
            self,
            fx=self.fx * f,
            fy=self.fy * f,
            cx=(self.cx + 0.5) * f - 0.5,
            cy=(self.cy + 0.5) * f - 0.5,
            width=max(1, int(round(self.width * f))),
            height=max(1, int(round(self.height * f))),
        )

    def pixel_directions(self, start: int = 0, stop: int | None = None) -> np.ndarray:
        """Return the unit ray directions of the pixels ``start:stop`` in row-major order.

        Parameters
        ----------
        start, stop : int
            Flat pixel index range (``v * width + u``); default all pixels.

        Returns
        -------
        directions : (stop - start, 3) float64 array
            Unit vectors in the optical frame.
        """
        stop = self.num_pixels if stop is None else stop
        idx = np.arange(start, stop)
        v, u = np.divmod(idx, self.width)
        d = np.empty((idx.size, 3))
        d[:, 0] = (u - self.cx) / self.fx
        d[:, 1] = (v - self.cy) / self.fy
        d[:, 2] = 1.0
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        return d

    def ray_directions(self) -> np.ndarray:
        """All (H*W, 3) float64 unit pixel ray directions, row-major."""
        return self.pixel_directions()

    @property
    def has_identity_pose(self) -> bool:
        """True when the camera sits at the scene origin looking along the scene's z."""
        return bool(np.array_equal(self.rotation, np.eye(3))
                    and not self.translation.any())

    def to_camera_frame(self, points) -> np.ndarray:
        """Scene points (N, 3) [m] -> the same points in the optical frame (N, 3) [m]."""
        p = np.atleast_2d(np.asarray(points, dtype=np.float64))
        # a contiguous right operand is much faster in numpy
        return p @ np.ascontiguousarray(self.rotation.T) + self.translation

    def project_camera_frame(self, points) -> np.ndarray:
        """Project optical-frame points (N, 3) [m] to pixel coordinates (N, 2) ``(u, v)`` [px].

        Points with ``z <= 0`` give NaN coordinates.
        """
        p = np.atleast_2d(np.asarray(points, dtype=np.float64))
        with np.errstate(divide="ignore", invalid="ignore"):
            u = self.fx * p[:, 0] / p[:, 2] + self.cx
            v = self.fy * p[:, 1] / p[:, 2] + self.cy
        bad = ~(p[:, 2] > 0.0)
        u[bad] = np.nan
        v[bad] = np.nan
        return np.stack([u, v], axis=1)

    def project(self, points) -> np.ndarray:
        """Project scene points (N, 3) [m] to pixel coordinates (N, 2) ``(u, v)`` [px].

        Points behind the camera (optical ``z <= 0``) give NaN coordinates.
        """
        return self.project_camera_frame(self.to_camera_frame(points))

    # ------------------------------------------------------------------ rendering
    def render(
        self,
        shapes: Sequence[Shape],
        ids: Sequence[int] | None = None,
        *,
        chunk_size: int = DEFAULT_CHUNK_SIZE,
        eps: float = DEFAULT_EPS,
    ) -> tuple[np.ndarray, np.ndarray]:
        """Ray-cast the shapes; nearest positive hit per pixel.

        Parameters
        ----------
        shapes : sequence of Shape
            Shapes posed in the optical frame (the camera must have the identity pose).
        ids : sequence of int, optional
            Label of each shape (default ``0 .. len(shapes) - 1``); must be >= 0.
        chunk_size : int, optional
            Rays processed at once, in [1, inf); memory is O(chunk_size).
        eps : float, optional
            Minimum accepted ray parameter [m].

        Returns
        -------
        organized : (H, W, 3) float64 array [m]
            Hit points, NaN where no shape is hit.
        labels : (H, W) int32 array
            Id of the shape seen in each pixel, -1 where nothing is hit.
        """
        if not self.has_identity_pose:
            raise ValueError("ray casting needs the camera at the origin of the shapes' frame "
                             "(identity pose)")
        shapes = list(shapes)
        ids = list(range(len(shapes))) if ids is None else [int(i) for i in ids]
        if len(ids) != len(shapes):
            raise ValueError(f"ids must have one entry per shape ({len(shapes)}), got {len(ids)}")
        if any(i < 0 for i in ids):
            raise ValueError("ids must be integers in [0, inf) (-1 is reserved for 'no hit')")
        if int(chunk_size) < 1:
            raise ValueError(f"chunk_size must be an integer in [1, inf), got {chunk_size!r}")
        chunk_size = int(chunk_size)

        n = self.num_pixels
        points = np.full((n, 3), np.nan)
        labels = np.full(n, -1, dtype=np.int32)
        for start in range(0, n, chunk_size):
            stop = min(start + chunk_size, n)
            d = self.pixel_directions(start, stop)
            t_best, lab = _nearest_hits(d, shapes, ids, eps)
            seen = np.isfinite(t_best)
            points[start:stop][seen] = d[seen] * t_best[seen, None]
            labels[start:stop] = lab
        return points.reshape(self.height, self.width, 3), labels.reshape(self.height, self.width)


def _nearest_hits(d: NDArray[np.float64], shapes: Sequence[Shape], ids: Sequence[int],
                  eps: float) -> tuple[NDArray[np.float64], NDArray[np.int32]]:
    """Nearest hit of unit rays ``d`` (m, 3) from the origin among ``shapes``.

    Returns the ray parameter (m,) [m] (``inf`` for a miss) and the id (m,) int32 of the
    shape hit (-1 for a miss). Only rays that reach a shape's bounding sphere are
    intersected with it.
    """
    centers = np.array([s.center for s in shapes]).reshape(-1, 3)
    radii = np.array([s.bounding_radius for s in shapes])
    # Camera at the origin: a ray d reaches the bounding sphere (c, rho) iff
    # |c|^2 - (c.d)^2 <= rho^2 and c.d + rho > 0.  Small relative margin.
    c2 = np.einsum("ij,ij->i", centers, centers)
    rho2 = (radii * (1.0 + 1e-9) + 1e-12) ** 2
    origin = np.zeros(3)
    t_best = np.full(len(d), np.inf)
    lab = np.full(len(d), -1, dtype=np.int32)
    cd = d @ centers.T  # (m, K)
    for k, shape in enumerate(shapes):
        reach = (c2[k] - cd[:, k] ** 2 <= rho2[k]) & (cd[:, k] + radii[k] > 0.0)
        cand = np.flatnonzero(reach)
        if cand.size == 0:
            continue
        t = shape.intersect(origin, d[cand], eps=eps)
        closer = t < t_best[cand]
        hit = cand[closer]
        t_best[hit] = t[closer]
        lab[hit] = ids[k]
    return t_best, lab
