"""Tests of msg_adapters.depth_image: depth Image + CameraInfo -> organized cloud, no rclpy.init.

Images are packed with ``struct`` pixel by pixel (a reference independent of the numpy
view under test); expected points are worked out by hand from the pinhole model
``x = (u - cx) z / fx, y = (v - cy) z / fy`` or come from the synthetic camera's ray caster.
"""

import os

os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")

import array
import math
import struct
from types import SimpleNamespace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from builtin_interfaces.msg import Time
from sensor_msgs.msg import CameraInfo, Image, RegionOfInterest
from std_msgs.msg import Header

from geomodel_ros.tools.synth import render_scene
from msg_adapters.depth_image import (CameraModel, DepthImageError, camera_info, camera_model,
                                      depth_image, depth_to_metres, depth_to_scene, depth_to_xyz)

HEADER = Header(stamp=Time(sec=7, nanosec=250), frame_id="depth_optical")
PAD = 0xA5  # filler of row padding: read by mistake, it shows up as garbage
#: fx, fy, cx, cy of the small test camera [px]
SMALL = CameraModel(fx=500.0, fy=400.0, cx=1.0, cy=0.5, width=3, height=2)
#: The 2 x 3 test image [mm]: (row 0) 1000, 0 (no return), 2000; (row 1) 1250, 3000, 1500.
MM = [[1000, 0, 2000], [1250, 3000, 1500]]
#: Its points worked out by hand [m] (NaN: no return).
EXPECTED = np.array([
    [[(0 - 1) * 1.0 / 500, (0 - 0.5) * 1.0 / 400, 1.0],   # (-0.002, -0.00125, 1)
     [math.nan] * 3,
     [(2 - 1) * 2.0 / 500, (0 - 0.5) * 2.0 / 400, 2.0]],  # (0.004, -0.0025, 2)
    [[-0.0025, 0.5 * 1.25 / 400, 1.25],                   # (-0.0025, 0.0015625, 1.25)
     [0.0, 0.5 * 3.0 / 400, 3.0],                         # (0, 0.00375, 3)
     [0.003, 0.5 * 1.5 / 400, 1.5]],                      # (0.003, 0.001875, 1.5)
])


def pack_image(rows, encoding, *, bigendian=False, step=None):
    """Image whose pixels are packed by struct; row padding filled with PAD."""
    code = {"16UC1": "H", "32FC1": "f"}.get(encoding, "H")
    size = struct.calcsize(code)
    height, width = len(rows), len(rows[0])
    step = width * size if step is None else step
    buf = bytearray([PAD]) * (step * height)
    for v, row in enumerate(rows):
        for u, value in enumerate(row):
            struct.pack_into((">" if bigendian else "<") + code, buf, v * step + u * size, value)
    return Image(header=HEADER, height=height, width=width, encoding=encoding,
                 is_bigendian=int(bigendian), step=step, data=array.array("B", bytes(buf)))


def small_info(**changes) -> CameraInfo:
    info = camera_info(SMALL, HEADER)
    for k, v in changes.items():
        setattr(info, k, v)
    return info


def assert_points(scene, expected):
    """Points equal the hand-worked ones (1e-12 m: float64 arithmetic), NaN where expected."""
    got = scene.points.reshape(expected.shape)
    assert np.array_equal(np.isnan(got), np.isnan(expected))
    np.testing.assert_allclose(got[~np.isnan(got)], expected[~np.isnan(expected)],
                               rtol=0, atol=1e-12)


@pytest.mark.parametrize("bigendian", [False, True])
def test_16uc1_millimetres_are_back_projected_through_the_pinhole(bigendian):
    scene = depth_to_scene(pack_image(MM, "16UC1", bigendian=bigendian), small_info())
    assert scene.points.shape == (6, 3) and scene.points.dtype == np.float64
    assert scene.organized_shape == (2, 3)
    assert scene.header.frame_id == "depth_optical"
    assert (scene.header.stamp.sec, scene.header.stamp.nanosec) == (7, 250)
    assert_points(scene, EXPECTED)


@pytest.mark.parametrize("bigendian", [False, True])
def test_32fc1_metres_with_every_kind_of_missing_return(bigendian):
    rows = [[1.0, math.nan, 2.0], [1.25, 3.0, 1.5]]
    assert_points(depth_to_scene(pack_image(rows, "32FC1", bigendian=bigendian), small_info()),
                  EXPECTED)
    for missing in (0.0, math.inf, -math.inf, -1.0):
        rows[0][1] = missing
        got = depth_to_metres(pack_image(rows, "32FC1", bigendian=bigendian))
        assert np.isnan(got[0, 1]), missing
        assert np.isfinite(np.delete(got.ravel(), 1)).all()


@pytest.mark.parametrize("encoding, rows", [("16UC1", MM),
                                            ("32FC1", [[1.0, 0.0, 2.0], [1.25, 3.0, 1.5]])])
