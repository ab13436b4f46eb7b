"""Synthetic sensor suite: every primitive type seen from 0.5-1.5 m, noise-free to Kinect-class.

A Kinect-like camera (640 x 480, f = 525 px) looks at a 0.4 m desk tilted like the paper's
(normal (0, -0.766, -0.643)) whose centre lies at distance 0.5, 1.0 or 1.5 m along the
paper's viewing direction. Three layouts share the desk: ``set_a`` (a box, a standing
cylinder, a sphere), ``set_b`` (a lying cylinder, a cone, a torus: irregular, must be
``unknown``) and ``set_c`` (frustums: a closed pot standing on its larger circle and an
open cup standing on its smaller one, rim up). Each is rendered noise-free, with ``mid``
noise and with :data:`KINECT_CLASS_NOISE`. Further shapes join through
:data:`EXTRA_LAYOUTS`: a name -> function returning layout items.
The room scene (:func:`~geomodel_ros.tools.synth.scenes.room_scene`) is the suite's
room-scale case.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Callable

import numpy as np

from .camera import PinholeCamera
from .scenes import (DESK_CENTER, DESK_NORMAL, DESK_SIZE, KINECT_CLASS_NOISE, KINECT_REAL_NOISE,
                     MIXED_EDGE_NOISE,
                     NoiseModel, Scene, apply_noise)
from .shapes import Box, Cone, Cylinder, Frustum, Rectangle, Shape, Sphere, Torus

__all__ = ["SUITE_CAMERA", "SUITE_DISTANCES", "SUITE_NOISE", "SUITE_LAYOUTS", "EXTRA_LAYOUTS",
           "SuiteCase", "suite_cases", "render_case"]

#: Kinect-like camera (640 x 480, 525 px focal length: 57 x 43 degrees).
SUITE_CAMERA = PinholeCamera(fx=525.0, fy=525.0, cx=319.5, cy=239.5, width=640, height=480)
#: Distances [m] of the desk centre from the camera.
SUITE_DISTANCES = (0.5, 1.0, 1.5)
#: Noise levels: none; half of Kinect-class (0.5 mm + 0.4 mm z^2); Kinect-class
#: (1.2 mm + 0.8 mm z^2, 5 % dropout, 3 holes).
SUITE_NOISE: dict[str, NoiseModel | None] = {
    "clean": None,
    "mid": NoiseModel(sigma_offset=0.0005, sigma_at_0_5m=0.0001, dropout=0.02),
    "kinect": KINECT_CLASS_NOISE,
}
#: Noise levels run only on request (``suite_cases(noises=...)``): a Kinect v1 as measured on
#: real frames (correlated range error and disparity quantisation added to Kinect-class).
OPTIONAL_NOISE: dict[str, NoiseModel] = {"kinect-real": KINECT_REAL_NOISE,
                                          "kinect-mixed": MIXED_EDGE_NOISE}

#: Layout item: a shape (posed at the origin, upright: local z along the desk normal, or
#: lying: local z in the desk plane), its desk coordinates u, v [mm] and "standing",
#: "inverted" (local z against the desk normal) or "lying", with a yaw [deg].
Item = tuple[Shape, float, float, str, float]


def _set_a() -> list[Item]:
    return [(Box(0.100, 0.070, 0.060), -90.0, -80.0, "standing", 20.0),
            (Cylinder(0.035, 0.100), 90.0, -80.0, "standing", 0.0),
            (Sphere(0.040), 0.0, 90.0, "standing", 0.0)]


def _set_b() -> list[Item]:
    return [(Cylinder(0.030, 0.120), -80.0, -60.0, "lying", 30.0),
            (Cone(0.045, 0.090), 90.0, -60.0, "standing", 0.0),
            (Torus(0.050, 0.018), 0.0, 100.0, "standing", 0.0)]


def _set_c() -> list[Item]:
    return [(Frustum(0.050, 0.032, 0.080), -80.0, -50.0, "standing", 0.0),
            (Frustum(0.042, 0.030, 0.095, base_cap=False), 80.0, -50.0, "inverted", 0.0)]


#: The suite's layouts.
SUITE_LAYOUTS: dict[str, Callable[[], list[Item]]] = {"set_a": _set_a, "set_b": _set_b,
                                                      "set_c": _set_c}
#: Layouts added by other modules (e.g. one with a frustum), run like SUITE_LAYOUTS.
EXTRA_LAYOUTS: dict[str, Callable[[], list[Item]]] = {}


def _desk_frame() -> np.ndarray:
    """(3, 3) rotation of the desk: x = camera x in the desk plane, z = desk normal."""
    x = np.array([1.0, 0.0, 0.0]) - DESK_NORMAL[0] * DESK_NORMAL
    x /= np.linalg.norm(x)
    return np.stack([x, np.cross(DESK_NORMAL, x), DESK_NORMAL], axis=1)


def _rot_z(deg: float) -> np.ndarray:
    c, s = np.cos(np.radians(deg)), np.sin(np.radians(deg))
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _place(item: Item, centre: np.ndarray) -> Shape:
    """Pose a layout item on the desk centred at ``centre`` (3,) [m], resting on it."""
    shape, u, v, how, yaw = item
    frame = _desk_frame()
    at = centre + 1e-3 * (u * frame[:, 0] + v * frame[:, 1])
    if how == "lying":
        z = frame @ _rot_z(yaw)[:, 0]
        x = frame[:, 2]
        rot = np.stack([x, np.cross(z, x), z], axis=1)
    else:
        rot = frame @ _rot_z(yaw)
        if how == "inverted":
            rot = rot @ np.diag([1.0, -1.0, -1.0])
    posed = replace(shape, center=at, rotation=rot)
    lowest = -posed.support(-DESK_NORMAL) - centre @ DESK_NORMAL
    return replace(posed, center=posed.center - lowest * DESK_NORMAL)


@dataclass(frozen=True)
class SuiteCase:
    """One rendered configuration: layout, distance [m], noise level name, seed."""

    layout: str
    distance: float
    noise: str
    seed: int


def suite_cases(seeds: tuple[int, ...] = (1,), noises: tuple[str, ...] | None = None
                ) -> list[SuiteCase]:
    """Every combination of layout, distance, noise level (default: SUITE_NOISE) and seed."""
    layouts = [*SUITE_LAYOUTS, *EXTRA_LAYOUTS]
    return [SuiteCase(lay, d, n, s) for lay in layouts for d in SUITE_DISTANCES
            for n in (noises or SUITE_NOISE) for s in seeds]


def render_case(case: SuiteCase) -> Scene:
    """Render one case: desk (label 0) and the layout's objects (1..K) with ground truth."""
    build = {**SUITE_LAYOUTS, **EXTRA_LAYOUTS}[case.layout]
    centre = case.distance * DESK_CENTER / np.linalg.norm(DESK_CENTER)
    frame = _desk_frame() @ _rot_z(10.0)
    shapes = [Rectangle(DESK_SIZE, DESK_SIZE, center=centre, rotation=frame)]
    shapes += [_place(item, centre) for item in build()]
    organized, labels = SUITE_CAMERA.render(shapes)
    noise = {**SUITE_NOISE, **OPTIONAL_NOISE}[case.noise]
    if noise is not None:
        organized, labels = apply_noise(organized, labels, noise, case.seed)
    return Scene(name=f"{case.layout}@{case.distance:g}m/{case.noise}", organized=organized,
                 label_image=labels, objects=[s.ground_truth(i) for i, s in enumerate(shapes)],
                 intrinsics=SUITE_CAMERA.intrinsics)
