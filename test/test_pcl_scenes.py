"""Boxes that are partly bent (a carton's gable) are boxes; round objects stay round.

The real scenes of ``../shared/data/pcl_scenes`` carry no labels: the expectations are what
a person sees in them (the data README), located by the pixels where a person sees each
object in the scene's colour image. The synthetic cartons and cylinders have exact
geometry, worked out below by hand.
"""

from __future__ import annotations

import functools
import math
from types import SimpleNamespace

import numpy as np
import pytest

from data_helpers import DATA, require
from geomodel_ros.core.fitting.strategies import truncated_cost
from geomodel_ros.core.obb import ray_offset_to_plane
from geomodel_ros.core.modeling import model_objects, model_scene
from geomodel_ros.core.noise import K_INLIER
from geomodel_ros.core.params import ModelingParams
from geomodel_ros.core.primitives import Primitive
from geomodel_ros.tools.synth import render_scene
from geomodel_ros.tools.synth.clutter import KINECT_CAMERA
from geomodel_ros.tools.synth.scenes import NoiseModel, apply_noise
from geomodel_ros.tools.synth.shapes import Box, Cone, Cylinder, Rectangle

PCL_SCENES = DATA / "pcl_scenes"
#: Where the milk carton is in the 640 x 480 image (rows, columns), seen in its colour.
CARTON_ROWS, CARTON_COLS = slice(70, 210), slice(245, 315)
#: Carpet at the top right of the milk scene's image, 1.6-2.1 m away, seen in its colour.
FAR_CARPET_ROWS, FAR_CARPET_COLS = slice(40, 80), slice(520, 610)
#: Where the shrink-wrapped pack of six bottles is in the region-growing scene's image.
PACK_ROWS, PACK_COLS = slice(145, 285), slice(325, 425)
#: Kinect-class depth noise: 1.2 mm + 0.5 mm (z / 0.5 m)^2, i.e. 3 mm at 0.95 m.
NOISE = NoiseModel(sigma_at_0_5m=0.0005, dropout=0.02, sigma_offset=0.0012)
#: A half-gallon carton: 95 mm square body, 195 mm tall, gable 45 mm high on top.
SIDE, BODY, GABLE = 0.095, 0.195, 0.045


# ------------------------------------------------------------------------ real scenes
@functools.lru_cache(maxsize=None)
def _modeled(name: str):
    from geomodel_ros.tools.io import read_cloud

    cloud = read_cloud(require(PCL_SCENES / name))
    labels, result = model_scene(cloud.points)
    return cloud.points, labels.reshape(480, 640), result


def _object_at(labels: np.ndarray, result, rows: slice, cols: slice) -> Primitive:
    """Return the reported object holding most pixels of the image window."""
    ids, counts = np.unique(labels[rows, cols], return_counts=True)
    counts = counts[ids >= 0]
    ids = ids[ids >= 0]
    oid = int(ids[np.argmax(counts)])
    return next(o for o in result.objects if o.id == oid)


def _floor_normal(result) -> np.ndarray:
    floor = max((o for o in result.objects if o.type == "plane"), key=lambda o: o.point_count)
    return floor.rotation[:, 2]


def test_milk_scene_floor_is_one_plane() -> None:
    _, labels, result = _modeled("milk_cartoon_all_small_clorox.pcd")
    big = [o for o in result.objects if o.point_count >= 100_000]
    assert [str(o.type) for o in big] == ["plane"]  # the carpet, seen whole
    assert big[0].point_count >= 0.7 * np.count_nonzero(labels >= 0)


def test_milk_carton_is_a_cuboid_of_a_cartons_size() -> None:
    _, labels, result = _modeled("milk_cartoon_all_small_clorox.pcd")
    carton = _object_at(labels, result, CARTON_ROWS, CARTON_COLS)
    assert carton.type == "cuboid", carton.reason
    up = _floor_normal(result)
    dims = np.array([carton.dimensions[k] for k in ("length", "width", "height")])
    tilt = np.degrees(np.arccos(np.abs(carton.rotation.T @ up)))
    vertical = int(np.argmin(tilt))
    assert tilt[vertical] < 10.0  # it stands on the floor
    # 95 mm square (the sensor's silhouettes run a few mm wide at 1 m, the more on a
    # face seen at a grazing angle), 195 mm body + up to 50 mm of gable
    sides = np.delete(dims, vertical)
    assert np.all((sides >= 0.085) & (sides <= 0.120)), dims
    assert 0.190 <= dims[vertical] <= 0.260, dims


