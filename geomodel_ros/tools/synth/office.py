"""An office floor seen by a Kinect-class camera: room-scale depth-camera data with exact labels.

:func:`office_scene` renders what a depth camera on a robot sees in a room: the floor
from about 1 m to the back wall, the back wall 3-4 m away with a door standing 3 cm proud
of it, a side wall, and two boxes on the floor at about 2 and 2.6 m. The camera (the
clutter scenes' 640 x 480 Kinect intrinsics) stands 1.3 m above the floor and looks at the
floor 1.8 m ahead (36 deg down), so the wall fills the top sixth of the image, as in an
office scene seen from standing height. Under Kinect noise the far range is where the
sensor's noise (sigma grows with the square of the range) and its disparity quantisation
(terraces 2.85e-3 z^2 apart: 3.5 cm at 3.5 m) matter: the desk scenes never go there.

Labels: 0 floor, 1 back wall, 2 door, 3 side wall, 4 box (0.4 x 0.3 x 0.4 m), 5 box
(0.5 m cube); -1 no return. Types: planes 0-3, cuboids 4-5.
"""

from __future__ import annotations

import math

import numpy as np

from .clutter import KINECT_CAMERA, _to_camera, camera_pose
from .scenes import NoiseModel, Scene, apply_noise
from .shapes import Box, Rectangle

__all__ = ["OFFICE_NAMES", "OFFICE_DISTANCES", "OFFICE_YAWS", "office_scene"]

#: Name of each label of :func:`office_scene`.
OFFICE_NAMES = ("floor", "wall", "door", "side wall", "box", "cube")
#: Distances of the back wall [m] and camera yaws [deg] of the benchmark's views.
OFFICE_DISTANCES = (3.0, 3.5, 4.0)
OFFICE_YAWS = (0.0, 20.0)
#: Camera height above the floor [m] and the floor point it looks at, straight ahead [m].
OFFICE_CAMERA_HEIGHT = 1.3
OFFICE_AIM = 1.8
#: How far the door stands out of the wall [m] (a door leaf in its frame).
OFFICE_DOOR_OFFSET = 0.03


def _frame(x, y, z) -> np.ndarray:
    """Rotation whose columns are the local x, y, z axes."""
    return np.stack([x, y, z], axis=1).astype(np.float64)


def office_scene(wall_distance: float = 3.5, yaw_deg: float = 0.0,
                 noise: NoiseModel | None = None, rng=None) -> Scene:
    """Render the office: floor, back wall, door, side wall and two boxes (module doc).

    Parameters
    ----------
    wall_distance : float
        Distance [m] from the camera's foot to the back wall, in (2, 6].
    yaw_deg : float
        Camera yaw [deg] from the wall's normal, in [-30, 30] (at 20 deg the side wall
        leaves the view and the wall is seen obliquely).
    noise : NoiseModel, optional
        Sensor degradations (e.g. ``KINECT_REAL_NOISE``); None gives the exact cloud.
    rng : None, int or Generator
        Randomness of the noise.
    """
    if not 2.0 < wall_distance <= 6.0 or not -30.0 <= yaw_deg <= 30.0:
        raise ValueError(f"wall_distance must be in (2, 6] m and yaw_deg in [-30, 30], got "
                         f"{wall_distance!r}, {yaw_deg!r}")
    ex, ey, ez = np.eye(3)
    d = float(wall_distance)
    facing = _frame(ey, -ez, -ex)  # a wall facing the camera (normal -x)
    shapes = [
        Rectangle(d + 3.0, 8.0, center=[d / 2 + 0.5, 0.0, 0.0], rotation=np.eye(3)),
        Rectangle(8.0, 2.6, center=[d, 0.0, 1.3], rotation=facing),
        Rectangle(0.9, 2.0, center=[d - OFFICE_DOOR_OFFSET, 0.6, 1.0], rotation=facing),
        Rectangle(d + 1.0, 2.6, center=[d / 2, -1.6, 1.3], rotation=_frame(ex, -ez, ey)),
        Box(0.4, 0.3, 0.4, center=[1.8, 0.3, 0.2], rotation=np.eye(3)),
        Box(0.5, 0.5, 0.5, center=[2.6, -0.5, 0.25], rotation=np.eye(3)),
    ]
    # The camera stands above the floor's origin and looks at the aim point on the floor.
    aim = (OFFICE_AIM, OFFICE_AIM * math.tan(math.radians(yaw_deg)))
    ground = math.hypot(*aim)
    rotation, position = camera_pose(math.hypot(ground, OFFICE_CAMERA_HEIGHT),
                                     math.atan2(OFFICE_CAMERA_HEIGHT, ground),
                                     math.atan2(-aim[1], -aim[0]), aim)
    posed = [_to_camera(s, rotation, position) for s in shapes]
    organized, labels = KINECT_CAMERA.render(posed)
    if noise is not None:
        organized, labels = apply_noise(organized, labels, noise, rng)
    return Scene(name=f"office_{d:g}m_{yaw_deg:g}deg", organized=organized, label_image=labels,
                 objects=[s.ground_truth(i) for i, s in enumerate(posed)],
                 intrinsics=KINECT_CAMERA.intrinsics)
