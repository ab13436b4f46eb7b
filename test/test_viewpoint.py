"""The camera of an organized cloud from its pixel grid (``core.viewpoint``).

Clouds that a robot's pipeline moved out of the camera's frame: a rendered clutter frame
(exact pinhole camera at the origin, optical axes) is moved into a robot's base frame (x
forward, y left, z up; the camera 1.25 m up, off the base's origin, pitched 25 deg down)
by a rigid transform chosen here. The recovered camera must be that transform, the
modeled objects those of the frame in the camera's own frame, moved by it. Clouds
already in their camera's frame are modeled as given; grids that are no pinhole image (a
re-sorted cloud, one noise-free plane, a lens's distortion, a handful of returns) give
no camera.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from geomodel_ros.core.modeling import model_scene
from geomodel_ros.core.params import ModelingParams
from geomodel_ros.core.viewpoint import grid_sensor_pose
from geomodel_ros.tools.synth.clutter import KINECT_NOISE, render_clutter

TILT = np.radians(25.0)
#: Camera optical axes (x right, y down, z forward) in the base frame, pitched down by TILT
#: (a turn about the base's y axis).
OPTICAL_IN_BASE = np.array([[np.cos(TILT), 0.0, np.sin(TILT)],
                            [0.0, 1.0, 0.0],
                            [-np.sin(TILT), 0.0, np.cos(TILT)]]) @ np.array(
    [[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
CAMERA_IN_BASE = np.array([0.3, -0.2, 1.25])


def _to_base(points: np.ndarray) -> np.ndarray:
    """Points (N, 3) of the camera's optical frame in the base frame."""
    return points @ OPTICAL_IN_BASE.T + CAMERA_IN_BASE


@pytest.fixture(scope="module")
def frame():
    scene = render_clutter(5, KINECT_NOISE)
    return scene, scene.organized.reshape(-1, 3), scene.organized.shape[:2]


def test_the_camera_of_a_moved_frame_is_the_transform(frame):
    _, pts, shape = frame
    assert np.linalg.det(OPTICAL_IN_BASE) == pytest.approx(1.0)
    for moved, tol in ((_to_base(pts), 1e-9), (_to_base(pts).astype(np.float32), 1e-6)):
        pose = grid_sensor_pose(moved, shape)
        assert pose is not None
        assert np.abs(pose.center - CAMERA_IN_BASE).max() < tol
        # p_sensor = R (p - C): R takes the base frame to the optical one.
        assert np.abs(pose.rotation - OPTICAL_IN_BASE.T).max() < tol
        assert pose.rms_px < 1e-3
        back = pose.to_sensor(np.asarray(moved, dtype=np.float64))
        ok = np.isfinite(pts).all(axis=1)
        assert np.abs(back[ok] - pts[ok]).max() < 100 * tol


def test_a_frame_in_its_cameras_frame_has_no_pose_to_recover(frame):
    _, pts, shape = frame
    assert grid_sensor_pose(pts, shape) is None
    assert grid_sensor_pose(pts.astype(np.float32), shape) is None


def test_the_real_kinect_frame_is_in_its_cameras_frame():
    from data_helpers import DATA, require

    from geomodel_ros.tools.io import load_osd

    pts, _ = load_osd(require(DATA / "osd_learn" / "learn0.pcd"))
    assert grid_sensor_pose(pts, (480, 640)) is None
    pose = grid_sensor_pose(_to_base(pts), (480, 640))
    assert pose is not None and np.abs(pose.center - CAMERA_IN_BASE).max() < 1e-5