def test_milk_scene_far_carpet_is_the_floor() -> None:
    # The carpet at the top right, 1.6-2.1 m away, bends 10-14 mm away from the floor's
    # plane (the sensor's range error grows with range): it was reported as a plane of its
    # own (2481 points), a fragment of the floor.
    _, labels, result = _modeled("milk_cartoon_all_small_clorox.pcd")
    floor = max(result.objects, key=lambda o: o.point_count)
    assert floor.type == "plane"
    window = labels[FAR_CARPET_ROWS, FAR_CARPET_COLS]
    assert np.mean(window == floor.id) >= 0.9


@pytest.mark.filterwarnings("error")
def test_office_scene_models_without_numeric_warnings() -> None:
    # A cuboid face that got no points averaged an empty array (RuntimeWarning).
    from geomodel_ros.tools.io import read_cloud

    model_scene(read_cloud(require(PCL_SCENES / "region_growing_rgb_tutorial.pcd")).points)


@pytest.mark.parametrize("name", ["region_growing_rgb_tutorial.pcd",
                                  "milk_cartoon_all_small_clorox.pcd"])
def test_no_box_is_thinner_than_the_noise_at_its_range(name: str) -> None:
    # Two opposite faces within one inlier band (K_INLIER sigma at the object's range, the
    # frame's own noise) are one plane's points: the office's strip of two disparity levels
    # at 3 m (151 points) was a 25 x 63 x 448 mm box under a 122 mm band.
    points, labels, result = _modeled(name)
    rows = labels.ravel()
    flat = np.asarray(points, dtype=float).reshape(-1, 3)
    boxes = [o for o in result.objects if o.type == "cuboid"]
    assert boxes or name.startswith("region"), "the milk scene's carton is a box"
    for o in boxes:
        at = float(np.median(np.linalg.norm(flat[rows == o.id], axis=1)))
        band = max(ModelingParams().ransac_threshold, K_INLIER * result.noise.sigma(at))
        assert min(o.dimensions.values()) > band, (o.id, o.dimensions, band)


def test_milk_scene_has_no_huge_round_object() -> None:
    # before the box rival the carton came out as a cylinder of radius 239 mm
    _, _, result = _modeled("milk_cartoon_all_small_clorox.pcd")
    radii = [o.dimensions["radius"] for o in result.objects
             if o.type in ("cylinder", "cone", "frustum")]
    assert all(r < 0.150 for r in radii), radii


def test_office_back_wall_and_door_are_no_round_bodies() -> None:
    # The wall and door 3.3-3.6 m away are planes (the data README). Their pieces bend
    # with the sensor's slow range errors, and a wide cone (r 243 and 424 mm) holds their
    # points closer than their planes beyond the noise; but their measured normals do not
    # turn with it (strategies.round_of_plane).
    points, labels, result = _modeled("region_growing_rgb_tutorial.pcd")
    flat = np.asarray(points, dtype=float).reshape(-1, 3)
    rows = labels.ravel()
    far = [o for o in result.objects
           if np.median(np.linalg.norm(flat[rows == o.id], axis=1)) > 3.0]
    assert len(far) >= 3
    assert all(o.type in ("plane", "unknown") for o in far), [(o.id, o.type) for o in far]


@pytest.mark.xfail(strict=True, reason="the bottle pack (transparent PET under shrink-wrap, "
                   "many depth holes) is split by the segmentation into five segments; the "
                   "largest is modeled as `unknown`")
def test_bottle_pack_is_one_cuboid() -> None:
    _, labels, result = _modeled("region_growing_rgb_tutorial.pcd")
    floor = max(result.objects, key=lambda o: o.point_count).id  # seen through holes
    window = labels[PACK_ROWS, PACK_COLS]
    window = window[(window >= 0) & (window != floor)]
    ids, counts = np.unique(window, return_counts=True)
    pack = next(o for o in result.objects if o.id == ids[np.argmax(counts)])
    assert counts.max() >= 0.8 * len(window)
    assert pack.type == "cuboid"


