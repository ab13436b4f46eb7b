"""The node's per-frame path outside the core: what its faster forms must keep.

Expectations come from the definitions: a reconstruction is the samples of each object in
turn (``sample_primitive``), tagged with that object's id; a point is valid when x, y and z
are all finite (REP 117: NaN and +-inf are no return).
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from geomodel_ros.core.params import ModelingParams
from geomodel_ros.core.primitives import ModelingResult, Primitive
from geomodel_ros.core.reconstruction import reconstruct, sample_primitive
from geomodel_ros.ros.processing import process_cloud

from msg_adapters.header import make_header
from msg_adapters.pointcloud2 import cloud_to_xyz, xyz_to_cloud

ROT = Rotation.from_euler("xyz", [0.3, -1.1, 2.0]).as_matrix()


def _objects() -> list[Primitive]:
    c = np.array([0.2, -0.1, 0.9])
    return [
        Primitive(7, "plane", c, ROT, {"length": 0.3, "width": 0.2}, 100, 0.0),
        Primitive(2, "unknown", c, ROT, {}, 100, 0.0),
        Primitive(11, "cuboid", c + 0.1, ROT.T, {"length": 0.05, "width": 0.04,
                                                  "height": 0.03}, 100, 0.0),
        Primitive(4, "frustum", c - 0.1, np.eye(3), {"radius": 0.03, "top_radius": 0.02,
                                                     "height": 0.05}, 100, 0.0),
    ]


def test_reconstruction_is_each_objects_samples_in_turn_with_its_id():
    objects = _objects()
    points, ids = reconstruct(objects, 0.004)
    expected = [sample_primitive(p, 0.004) for p in objects]
    assert len(expected[1]) == 0  # unknown: nothing
    np.testing.assert_allclose(points, np.vstack(expected), rtol=0, atol=1e-12)
    np.testing.assert_array_equal(ids, np.repeat([p.id for p in objects],
                                                 [len(e) for e in expected]))
    assert ids.dtype == np.int32


def test_samples_are_the_local_surface_rotated_and_moved():
    plane = _objects()[0]
    world = sample_primitive(plane, 0.01)
    local = (world - plane.center) @ plane.rotation
    # A 0.3 x 0.2 m plane at 0.01 m: a 31 x 21 grid on z = 0 from corner to corner.
    assert len(world) == 31 * 21
    np.testing.assert_allclose(local[:, 2], 0.0, atol=1e-12)
    np.testing.assert_allclose(local.min(axis=0)[:2], [-0.15, -0.1], atol=1e-12)
    np.testing.assert_allclose(local.max(axis=0)[:2], [0.15, 0.1], atol=1e-12)


def test_no_objects_give_an_empty_reconstruction():
    points, ids = reconstruct([], 0.002)
    assert points.shape == (0, 3) and ids.shape == (0,)


def test_a_point_with_any_non_finite_coordinate_is_not_valid():
    pts = np.array([[0.1, 0.2, 1.0],
                    [np.nan, 0.2, 1.0],
                    [0.1, np.inf, 1.0],
                    [0.1, 0.2, -np.inf],
                    [0.3, 0.2, 1.1],
                    [-0.1, 0.0, 0.9]])
    seen = []

    def core(points, _params, **_):
        seen.append(points)
        return np.full(len(points), -1), ModelingResult(objects=[], timing={})

    frame = process_cloud(xyz_to_cloud(pts.reshape(2, 3, 3), make_header("cam", 5)),
                          ModelingParams(), model_scene=core, reconstruction=False)
    assert frame.valid_points == 3
    assert len(seen) == 1 and seen[0].shape == (6, 3)  # every row, aligned with the pixels
    nothing = process_cloud(xyz_to_cloud(pts[1:4], make_header("cam", 5)), ModelingParams(),
                            model_scene=core)
    assert nothing.valid_points == 0 and len(seen) == 1  # the core is not called


def test_a_built_cloud_reads_back_bit_for_bit():
    rng = np.random.default_rng(3)
    pts = rng.normal(size=(500, 3)).astype(np.float32)
    pts[::9, 1] = np.nan
    msg = xyz_to_cloud(pts, make_header("cam", 1), fields={"object_id": np.arange(500)})
    np.testing.assert_array_equal(cloud_to_xyz(msg, keep_organized=True,
                                               dtype=np.float32)[0], pts)
    assert len(msg.data) == 500 * msg.point_step and not msg.is_dense


def test_objects_and_markers_go_out_before_the_clouds_are_built(monkeypatch):
    from geomodel_ros.ros import processing

    objects = _objects()
    labels = np.array([7, 7, -1, 11, 11, 4])
    events: list[str] = []
    handed: list[tuple] = []
    real_segments, real_reconstruct = processing.segments_cloud, processing.reconstruct

    def segments(*args, **kwargs):
        events.append("segments")
        return real_segments(*args, **kwargs)

    def recon(*args, **kwargs):
        events.append("reconstruction")
        return real_reconstruct(*args, **kwargs)

    def first(markers, objects_msg):
        events.append("objects")
        handed.append((markers, objects_msg))

    def core(_points, _params, **_):
        return labels, ModelingResult(objects=objects, timing={})

    monkeypatch.setattr(processing, "segments_cloud", segments)
    monkeypatch.setattr(processing, "reconstruct", recon)
    pts = np.random.default_rng(2).normal(0.0, 0.1, (6, 3)) + [0.0, 0.0, 1.0]
    frame = process_cloud(xyz_to_cloud(pts, make_header("cam", 5)), ModelingParams(),
                          model_scene=core, on_objects=first)
    assert events == ["objects", "segments", "reconstruction"]
    assert len(handed) == 1
    assert handed[0][0] is frame.markers and handed[0][1] is frame.objects
    assert [o.id for o in frame.objects.primitives] == [7, 2, 11, 4]
    assert "first_out_s" in frame.timing
    # Without the callback nothing changes but the stage it would time.
    events.clear()
    plain = process_cloud(xyz_to_cloud(pts, make_header("cam", 5)), ModelingParams(),
                          model_scene=core)
    assert events == ["segments", "reconstruction"] and "first_out_s" not in plain.timing