def test_row_padding_is_skipped(encoding, rows):
    padded = pack_image(rows, encoding, step=3 * 4 + 6)  # 6 garbage bytes after each row
    assert_points(depth_to_scene(padded, small_info()), EXPECTED)


def test_the_callers_message_is_not_modified_and_results_do_not_share_its_memory():
    msg = pack_image(MM, "16UC1", bigendian=True)
    before = bytes(msg.data)
    scene = depth_to_scene(msg, small_info())
    scene.points[:] = 0.0
    assert bytes(msg.data) == before
    assert msg.is_bigendian == 1


def test_duck_typed_message_with_numpy_data_as_rosbags_gives_it():
    msg = pack_image(MM, "16UC1")
    duck = SimpleNamespace(header=HEADER, height=2, width=3, encoding="16UC1",
                           is_bigendian=0, step=6, data=np.frombuffer(bytes(msg.data), np.uint8))
    assert_points(depth_to_scene(duck, small_info()), EXPECTED)


@pytest.mark.parametrize("encoding", ["rgb8", "mono16", "16SC1", "32FC3", ""])
def test_unknown_encoding_is_a_typed_error_naming_the_allowed_ones(encoding):
    msg = pack_image(MM, "16UC1")
    msg.encoding = encoding
    with pytest.raises(DepthImageError, match=rf"encoding '{encoding}' is not supported; "
                                               r"use one of: 16UC1, 32FC1"):
        depth_to_scene(msg, small_info())


def test_inconsistent_image_layout_is_a_typed_error():
    short_step = pack_image(MM, "16UC1")
    short_step.step = 5
    short_step.data = array.array("B", bytes(10))
    with pytest.raises(DepthImageError, match=r"step 5 is shorter than a row of 3 16UC1 "
                                               r"pixels \(6 bytes\)"):
        depth_to_metres(short_step)
    truncated = pack_image(MM, "16UC1")
    truncated.data = truncated.data[:-1]
    with pytest.raises(DepthImageError, match=r"has 11 bytes, expected step\*height = 6\*2"):
        depth_to_metres(truncated)


@pytest.mark.parametrize("width, height", [(4, 2), (3, 3), (640, 480)])
def test_image_and_camera_info_of_different_sizes_are_refused(width, height):
    info = camera_info(SMALL._replace(width=width, height=height), HEADER)
    with pytest.raises(DepthImageError, match=rf"depth image is 3 x 2 but its CameraInfo is "
                                               rf"{width} x {height}"):
        depth_to_scene(pack_image(MM, "16UC1"), info)
    with pytest.raises(DepthImageError, match="same size"):
        depth_to_xyz(np.ones((2, 3)), camera_model(info))


def test_intrinsics_come_from_p_when_set_else_from_k():
    info = small_info()
    assert camera_model(info) == SMALL
    # A rectified image's P differs from the raw K: P wins, as in image_geometry.
    info.k = [999.0, 0, 9.0, 0, 999.0, 9.0, 0, 0, 1]
    assert camera_model(info) == SMALL
    info = small_info(p=[0.0] * 12)
    info.k = [250.0, 0, 2.0, 0, 200.0, 1.0, 0, 0, 1]
    assert camera_model(info) == CameraModel(250.0, 200.0, 2.0, 1.0, 3, 2)
    # Hand-worked: pixel (v=1, u=0) at 1.25 m with fx=250, cx=2, fy=200, cy=1.
    point = depth_to_scene(pack_image(MM, "16UC1"), info).points[3]
    np.testing.assert_allclose(point, [-2 * 1.25 / 250, 0.0, 1.25], rtol=0, atol=1e-12)


@pytest.mark.parametrize("changes, match", [
    ({"p": [0.0] * 12, "k": [0.0] * 9}, r"CameraInfo K has fx=0.0.*must be finite and > 0"),
    ({"p": [-5.0, 0, 1, 0, 0, 400, 0.5, 0, 0, 0, 1, 0]}, r"CameraInfo P has fx=-5.0"),
    ({"p": [500.0, 0, math.nan, 0, 0, 400, 0.5, 0, 0, 0, 1, 0]}, r"cx=nan"),
    ({"width": 0}, r"size 0 x 2"),
    ({"binning_x": 2}, r"binning \(2, 0\)"),
    ({"roi": RegionOfInterest(x_offset=1, y_offset=0, height=1, width=2)},
     r"region of interest \(1, 0, 2 x 1\)"),
])
def test_unusable_camera_info_is_a_typed_error(changes, match):
    with pytest.raises(DepthImageError, match=match):
        camera_model(small_info(**changes))


def test_roi_of_the_whole_image_is_accepted():
    info = small_info(roi=RegionOfInterest(x_offset=0, y_offset=0, height=2, width=3))
    assert camera_model(info) == SMALL