def test_bottle_pack_is_not_typed_round() -> None:
    # The pack's largest segment (the upper bottles and their shoulders, a bump facing
    # the sensor) was a cone of radius 341 mm whose axis ran almost along the floor: its
    # base reached 95 mm into the floor, which no solid resting above it can.
    _, labels, result = _modeled("region_growing_rgb_tutorial.pcd")
    floor = max(result.objects, key=lambda o: o.point_count).id  # seen through holes
    window = labels[PACK_ROWS, PACK_COLS]
    ids, counts = np.unique(window[(window >= 0) & (window != floor)], return_counts=True)
    pack = next(o for o in result.objects if o.id == ids[np.argmax(counts)])
    assert pack.type not in ("cylinder", "cone", "frustum", "sphere"), pack.reason
    assert "into the support" in pack.reason


# ------------------------------------------------------------------------ synthetic
def _look(elevation_deg: float, distance: float, target) -> tuple[np.ndarray, np.ndarray]:
    """Return the optical-frame rotation (rows x, y, z) and position [m] of a camera.

    It looks at ``target`` from ``elevation_deg`` above the floor (world z up).
    """
    e = math.radians(elevation_deg)
    forward = np.array([0.0, math.cos(e), -math.sin(e)])
    right = np.cross(forward, [0.0, 0.0, 1.0])
    right /= np.linalg.norm(right)
    return np.array([right, np.cross(forward, right), forward]), target - distance * forward


