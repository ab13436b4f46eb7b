"""Synthetic depth-camera data with exact ground truth.

Analytic shapes, the ray-casting pinhole camera, the paper's desk scenes and seeded
cluttered tabletop scenes (:mod:`geomodel_ros.tools.synth.clutter`).

ROS-free (numpy only).  Typical use::

    from geomodel_ros.tools.synth import render_scene, SENSOR_NOISE
    scene = render_scene("scene3", noise=SENSOR_NOISE, rng=0)
    scene.points, scene.labels, scene.objects
"""

from .camera import DEFAULT_CHUNK_SIZE, PinholeCamera
from .clutter import KINECT_CAMERA, KINECT_NOISE, OpenFrustum, render_clutter, render_layout
from .scenes import (
    DESK_CENTER,
    DESK_NORMAL,
    DESK_SIZE,
    GROUND_TRUTH_TYPES,
    PAPER_CAMERA,
    PAPER_SCENE_NAMES,
    SCENE_NAMES,
    KINECT_CLASS_NOISE,
    SENSOR_NOISE,
    TINY_CAMERA,
    GroundTruthObject,
    NoiseModel,
    Scene,
    apply_noise,
    desk_frame,
    render_scene,
    scene_geometry,
)
from .shapes import Box, Cone, Cylinder, Frustum, Rectangle, Shape, Sphere, Torus

__all__ = [
    "PinholeCamera",
    "DEFAULT_CHUNK_SIZE",
    "Shape",
    "Rectangle",
    "Box",
    "Cylinder",
    "Cone",
    "Frustum",
    "Sphere",
    "Torus",
    "GroundTruthObject",
    "GROUND_TRUTH_TYPES",
    "NoiseModel",
    "SENSOR_NOISE",
    "KINECT_CLASS_NOISE",
    "Scene",
    "SCENE_NAMES",
    "PAPER_SCENE_NAMES",
    "PAPER_CAMERA",
    "TINY_CAMERA",
    "DESK_CENTER",
    "DESK_NORMAL",
    "DESK_SIZE",
    "desk_frame",
    "scene_geometry",
    "render_scene",
    "apply_noise",
    "OpenFrustum",
    "KINECT_CAMERA",
    "KINECT_NOISE",
    "render_clutter",
    "render_layout",
]