def test_16uc1_builder_rounds_to_whole_millimetres_and_marks_no_return_as_zero():
    depth = np.array([[1.0004, 1.0006, math.nan], [0.0, -2.0, 70.0]])
    msg = depth_image(depth, HEADER, encoding="16UC1")
    assert (msg.encoding, msg.step, msg.is_bigendian) == ("16UC1", 6, 0)
    assert struct.unpack("<6H", bytes(msg.data)) == (1000, 1001, 0, 0, 0, 0)  # 70 m > 65.535
    got = depth_to_metres(msg, dtype=np.float64)
    np.testing.assert_array_equal(got, [[1.0, 1.001, math.nan], [math.nan] * 3])


def test_32fc1_builder_keeps_float32_metres():
    depth = np.array([[1.0004, math.inf], [0.0, 2.5]])
    msg = depth_image(depth, HEADER, encoding="32FC1")
    assert (msg.step, msg.width, msg.height) == (8, 2, 1 + 1)
    got = depth_to_metres(msg, dtype=np.float64)
    np.testing.assert_array_equal(got, [[np.float32(1.0004), math.nan], [math.nan, 2.5]])
    with pytest.raises(ValueError, match="encoding must be one of 16UC1, 32FC1"):
        depth_image(depth, HEADER, encoding="mono8")


@pytest.mark.parametrize("encoding, atol", [
    # 32FC1: z in float32 (relative 2^-24, < 0.1 um at 1 m); x, y follow z.
    ("32FC1", 2e-7),
    # 16UC1: z rounded to the millimetre (0.5 mm), x and y scale with z by |u - cx| / fx
    # <= 0.6 at the image border of these scenes: 0.5 mm in all.
    ("16UC1", 5e-4 + 1e-9),
])
def test_rendered_scene_through_a_depth_image_gives_the_ray_cast_points(encoding, atol):
    """The ray caster's pixel convention and the back-projection agree."""
    scene = render_scene("scene2")
    camera = CameraModel(**scene.intrinsics)
    organized = scene.organized
    msg = depth_image(organized[..., 2], HEADER, encoding=encoding)
    got = depth_to_scene(msg, camera_info(camera, HEADER))
    assert got.organized_shape == organized.shape[:2]
    flat = organized.reshape(-1, 3)
    assert np.array_equal(np.isnan(got.points).any(axis=1), np.isnan(flat).any(axis=1))
    seen = ~np.isnan(flat[:, 2])
    err = np.abs(got.points[seen] - flat[seen])
    assert err.max() <= atol
    if encoding == "16UC1":  # quantisation really happened (the bound is not vacuous)
        assert err[:, 2].max() > 0.4e-3


# --------------------------------------------------------------------------- fuzzing
SPOILS = (None, None, "encoding", "step", "bytes", "size", "intrinsics")


@st.composite
def _random_pair(draw):
    """Draw a depth image (any padding, byte order, content) and its CameraInfo.

    At most one thing is spoiled (``SPOILS``): the pair and what was spoiled.
    """
    spoil = draw(st.sampled_from(SPOILS))
    height, width = draw(st.integers(1, 5)), draw(st.integers(1, 5))
    encoding = draw(st.sampled_from(["16UC1", "32FC1"]))
    size = 4 if encoding == "32FC1" else 2
    step = width * size + draw(st.integers(0, 7))  # row padding
    if spoil == "step":
        step = draw(st.integers(0, width * size - 1))
    n_bytes = step * height
    if spoil == "bytes":
        n_bytes = draw(st.integers(0, 64).filter(lambda n: n != step * height))
    data = draw(st.binary(min_size=n_bytes, max_size=n_bytes))
    image = Image(header=HEADER, height=height, width=width, encoding=encoding,
                  is_bigendian=draw(st.integers(0, 1)), step=step, data=array.array("B", data))
    if spoil == "encoding":
        image.encoding = draw(st.sampled_from(["mono16", "8UC1", "", "16uc1", "32FC3"]))
    model = CameraModel(draw(st.floats(1.0, 1e4)), draw(st.floats(1.0, 1e4)),
                        draw(st.floats(-10.0, 10.0)), draw(st.floats(-10.0, 10.0)), width, height)
    if spoil == "size":
        model = model._replace(width=width + draw(st.integers(1, 3)))
    info = camera_info(model, HEADER)
    if spoil == "intrinsics":
        p = list(info.p)
        p[draw(st.sampled_from([0, 2, 5, 6]))] = draw(st.sampled_from([math.nan, math.inf]))
        info.p = p
    return image, info, spoil


@settings(max_examples=300, deadline=None)
@given(_random_pair())
def test_any_image_gives_a_scene_or_a_typed_error(drawn):
    """Whatever the bytes hold: valid layouts give points, spoiled ones a typed error."""
    image, info, spoil = drawn
    if spoil is not None:
        with pytest.raises(DepthImageError):
            depth_to_scene(image, info)
        return
    scene = depth_to_scene(image, info)
    h, w = int(image.height), int(image.width)
    assert scene.points.shape == (h * w, 3)
    missing = np.isnan(scene.points)
    assert np.array_equal(missing.any(axis=1), missing.all(axis=1))  # whole rows only
    assert np.isfinite(scene.points[~missing.any(axis=1)]).all()
    assert (scene.points[~missing.any(axis=1), 2] > 0).all()
