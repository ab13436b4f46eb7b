"""Where the sensor is: the camera of an organized cloud, recovered from its pixel grid.

The modeling works in the sensor's frame: the noise grows along each point's viewing ray
from the origin, hidden ends are completed along the rays, the frame's noise is measured
against the range. Camera drivers publish clouds so (the optical frame), but a robot's
pipeline often hands on a cloud transformed into another frame (its base, the map), and
a rigid transform keeps an organized cloud's layout. Such a cloud still says where its
camera is: a depth camera's cloud is a pinhole image, every point on the ray of its
pixel, so the projective camera P (3 x 4) that maps each point to its (column, row) is
found by the direct linear transform (Hartley and Zisserman, *Multiple View Geometry*,
sec. 7.1; Hartley's normalisation) and splits into intrinsics, rotation R and centre C.
:func:`grid_sensor_pose` returns that pose when the grid is such an image and the cloud's
origin is not its camera already; :meth:`SensorPose.to_sensor` moves the points into the
camera's optical frame (x right, y down, z forward, origin at the camera), and
:meth:`SensorPose.result_to_input` moves the modeled objects and support planes back.
Depth noise along the rays does not move a point off its pixel's ray, so the fit is exact
on real frames too (up to float rounding); distortion that the driver did not remove, a
re-sorted cloud or a scanner's rings fit no pinhole, and the cloud is then modeled as given.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Final

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.linalg import rq
from scipy.spatial.transform import Rotation

from geomodel_ros.core.primitives import ModelingResult, Primitive

__all__ = ["SensorPose", "grid_sensor_pose", "GRID_SAMPLE", "MAX_REPROJECTION_PX",
           "ORIGIN_TOLERANCE", "MIN_SECOND_SINGULAR"]

#: Pixels the camera is fitted to (every k-th pixel with a return; every k-th of the
#: returns when fewer than a quarter of those have one): the linear system has 12
#: unknowns, and a few thousand rows spread over the image pin them down to float rounding.
GRID_SAMPLE: Final = 3000
#: Largest RMS reprojection error [px] for the grid to count as a pinhole image (as the
#: pictures' camera fit, ``tools.picture.PINHOLE_FIT_TOLERANCE_PX``): a depth camera's
#: own cloud fits to ~1e-4 px, a re-sorted cloud or a scanner's rings to many pixels.
MAX_REPROJECTION_PX: Final = 0.5
#: A recovered camera within this distance [m] of the origin and this angle [rad] of the
#: optical axes is the cloud's own frame: nothing is moved (float32 clouds recover their
#: own camera to ~1e-6).
ORIGIN_TOLERANCE: Final = 1e-4
#: The camera is determined only when the second smallest singular value of the
#: normalised linear system is at least this share of the largest: points that all lie
#: on one plane (a noise-free wall seen alone) fit a family of cameras, and that value is
#: then at the float rounding (~1e-16); any relief, even a real sensor's noise along the
#: rays on a flat wall, lifts it far above (a 2 mm bump on a wall 2 m away: 6e-4; a
#: tabletop frame: 0.04-0.08). How well the best camera fits is the reprojection test's.
MIN_SECOND_SINGULAR: Final = 1e-9
#: Fewest finite pixels to fit a camera to (six points determine one; many more make
#: the fit a check).
MIN_GRID_PIXELS: Final = 100
#: Coordinates [m] beyond which a row is no measurement (a driver's garbage, 1e300): left
#: out of the fit, whose products would overflow; a map frame's points lie far within.
MAX_COORDINATE: Final = 1e9


@dataclass(frozen=True)
class SensorPose:
    """The camera of a cloud: ``p_sensor = rotation @ (p - center)`` for a point ``p``.

    Attributes
    ----------
    rotation : (3, 3) float64, from the cloud's frame to the camera's optical frame
    center : (3,) float64 [m], the camera's centre in the cloud's frame
    rms_px : float or None, RMS reprojection error of the grid's fit [px] (None: the pose
        was given, :meth:`from_transform`)
    """

    rotation: NDArray[np.float64]
    center: NDArray[np.float64]
    rms_px: float | None = None

    @classmethod
    def from_transform(cls, translation: ArrayLike, quaternion: ArrayLike) -> SensorPose:
        """Make the pose of the sensor's optical frame in the cloud's frame, as tf2 gives it.

        ``translation`` (x, y, z) [m] and ``quaternion`` (x, y, z, w) of the transform
        from the optical frame to the cloud's (``lookup_transform(cloud_frame,
        sensor_frame, ...)``: ``p_cloud = R p_sensor + t``). The quaternion is
        normalised. Raises ValueError for values that are not finite, a zero quaternion or a
        position beyond :data:`MAX_COORDINATE`.
        """
        t = np.asarray(translation, dtype=np.float64).reshape(-1)
        q = np.asarray(quaternion, dtype=np.float64).reshape(-1)
        if t.shape != (3,) or q.shape != (4,):
            raise ValueError(f"a sensor pose needs 3 translation and 4 quaternion values, "
                             f"got {t.size} and {q.size}")
        if not (np.isfinite(t).all() and np.isfinite(q).all()):
            raise ValueError("the sensor's pose is not finite")
        if np.abs(t).max() > MAX_COORDINATE:
            raise ValueError(f"the sensor's position {t.tolist()} lies beyond "
                             f"{MAX_COORDINATE:g} m: no measurement")
        scale = float(np.abs(q).max())
        if not scale > 0.0:
            raise ValueError("the sensor's rotation is a zero quaternion")
        # Scaled first: the norm of a quaternion of huge components would overflow.
        r = Rotation.from_quat(q / scale).as_matrix()  # scalar last, as ROS; normalised
        return cls(r.T, t.copy())

    def to_dict(self) -> dict:
        """JSON-ready: the camera's centre [m], optical axes (columns x, y, z), fit [px].

        Centre and axes are in the cloud's frame; the fit is null for a given pose.
        """
        return {"center": [float(v) for v in self.center],
                "rotation": [[float(v) for v in row] for row in self.rotation.T],
                "reprojection_rms_px": None if self.rms_px is None else float(self.rms_px)}

    def to_sensor(self, points: NDArray[np.float64]) -> NDArray[np.float64]:
        """Return ``points`` (N, 3) [m] in the camera's optical frame.

        Non-finite rows stay non-finite; rows so large that they overflow become so (the
        modeling's input gates leave both out).
        """
        with np.errstate(over="ignore", invalid="ignore"):
            return (points - self.center) @ self.rotation.T

    def to_input(self, points: NDArray[np.float64]) -> NDArray[np.float64]:
        """Return ``points`` (N, 3) [m] of the camera's optical frame in the cloud's frame."""
        return points @ self.rotation + self.center

    def primitive_to_input(self, prim: Primitive) -> Primitive:
        """Return ``prim`` (modeled in the camera's frame) placed in the cloud's frame."""
        return dataclasses.replace(prim, center=self.to_input(prim.center[None])[0],
                                   rotation=self.rotation.T @ prim.rotation)

    def result_to_input(self, result: ModelingResult) -> ModelingResult:
        """Return ``result`` with its objects and support planes in the cloud's frame.

        A plane ``n . x + d = 0`` of the camera's frame is ``n' . p + d' = 0`` with
        ``n' = R^T n`` and ``d' = d - n' . C``; its normal still faces the sensor.
        """
        supports = {}
        for k, (normal, d) in result.supports.items():
            n = self.rotation.T @ np.asarray(normal, dtype=np.float64)
            supports[k] = (n, float(d) - float(n @ self.center))
        return dataclasses.replace(result, objects=[self.primitive_to_input(o)
                                                    for o in result.objects],
                                   supports=supports, sensor=self)


def grid_sensor_pose(points: NDArray[np.float64], shape: tuple[int, int]
                     ) -> SensorPose | None:
    """Return the camera of an organized cloud when it is not at the cloud's origin.

    Parameters
    ----------
    points : (H * W, 3) float array [m]
        The cloud's rows, row-major over the image (non-finite rows: no return).
    shape : (H, W)

    Returns
    -------
    SensorPose or None
        None when the grid is no pinhole image (too few finite pixels, points on one
        plane, reprojection error above :data:`MAX_REPROJECTION_PX`) or when its camera
        is the cloud's own optical frame (within :data:`ORIGIN_TOLERANCE`).
    """
    h, w = shape
    pts = np.asarray(points).reshape(h * w, 3)
    # Every k-th pixel, then its returns: a frame with few returns is sampled finer.
    rows = np.arange(0, h * w, max(1, h * w // GRID_SAMPLE))
    rows = rows[_measured(pts[rows])]
    if len(rows) < GRID_SAMPLE // 4:
        rows = np.flatnonzero(_measured(pts))
        rows = rows[:: max(1, len(rows) // GRID_SAMPLE)]
    if len(rows) < MIN_GRID_PIXELS:
        return None
    x = pts[rows].astype(np.float64)
    uv = np.column_stack([rows % w, rows // w]).astype(np.float64)
    try:
        with np.errstate(all="ignore"):
            camera = _dlt(x, uv)
            if camera is None or not np.isfinite(camera).all():
                return None
            rms = _reprojection_rms(camera, x, uv)
            if not rms <= MAX_REPROJECTION_PX:
                return None
            pose = _decompose(camera)
    except np.linalg.LinAlgError:  # a degenerate sample (e.g. every point the same)
        return None
    if pose is None or not np.isfinite(pose[1]).all():
        return None
    rotation, center = pose
    turned = math.acos(max(-1.0, min(1.0, (np.trace(rotation) - 1.0) / 2.0)))
    if np.linalg.norm(center) <= ORIGIN_TOLERANCE and turned <= ORIGIN_TOLERANCE:
        return None
    return SensorPose(rotation, center, float(rms))


def _measured(points: NDArray) -> NDArray[np.bool_]:
    """Rows (n,) of ``points`` (n, 3) that may be measurements: finite, within MAX_COORDINATE."""
    with np.errstate(invalid="ignore"):
        return np.all(np.abs(points) <= MAX_COORDINATE, axis=1)


def _normaliser(p: NDArray[np.float64]) -> NDArray[np.float64]:
    """Similarity (d+1, d+1) moving ``p`` (n, d) to its centroid, mean distance sqrt(d)."""
    d = p.shape[1]
    c = p.mean(axis=0)
    s = math.sqrt(d) / max(float(np.mean(np.linalg.norm(p - c, axis=1))), 1e-12)
    t = np.eye(d + 1)
    t[:d, :d] *= s
    t[:d, d] = -s * c
    return t


def _dlt(x: NDArray[np.float64], uv: NDArray[np.float64]) -> NDArray[np.float64] | None:
    """Camera matrix (3, 4) mapping points ``x`` (n, 3) to pixels ``uv`` (n, 2), or None.

    Linear least squares on Hartley-normalised coordinates; None when the solution is not
    unique (:data:`MIN_SECOND_SINGULAR`).
    """
    tx, tu = _normaliser(x), _normaliser(uv)
    xh = np.column_stack([x, np.ones(len(x))]) @ tx.T
    uh = np.column_stack([uv, np.ones(len(uv))]) @ tu.T
    zero = np.zeros_like(xh)
    a = np.vstack([np.hstack([xh, zero, -uh[:, :1] * xh]),
                   np.hstack([zero, xh, -uh[:, 1:2] * xh])])
    _, s, vt = np.linalg.svd(a, full_matrices=False)
    if s[-2] < MIN_SECOND_SINGULAR * s[0]:
        return None
    return np.linalg.inv(tu) @ vt[-1].reshape(3, 4) @ tx


def _reprojection_rms(camera: NDArray[np.float64], x: NDArray[np.float64],
                      uv: NDArray[np.float64]) -> float:
    """RMS distance [px] between ``uv`` (n, 2) and the projections of ``x`` (n, 3)."""
    proj = np.column_stack([x, np.ones(len(x))]) @ camera.T
    err = proj[:, :2] / proj[:, 2:3] - uv  # a point at the camera's centre: inf, no fit
    return float(np.sqrt(np.mean(np.sum(err * err, axis=1))))


def _decompose(camera: NDArray[np.float64]
               ) -> tuple[NDArray[np.float64], NDArray[np.float64]] | None:
    """Rotation (3, 3) and centre (3,) of ``camera`` = K [R | -R C], or None if degenerate.

    K's diagonal is made positive (x right and y down along the pixel axes, the points in
    front of the camera: positive depth).
    """
    m = camera[:, :3]
    det = np.linalg.det(m)
    if abs(det) < 1e-300:
        return None
    if det < 0.0:  # P is known up to sign: with det M > 0, K R has det R = +1
        camera, m = -camera, -m
    k, r = rq(m)
    signs = np.sign(np.diag(k))
    if np.any(signs == 0):
        return None
    r = signs[:, None] * r  # K D D R with D = diag(signs): K D has a positive diagonal
    center = -np.linalg.solve(m, camera[:, 3])
    return r, center