def _yaw(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _gabled_carton(turn: float) -> list:
    """Return the body and the two roof slopes of a carton at the world origin (z up)."""
    yaw = _yaw(turn)
    shapes = [(Box, dict(length=SIDE, width=SIDE, height=BODY), [0, 0, BODY / 2], yaw)]
    slope = math.hypot(SIDE / 2, GABLE)
    for s in (1.0, -1.0):
        down = np.array([0.0, s * SIDE / 2, -GABLE]) / slope  # from the ridge to the eave
        x = np.array([s, 0.0, 0.0])
        rot = np.column_stack([x, down, np.cross(x, down)])
        shapes.append((Rectangle, dict(length=SIDE, width=slope),
                       yaw @ [0, s * SIDE / 4, BODY + GABLE / 2], yaw @ rot))
    return shapes


def _render(shapes: list, seed: int, elevation_deg: float = 50.0):
    """Return the noisy cloud and labels (floor 0, object 1) of ``shapes`` on a floor."""
    r, cam = _look(elevation_deg, 0.95, np.array([0.0, 0.0, 0.1]))
    floor = (Rectangle, dict(length=3.0, width=3.0), [0, 0, 0], np.eye(3))
    posed = [cls(**size, center=r @ (np.asarray(c, dtype=float) - cam), rotation=r @ rot)
             for cls, size, c, rot in [floor] + shapes]
    pts, lab = KINECT_CAMERA.render(posed, [0] + [1] * len(shapes))
    pts, lab = apply_noise(pts, lab, NOISE, np.random.default_rng(seed))
    return pts.reshape(-1, 3), lab.reshape(-1)


@pytest.mark.parametrize("turn_deg", [20.0, 35.0])
def test_gabled_carton_is_a_cuboid(turn_deg: float) -> None:
    # With this noise draw the gable and the front side come out as one curved face, as
    # on the real carton: a cylinder fits them, and the box of the flat core wins.
    pts, lab = _render(_gabled_carton(math.radians(turn_deg)), seed=0)
    carton = next(o for o in model_objects(pts, lab).objects if o.id == 1)
    assert carton.type == "cuboid", carton.reason
    dims = sorted(carton.dimensions.values())
    assert dims[0] == pytest.approx(SIDE, abs=0.006)
    assert dims[1] == pytest.approx(SIDE, abs=0.006)
    # the enclosing box of body and gable, within two noise bands (2 x 3.5 sigma)
    assert dims[2] == pytest.approx(BODY + GABLE, abs=0.021)


@pytest.mark.parametrize("radius,height", [(0.03, 0.12), (0.05, 0.2), (0.1, 0.2),
                                           (0.2, 0.12)])
def test_standing_cylinders_never_become_boxes(radius: float, height: float) -> None:
    shape = (Cylinder, dict(radius=radius, height=height), [0, 0, height / 2], np.eye(3))
    for seed in (0, 1):
        pts, lab = _render([shape], seed)
        cyl = next(o for o in model_objects(pts, lab).objects if o.id == 1)
        assert cyl.type != "cuboid", cyl.reason
        if radius >= 0.05:  # (a 30 mm can at 0.95 m comes out a cone with one noise draw)
            assert cyl.type == "cylinder", cyl.reason
            assert cyl.dimensions["radius"] == pytest.approx(radius, rel=0.03)


def test_half_hidden_cylinder_beats_its_box_rival() -> None:
    # The cylinder behind the tall box shows one strip, whose normals turn little: a box
    # of that strip is tried against it and loses.
    scene = render_scene("occluded")
    result = model_objects(scene.points, scene.labels)
    cyl = next(o for o in result.objects if o.id == 2)
    assert cyl.type == "cylinder"
    assert "does not replace cylinder" in cyl.reason
    assert cyl.dimensions["radius"] == pytest.approx(0.030, abs=0.0003)


def test_truncated_cost_by_hand() -> None:
    t = 0.004
    box = Primitive(1, "cuboid", np.zeros(3), np.eye(3),
                    {"length": 0.1, "width": 0.1, "height": 0.1}, 4, 0.0)
    on = np.array([[0.05, 0.0, 0.0], [0.0, -0.05, 0.01], [0.02, 0.0, 0.05]])
    cloud = SimpleNamespace(points=on, params=SimpleNamespace(ransac_threshold=t))
    assert truncated_cost(box, cloud) == pytest.approx(0.0, abs=1e-12)
    half = np.array([[0.05 + t / 2, 0.0, 0.0], [0.0, 0.0, -0.05 - t / 2]])
    far = np.array([[0.05 + 2 * t, 0.0, 0.0], [0.0, 0.0, 0.5]])
    cloud.points = np.vstack([half, far])  # (0.25 + 0.25 + 1 + 1) / 4
    assert truncated_cost(box, cloud) == pytest.approx(0.625)
    cloud.points = np.array([[0.0, 0.0, 0.0]])  # the centre: half a side from every face
    assert truncated_cost(box, cloud) == pytest.approx(1.0)


def test_ray_offset_to_plane_by_hand() -> None:
    n, d = np.array([0.0, 0.0, 1.0]), -1.0  # the plane z = 1 m
    pts = np.array([
        [0.0, 0.0, 1.01],  # on the optical axis, 10 mm behind the plane
        [0.3, 0.4, 0.9],  # its ray meets the plane at 1/0.9 of its distance (0.5/0.9 m)
        [1.0, 0.0, 0.1],  # a ray at 84 deg to the normal: too oblique to judge
        [0.0, 0.0, -1.0],  # the ray points away from the plane
    ])
    off = ray_offset_to_plane(pts, n, d)
    dist = np.linalg.norm(pts[1])
    assert off[0] == pytest.approx(0.01)
    assert off[1] == pytest.approx(dist / 0.9 - dist)
    assert off[2] == 0.0
    assert off[3] == np.inf


def _lying_cone(radius: float, height: float) -> tuple:
    """Return a cone lying on its side on the floor (a generator on it), z up."""
    alpha = math.atan(radius / height)
    tilt = math.pi / 2 + alpha  # local z (base -> apex) turned down to alpha below level
    rot = np.array([[math.cos(tilt), 0.0, math.sin(tilt)], [0.0, 1.0, 0.0],
                    [-math.sin(tilt), 0.0, math.cos(tilt)]])
    base = np.array([0.0, 0.0, radius * math.cos(alpha)])
    return (Cone, dict(radius=radius, height=height), base + rot[:, 2] * height / 2, rot)


@pytest.mark.parametrize("lying", [False, True])
def test_resting_cones_stay_cones(lying: bool) -> None:
    # A real cone touches its support along its base rim (standing) or along a generator
    # (lying): its solid reaches no deeper than the noise band into the floor.
    radius, height = 0.08, 0.20
    shape = _lying_cone(radius, height) if lying else \
        (Cone, dict(radius=radius, height=height), [0, 0, height / 2], np.eye(3))
    for seed in (0, 1):
        pts, lab = _render([shape], seed)
        cone = next(o for o in model_objects(pts, lab).objects if o.id == 1)
        assert cone.type == "cone", cone.reason
        assert cone.dimensions["radius"] == pytest.approx(radius, rel=0.05)
        assert cone.dimensions["height"] == pytest.approx(height, rel=0.05)