def test_grids_that_are_no_pinhole_image_give_no_camera(frame):
    _, pts, shape = frame
    moved = _to_base(pts)
    rng = np.random.default_rng(0)
    # Rows re-sorted: every point keeps its coordinates but not its pixel.
    assert grid_sensor_pose(moved[rng.permutation(len(moved))], shape) is None
    # A flat wall alone: a family of cameras maps it to its pixels (no unique camera).
    h, w = 60, 80
    v, u = np.mgrid[0:h, 0:w].astype(float)
    wall = np.stack([(u - 40) / 500.0 * 2.0, (v - 30) / 500.0 * 2.0, np.full_like(u, 2.0)],
                    axis=-1).reshape(-1, 3)
    assert grid_sensor_pose(_to_base(wall), (h, w)) is None
    # A lens's distortion that the driver did not remove (radial, k1 = 0.2: 30 px at the
    # corners of a 640 x 480 image): its points lie on bent rays, no pinhole camera's.
    v, u = np.mgrid[0:480, 0:640].astype(float)
    xn, yn = (u - 320.0) / 525.0, (v - 240.0) / 525.0
    bend = 1.0 + 0.2 * (xn * xn + yn * yn)
    depth = 1.0 + 0.2 * np.sin(3.0 * xn) * np.cos(2.0 * yn)  # no plane
    bent = np.stack([xn * bend * depth, yn * bend * depth, depth], axis=-1).reshape(-1, 3)
    assert grid_sensor_pose(_to_base(bent), (480, 640)) is None
    straight = np.stack([xn * depth, yn * depth, depth], axis=-1).reshape(-1, 3)
    assert grid_sensor_pose(_to_base(straight), (480, 640)) is not None
    # A handful of returns.
    few = np.full_like(moved, np.nan)
    keep = rng.choice(np.flatnonzero(np.isfinite(moved).all(axis=1)), 50, replace=False)
    few[keep] = moved[keep]
    assert grid_sensor_pose(few, shape) is None


def test_a_moved_frame_gives_the_objects_of_its_camera_frame_moved(frame):
    scene, pts, shape = frame
    labels, result = model_scene(pts.reshape(*shape, 3), ModelingParams())
    moved_labels, moved = model_scene(_to_base(pts).reshape(*shape, 3), ModelingParams())
    assert result.sensor is None
    assert moved.sensor is not None
    assert np.abs(moved.sensor.center - CAMERA_IN_BASE).max() < 1e-9
    assert np.mean(moved_labels == labels) > 0.999
    assert len(moved.objects) == len(result.objects)
    for a, b in zip(result.objects, moved.objects):
        assert (a.id, a.type) == (b.id, b.type)
        np.testing.assert_allclose(_to_base(a.center[None])[0], b.center, atol=1e-3)
        np.testing.assert_allclose(OPTICAL_IN_BASE @ a.rotation, b.rotation, atol=1e-3)
        for k, v in a.dimensions.items():
            assert b.dimensions[k] == pytest.approx(v, abs=1e-3)
    # The support planes, moved: n' = R n, d' = d - n' . C (its normal still faces the
    # camera), and they hold the desk's points in the base frame.
    assert set(moved.supports) == set(result.supports)
    for k, (normal, d) in result.supports.items():
        n_base = OPTICAL_IN_BASE @ normal
        np.testing.assert_allclose(moved.supports[k][0], n_base, atol=1e-3)
        assert moved.supports[k][1] == pytest.approx(d - n_base @ CAMERA_IN_BASE, abs=1e-3)
        assert CAMERA_IN_BASE @ moved.supports[k][0] + moved.supports[k][1] > 0.0
    desk = max(moved.supports, key=lambda k: np.count_nonzero(moved_labels == k))
    normal, d = moved.supports[desk]
    assert np.median(np.abs(_to_base(pts)[moved_labels == desk] @ normal + d)) < 0.003
    # Many more objects than one: the scene's types are found at all.
    assert sum(o.type.value != "unknown" for o in moved.objects) >= 10


def test_origin_models_the_moved_frame_as_given(frame):
    _, pts, shape = frame
    _, as_given = model_scene(_to_base(pts).reshape(*shape, 3),
                              ModelingParams(viewpoint="origin"))
    _, own = model_scene(pts.reshape(*shape, 3), ModelingParams())
    assert as_given.sensor is None
    # Its rays are then taken from the base's origin: the ranges the noise is measured at
    # are the points' distances from there (about 1.3 m), not from the camera (0.6 m).
    base_range = np.median(np.linalg.norm(_to_base(pts[np.isfinite(pts).all(axis=1)]), axis=1))
    assert as_given.noise.depth == pytest.approx(base_range, rel=0.05)
    assert abs(as_given.noise.depth - own.noise.depth) > 0.3


def test_unorganized_clouds_are_modeled_as_given(frame):
    _, pts, _ = frame
    ok = np.isfinite(pts).all(axis=1)
    _, result = model_scene(_to_base(pts[ok]), ModelingParams())
    assert result.sensor is None


def test_the_json_and_the_diagnostics_carry_the_camera(frame):
    from msg_adapters.diagnostics import sensor_values

    _, pts, shape = frame
    _, moved = model_scene(_to_base(pts).reshape(*shape, 3), ModelingParams())
    out = json.loads(json.dumps(moved.to_dict()))
    np.testing.assert_allclose(out["sensor"]["center"], CAMERA_IN_BASE, atol=1e-9)
    # Its optical axes as columns in the base frame: z (forward) tilted 25 deg down.
    z = np.array(out["sensor"]["rotation"])[:, 2]
    np.testing.assert_allclose(z, [np.cos(TILT), 0.0, -np.sin(TILT)], atol=1e-9)
    assert sensor_values(moved.sensor) == {"sensor_origin_m": "0.3000 -0.2000 1.2500"}
    assert sensor_values(None) == {}
    _, own = model_scene(pts.reshape(*shape, 3), ModelingParams())
    assert own.to_dict()["sensor"] is None


def test_the_node_models_a_cloud_in_the_robots_frame_and_answers_in_it(frame):
    from geomodel_ros.ros.processing import process_cloud
    from msg_adapters.header import make_header
    from msg_adapters.pointcloud2 import xyz_to_cloud

    _, pts, shape = frame
    _, own = model_scene(pts.reshape(*shape, 3), ModelingParams())
    msg = xyz_to_cloud(_to_base(pts).astype(np.float32).reshape(*shape, 3),
                       make_header("base_link", 7))
    out = process_cloud(msg, ModelingParams(), segments=False, reconstruction=True)
    assert out.diagnostics["sensor_origin_m"] == "0.3000 -0.2000 1.2500"
    assert out.markers.markers[-1].header.frame_id == "base_link"
    types = sorted(o.type.value for o in out.result.objects)
    assert types == sorted(o.type.value for o in own.objects)
    # The desk (the largest object) in the base frame: its plane through the moved points.
    desk = max(out.result.objects, key=lambda o: o.point_count)
    own_desk = max(own.objects, key=lambda o: o.point_count)
    np.testing.assert_allclose(desk.center, _to_base(own_desk.center[None])[0], atol=2e-3)
    # The reconstruction is the camera frame's, moved into the base frame.
    from geomodel_ros.core.reconstruction import reconstruct
    from msg_adapters.pointcloud2 import cloud_to_xyz

    recon = cloud_to_xyz(out.reconstruction)
    expected, _ = reconstruct(own.objects, ModelingParams().reconstruction_spacing)
    assert len(recon) == pytest.approx(len(expected), rel=0.01)
    np.testing.assert_allclose(recon.mean(axis=0), _to_base(expected).mean(axis=0), atol=2e-3)


def test_garbage_rows_neither_hide_the_camera_nor_raise(frame):
    # A driver's garbage among the returns of a moved frame: rows at 1e300 and 1e308 m
    # (finite), infinities, NaN. The camera comes from the rest; nothing overflows into a
    # warning (errors here) and the garbage rows belong to no object.
    import warnings

    _, pts, shape = frame
    moved = _to_base(pts)
    moved[::97] = 1e300
    moved[1::89] = [1e308, -1e308, 1e308]
    moved[2::83] = np.inf
    moved[3::79] = np.nan
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        pose = grid_sensor_pose(moved, shape)
        assert pose is not None and np.abs(pose.center - CAMERA_IN_BASE).max() < 1e-9
        labels, result = model_scene(moved.reshape(*shape, 3), ModelingParams())
    assert result.sensor is not None
    assert np.all(labels[::97] == -1) and np.all(labels[1::89] == -1)
    assert sum(o.type.value != "unknown" for o in result.objects) >= 10
    # The same garbage in the camera's own frame (the hidden ends' view of the returns
    # squared 1e300 into an overflow warning before).
    own = pts.copy()
    own[::97] = 1e300
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        labels, result = model_scene(own.reshape(*shape, 3), ModelingParams())
    assert result.sensor is None and np.all(labels[::97] == -1)
