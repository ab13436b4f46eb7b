"""Tests of msg_adapters.pointcloud2: PointCloud2 <-> numpy, without rclpy.init.

Messages are built (and ``xyz_to_cloud`` output is decoded) with ``struct``, point by point,
field by field: a reference independent of the numpy dtype machinery under test.
"""

import os

os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")

import array
import re
import struct
import warnings
from types import SimpleNamespace
from typing import NamedTuple

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from sensor_msgs.msg import PointCloud2, PointField
from std_msgs.msg import Header

from msg_adapters.pointcloud2 import (
    PointCloud2Error,
    cloud_to_fields,
    cloud_to_xyz,
    cloud_to_xyz_and_mask,
    pack_rgb,
    structured_view,
    unpack_rgb,
    xyz_to_cloud,
)

F32, F64 = PointField.FLOAT32, PointField.FLOAT64
# datatype -> (struct code, numpy dtype)
TYPES = {
    PointField.INT8: ("b", np.int8),
    PointField.UINT8: ("B", np.uint8),
    PointField.INT16: ("h", np.int16),
    PointField.UINT16: ("H", np.uint16),
    PointField.INT32: ("i", np.int32),
    PointField.UINT32: ("I", np.uint32),
    F32: ("f", np.float32),
    F64: ("d", np.float64),
}
PAD = 0xA5  # filler for padding bytes: read by mistake, it shows up as garbage


class Spec(NamedTuple):
    name: str
    offset: int
    datatype: int
    count: int = 1


def make_cloud(
    specs,
    columns,
    *,
    height,
    width,
    point_step=None,
    row_step=None,
    bigendian=False,
    frame_id="sensor",
):
    """PointCloud2 from ``columns[name]`` ((H*W,) or (H*W, count) arrays), packed by struct.

    Padding bytes, and fields named ``'_'`` (padding by PCL's convention), are filled with PAD.
    """
    if point_step is None:
        point_step = max(
            (s.offset + struct.calcsize("<" + TYPES[s.datatype][0]) * s.count for s in specs),
            default=0,
        )
    if row_step is None:
        row_step = point_step * width
    endian = ">" if bigendian else "<"
    buf = bytearray([PAD]) * (row_step * height)
    for spec in specs if height * width else ():
        if spec.name == "_":
            continue
        fmt = endian + TYPES[spec.datatype][0] * spec.count
        values = np.asarray(columns[spec.name]).reshape(height * width, spec.count)
        for index, point in enumerate(values.tolist()):
            row, col = divmod(index, width)
            struct.pack_into(fmt, buf, row * row_step + col * point_step + spec.offset, *point)
    msg = PointCloud2(
        header=Header(frame_id=frame_id),
        height=height,
        width=width,
        fields=[
            PointField(name=s.name, offset=s.offset, datatype=s.datatype, count=s.count)
            for s in specs
        ],
        is_bigendian=bigendian,
        point_step=point_step,
        row_step=row_step,
        is_dense=False,
    )
    msg.data = array.array("B", bytes(buf))
    return msg


def decode(msg, name):
    """One field of ``msg`` as a list of per-point tuples, read with struct."""
    (field,) = [f for f in msg.fields if f.name == name]
    fmt = (">" if msg.is_bigendian else "<") + TYPES[field.datatype][0] * field.count
    data = bytes(msg.data)
    return [
        struct.unpack_from(fmt, data, row * msg.row_step + col * msg.point_step + field.offset)
        for row in range(msg.height)
        for col in range(msg.width)
    ]


def snapshot(msg):
    fields = [(f.name, f.offset, f.datatype, f.count) for f in msg.fields]
    return (
        bytes(msg.data),
        fields,
        msg.height,
        msg.width,
        msg.point_step,
        msg.row_step,
        msg.is_bigendian,
    )


def assert_same_floats(actual, expected):
    """Equal values, NaN where NaN, and the same sign of zero."""
    actual, expected = np.asarray(actual), np.asarray(expected)
    assert actual.shape == expected.shape
    assert np.array_equal(actual, expected, equal_nan=True)
    finite = ~np.isnan(expected)
    assert np.array_equal(np.signbit(actual[finite]), np.signbit(expected[finite]))


def xyz_rgb_specs(point_step_layout):
    """X y z FLOAT32 + rgb, PCL's padded 32-byte layout or the packed 16-byte one."""
    rgb_offset = 16 if point_step_layout == 32 else 12
    return [Spec("x", 0, F32), Spec("y", 4, F32), Spec("z", 8, F32), Spec("rgb", rgb_offset, F32)]


def random_xyz(rng, n):
    return rng.uniform(-20.0, 20.0, size=(n, 3)).astype(np.float32)


def rgb_as_float_bits(packed):
    return np.asarray(packed, dtype=np.uint32).view(np.float32)


# --------------------------------------------------------------------------------------
# Reading: layouts


@pytest.mark.parametrize("bigendian", [False, True], ids=["little", "big"])
@pytest.mark.parametrize("point_step", [16, 32])
def test_xyz_rgb_layouts_read_exactly(point_step, bigendian):
    rng = np.random.default_rng(1)
    xyz = random_xyz(rng, 50)
    colours = rng.integers(0, 256, size=(50, 3), dtype=np.uint8)
    packed = pack_rgb(colours)
    msg = make_cloud(
        xyz_rgb_specs(point_step),
        {"x": xyz[:, 0], "y": xyz[:, 1], "z": xyz[:, 2], "rgb": rgb_as_float_bits(packed)},
        height=1,
        width=50,
        point_step=point_step,
        bigendian=bigendian,
    )
    before = snapshot(msg)

    points = cloud_to_xyz(msg)
    extras = cloud_to_fields(msg, ["rgb"])

    assert points.dtype == np.float64 and points.shape == (50, 3) and points.flags.c_contiguous
    assert_same_floats(points, xyz.astype(np.float64))
    assert extras["rgb"].dtype == np.uint32
    assert np.array_equal(extras["rgb"], packed)
    assert np.array_equal(unpack_rgb(extras["rgb"]), colours)
    assert snapshot(msg) == before


def test_float64_xyz_keeps_full_precision():
    rng = np.random.default_rng(2)
    xyz = rng.normal(size=(30, 3)) * 1e3  # not representable in float32
    specs = [Spec("intensity", 0, F32), Spec("x", 8, F64), Spec("y", 16, F64), Spec("z", 24, F64)]
    msg = make_cloud(
        specs,
        {"intensity": np.zeros(30, np.float32), "x": xyz[:, 0], "y": xyz[:, 1], "z": xyz[:, 2]},
        height=1,
        width=30,
        point_step=40,
    )
    assert np.array_equal(cloud_to_xyz(msg), xyz)
    assert np.array_equal(cloud_to_xyz(msg, dtype=np.float32), xyz.astype(np.float32))


def test_coordinates_beyond_float32_become_infinite_without_numeric_warnings():
    # A malformed or fuzzed cloud's 1e300 m: stored as +-inf in FLOAT32 (the cloud is then
    # not dense), read back as +-inf into a float32 array; no RuntimeWarning either way.
    xyz = np.array([[1e300, -1e300, 0.5], [1.0, 2.0, 3.0]])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        msg = xyz_to_cloud(xyz, Header())
        back = cloud_to_xyz(msg, skip_nans=False)
    assert not msg.is_dense
    assert back[0, 0] == np.inf and back[0, 1] == -np.inf and back[0, 2] == np.float32(0.5)
    assert np.array_equal(back[1], [1.0, 2.0, 3.0])
    specs = [Spec("x", 0, F64), Spec("y", 8, F64), Spec("z", 16, F64)]
    wide = make_cloud(specs, {"x": xyz[:, 0], "y": xyz[:, 1], "z": xyz[:, 2]}, height=1,
                      width=2, point_step=24)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        narrow = cloud_to_xyz(wide, dtype=np.float32, keep_organized=True, skip_nans=False)
    assert narrow[0, 0, 0] == np.inf and narrow[0, 0, 1] == -np.inf
    assert np.array_equal(cloud_to_xyz(wide, skip_nans=False), xyz)


def test_mixed_float32_and_float64_xyz_big_endian():
    xyz = np.array([[1.5, -2.25, 3.125], [0.0, 1e-3, -7.0]])
    specs = [Spec("z", 0, F32), Spec("x", 4, F64), Spec("y", 12, F32)]
    msg = make_cloud(
        specs, {"x": xyz[:, 0], "y": xyz[:, 1], "z": xyz[:, 2]}, height=1, width=2, bigendian=True
    )
    assert_same_floats(cloud_to_xyz(msg), xyz.astype(np.float32).astype(np.float64))


def test_row_step_padding_is_skipped():
    rng = np.random.default_rng(3)
    height, width = 4, 5
    xyz = random_xyz(rng, height * width)
    specs = [Spec("x", 0, F32), Spec("y", 4, F32), Spec("z", 8, F32)]
    msg = make_cloud(
        specs,
        {"x": xyz[:, 0], "y": xyz[:, 1], "z": xyz[:, 2]},
        height=height,
        width=width,
        point_step=16,
        row_step=16 * width + 12,  # 12 garbage bytes after every row
    )
    assert_same_floats(cloud_to_xyz(msg), xyz)
    assert_same_floats(cloud_to_xyz(msg, keep_organized=True), xyz.reshape(height, width, 3))


def organized_with_nans():
    """Build a 3x4 organized cloud whose points 1, 6 (NaN), 9, 11 (-Inf, +Inf) are invalid."""
    rng = np.random.default_rng(4)
    xyz = random_xyz(rng, 12)
    xyz[1, 0] = np.nan
    xyz[6, :] = np.nan
    xyz[9, 0] = -np.inf
    xyz[11, 2] = np.inf
    labels = np.arange(100, 112, dtype=np.int32)
    specs = [
        Spec("x", 0, F32),
        Spec("y", 4, F32),
        Spec("z", 8, F32),
        Spec("label", 12, PointField.INT32),
    ]
    msg = make_cloud(
        specs, {"x": xyz[:, 0], "y": xyz[:, 1], "z": xyz[:, 2], "label": labels}, height=3, width=4
    )
    return msg, xyz, labels


def test_organized_nans_kept():
    msg, xyz, labels = organized_with_nans()
    grid = cloud_to_xyz(msg, keep_organized=True)
    assert grid.shape == (3, 4, 3)
    assert_same_floats(grid, xyz.reshape(3, 4, 3))
    assert_same_floats(cloud_to_xyz(msg, skip_nans=False), xyz)
    assert np.array_equal(
        cloud_to_fields(msg, ["label"], keep_organized=True)["label"], labels.reshape(3, 4)
    )


def test_organized_nans_dropped_and_mask_maps_back():
    msg, xyz, labels = organized_with_nans()
    points, mask = cloud_to_xyz_and_mask(msg)

    assert mask.shape == (12,) and mask.dtype == np.bool_
    assert np.array_equal(np.flatnonzero(~mask), [1, 6, 9, 11])
    assert points.shape == (8, 3)
    assert_same_floats(points, xyz[mask])
    assert np.array_equal(cloud_to_xyz(msg), points)
    aligned = cloud_to_fields(msg, ["label"], mask=mask)["label"]
    assert np.array_equal(aligned, labels[mask])
    grid_mask = cloud_to_fields(msg, "label", mask=mask.reshape(3, 4))["label"]
    assert np.array_equal(grid_mask, aligned)


def test_skip_nans_false_mask_is_all_true():
    msg, xyz, _ = organized_with_nans()
    points, mask = cloud_to_xyz_and_mask(msg, skip_nans=False)
    assert mask.all() and mask.shape == (12,)
    assert_same_floats(points, xyz)


@pytest.mark.parametrize("bigendian", [False, True], ids=["little", "big"])
def test_count_greater_than_one_fields(bigendian):
    rng = np.random.default_rng(5)
    n = 7
    xyz = random_xyz(rng, n)
    normals = rng.normal(size=(n, 3)).astype(np.float32)
    hist = rng.integers(-30000, 30000, size=(n, 5)).astype(np.int16)
    specs = [
        Spec("normal", 0, F32, 3),
        Spec("x", 12, F32),
        Spec("hist", 16, PointField.INT16, 5),
        Spec("y", 26, F32),  # unaligned offsets are legal
        Spec("z", 30, F32),
    ]
    msg = make_cloud(
        specs,
        {"normal": normals, "x": xyz[:, 0], "hist": hist, "y": xyz[:, 1], "z": xyz[:, 2]},
        height=1,
        width=n,
        point_step=36,
        bigendian=bigendian,
    )
    assert_same_floats(cloud_to_xyz(msg), xyz)
    out = cloud_to_fields(msg, ["normal", "hist"])
    assert out["normal"].shape == (n, 3) and out["normal"].dtype == np.float32
    assert np.array_equal(out["normal"], normals)
    assert out["hist"].shape == (n, 5) and out["hist"].dtype == np.int16
    assert out["hist"].dtype.isnative
    assert np.array_equal(out["hist"], hist)
    grid = cloud_to_fields(msg, ["hist"], keep_organized=True)["hist"]
    assert grid.shape == (1, n, 5)


def test_rgb_declared_uint32_and_rgba_are_uint32_too():
    packed = np.array([0x00FF0000, 0x0000FF00, 0x800000FF], dtype=np.uint32)
    specs = [
        Spec("x", 0, F32),
        Spec("y", 4, F32),
        Spec("z", 8, F32),
        Spec("rgba", 12, PointField.UINT32),
    ]
    msg = make_cloud(
        specs, {"x": [0, 1, 2], "y": [0, 0, 0], "z": [1, 1, 1], "rgba": packed}, height=1, width=3
    )
    rgba = cloud_to_fields(msg, ["rgba"])["rgba"]
    assert rgba.dtype == np.uint32
    assert unpack_rgb(rgba, alpha=True).tolist() == [
        [255, 0, 0, 0],
        [0, 255, 0, 0],
        [0, 0, 255, 128],
    ]


def test_padding_fields_named_underscore_may_repeat_and_are_not_read():
    specs = [
        Spec("x", 0, F32),
        Spec("_", 4, PointField.UINT8, 4),
        Spec("y", 8, F32),
        Spec("_", 12, F32),
        Spec("z", 16, F32),
    ]
    msg = make_cloud(specs, {"x": [1], "y": [2], "z": [3]}, height=1, width=1)
    assert cloud_to_xyz(msg).tolist() == [[1.0, 2.0, 3.0]]
    assert structured_view(msg).dtype.names == ("x", "y", "z")
    with pytest.raises(PointCloud2Error, match="no field '_'"):
        cloud_to_fields(msg, ["_"])


# --------------------------------------------------------------------------------------
# Reading: the caller's message is never touched, results never alias it


@pytest.mark.parametrize("bigendian", [False, True], ids=["little", "big"])
def test_reading_neither_modifies_nor_aliases_the_message(bigendian):
    msg, _, _ = organized_with_nans()
    if bigendian:  # re-pack the same cloud big-endian
        view = structured_view(msg)
        specs = [Spec(f.name, f.offset, f.datatype, f.count) for f in msg.fields]
        columns = {name: np.array(view[name]).reshape(-1) for name in view.dtype.names}
        msg = make_cloud(specs, columns, height=3, width=4, bigendian=True)
    before = snapshot(msg)
    data_object = msg.data

    results = [
        cloud_to_xyz(msg),
        cloud_to_xyz(msg, keep_organized=True),
        cloud_to_xyz(msg, skip_nans=False, dtype=np.float32),
        *cloud_to_xyz_and_mask(msg),
        *cloud_to_fields(msg, ["label", "x"]).values(),
        *cloud_to_fields(msg, ["x"], keep_organized=True).values(),
    ]
    backing = np.frombuffer(msg.data, dtype=np.uint8)
    for result in results:
        assert not np.shares_memory(result, backing)
        assert result.flags.writeable
        result[...] = 0  # scribbling on a result must not reach the message
    del backing
    assert snapshot(msg) == before
    assert msg.data is data_object
    msg.data.append(0)  # no buffer export left behind: the array.array is still resizable


def test_structured_view_is_zero_copy_and_read_only():
    msg, xyz, _ = organized_with_nans()
    view = structured_view(msg)
    assert view.shape == (3, 4)
    assert np.shares_memory(view, np.frombuffer(msg.data, dtype=np.uint8))
    assert not view.flags.writeable
    with pytest.raises(ValueError, match="read-only"):
        view["x"][0, 0] = 1.0
    assert_same_floats(view["y"].reshape(-1), xyz[:, 1])


# --------------------------------------------------------------------------------------
# Reading: other message implementations


def test_duck_typed_message_with_ndarray_or_list_data():
    msg = xyz_to_cloud(np.array([[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]]), Header())
    attrs = {
        k: getattr(msg, k)
        for k in ("height", "width", "fields", "is_bigendian", "point_step", "row_step")
    }
    as_ndarray = SimpleNamespace(data=np.frombuffer(bytes(msg.data), dtype=np.uint8), **attrs)
    as_list = SimpleNamespace(data=list(msg.data), **attrs)
    as_strided = SimpleNamespace(
        data=np.repeat(np.frombuffer(bytes(msg.data), np.uint8), 2)[::2], **attrs
    )
    for duck in (as_ndarray, as_list, as_strided):
        assert cloud_to_xyz(duck).tolist() == [[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]]


def test_cdr_round_trip_through_rclpy_and_rosbags():
    rclpy_serialization = pytest.importorskip("rclpy.serialization")
    typesys = pytest.importorskip("rosbags.typesys")
    rng = np.random.default_rng(6)
    xyz = random_xyz(rng, 40)
    packed = pack_rgb(rng.integers(0, 256, size=(40, 3), dtype=np.uint8))
    msg = xyz_to_cloud(xyz, Header(frame_id="lidar"), fields={"rgb": packed})
    raw = rclpy_serialization.serialize_message(msg)

    back = rclpy_serialization.deserialize_message(raw, PointCloud2)
    from_bag = typesys.get_typestore(typesys.Stores.ROS2_JAZZY).deserialize_cdr(
        raw, "sensor_msgs/msg/PointCloud2"
    )
    for received in (back, from_bag):
        assert_same_floats(cloud_to_xyz(received, dtype=np.float32), xyz)
        assert np.array_equal(cloud_to_fields(received, ["rgb"])["rgb"], packed)


# --------------------------------------------------------------------------------------
# Reading: empty clouds


@pytest.mark.parametrize(
    "msg",
    [
        PointCloud2(),  # default-constructed: no fields at all
        make_cloud(xyz_rgb_specs(32), {}, height=1, width=0, point_step=32),
        make_cloud(xyz_rgb_specs(16), {}, height=0, width=5, point_step=16),
    ],
    ids=["default", "width0", "height0"],
)
def test_empty_cloud_gives_empty_arrays(msg):
    points, mask = cloud_to_xyz_and_mask(msg)
    assert points.shape == (0, 3) and points.dtype == np.float64
    assert mask.shape == (0,)
    assert cloud_to_xyz(msg).shape == (0, 3)
    assert cloud_to_xyz(msg, keep_organized=True).shape == (msg.height, msg.width, 3)


def test_empty_cloud_fields_keep_their_dtype():
    msg = make_cloud(xyz_rgb_specs(16), {}, height=1, width=0, point_step=16)
    rgb = cloud_to_fields(msg, ["rgb"])["rgb"]
    assert rgb.shape == (0,) and rgb.dtype == np.uint32


# --------------------------------------------------------------------------------------
# Reading: malformed messages


def valid_cloud(**overrides):
    """Build a valid 2x3 x/y/z/rgb cloud; ``overrides`` replace message attributes."""
    msg = make_cloud(
        xyz_rgb_specs(16),
        {"x": np.arange(6), "y": np.ones(6), "z": np.zeros(6), "rgb": np.zeros(6)},
        height=2,
        width=3,
        point_step=16,
    )
    for key, value in overrides.items():
        setattr(msg, key, value)
    return msg


def fields_with(**changes):
    """Return the x/y/z/rgb field table with one field's attributes changed, by name."""
    fields = []
    for spec in xyz_rgb_specs(16):
        attrs = spec._asdict()
        attrs.update(changes.get(spec.name, {}))
        fields.append(PointField(**attrs))
    return fields


MALFORMED = {
    "missing z": (
        dict(fields=fields_with()[:2] + fields_with()[3:]),
        r"no field 'z' \(fields: 'x', 'y', 'rgb'\); x, y and z are required",
    ),
    "datatype 0": (
        dict(fields=fields_with(rgb={"datatype": 0})),
        r"'rgb' has datatype 0; allowed datatypes are 1 \(INT8\)",
    ),
    "datatype 9": (
        dict(fields=fields_with(y={"datatype": 9})),
        r"'y' has datatype 9; allowed .* 8 \(FLOAT64\)",
    ),
    "x as INT32": (
        dict(fields=fields_with(x={"datatype": PointField.INT32})),
        "'x' is INT32; x, y and z must be FLOAT32 or FLOAT64 with count 1",
    ),
    "z with count 3": (
        dict(fields=fields_with(z={"count": 3, "offset": 4})),
        "'z' is FLOAT32 x 3; x, y and z must",
    ),
    "count 0": (
        dict(fields=fields_with(rgb={"count": 0})),
        "'rgb' has count 0; count must be >= 1",
    ),
    "field past point_step": (
        dict(fields=fields_with(rgb={"offset": 14})),
        r"'rgb' \(FLOAT32 x 1\) occupies bytes \[14, 18\) of each point but point_step is 16",
    ),
    "count > 1 past point_step": (
        dict(fields=fields_with(rgb={"count": 2})),
        r"'rgb' \(FLOAT32 x 2\) occupies bytes \[12, 20\) of each point but point_step is 16",
    ),
    "duplicate name": (dict(fields=fields_with(rgb={"name": "x"})), "'x' appears more than once"),
    "empty name": (dict(fields=fields_with(rgb={"name": ""})), "PointField #3 has an empty name"),
    "rows too short": (
        dict(row_step=40),
        r"point_step\*width = 16\*3 = 48 bytes exceeds row_step = 40",
    ),
    "truncated data": (
        dict(data=array.array("B", bytes(95))),
        re.escape("PointCloud2 data has 95 bytes, expected row_step*height = 48*2 = 96"),
    ),
    "data too long": (
        dict(data=array.array("B", bytes(100))),
        re.escape("data has 100 bytes, expected row_step*height = 48*2 = 96"),
    ),
    "height without data": (
        dict(height=3),
        re.escape("data has 96 bytes, expected row_step*height = 48*3 = 144"),
    ),
}


@pytest.mark.parametrize("overrides, match", MALFORMED.values(), ids=MALFORMED.keys())
def test_malformed_cloud_raises_with_explanation(overrides, match):
    msg = valid_cloud(**overrides)
    before = snapshot(msg)
    readers = [
        lambda: cloud_to_xyz(msg),
        lambda: cloud_to_xyz(msg, keep_organized=True),
        lambda: cloud_to_xyz_and_mask(msg),
    ]
    if "x, y and z" not in match:  # xyz-only problems do not concern other fields
        readers += [lambda: cloud_to_fields(msg, []), lambda: structured_view(msg)]
    for read in readers:
        with pytest.raises(PointCloud2Error, match=match):
            read()
    assert snapshot(msg) == before


def test_point_cloud2_error_is_a_value_error():
    assert issubclass(PointCloud2Error, ValueError)


def test_overlapping_fields_within_point_step_are_legal():
    # rgb and rgba overlapping (both at 12) is seen in the wild and is not an error
    fields = fields_with() + [
        PointField(name="rgba", offset=12, datatype=PointField.UINT32, count=1)
    ]
    msg = valid_cloud(fields=fields)
    out = cloud_to_fields(msg, ["rgb", "rgba"])
    assert np.array_equal(out["rgb"], out["rgba"])


def test_bad_arguments_raise_value_error():
    msg, _, _ = organized_with_nans()
    with pytest.raises(ValueError, match="dtype must be a floating type"):
        cloud_to_xyz(msg, dtype=np.int32)
    with pytest.raises(
        ValueError, match=re.escape("mask must be a bool array of shape (12,) or (3, 4)")
    ):
        cloud_to_fields(msg, ["label"], mask=np.ones(11, dtype=bool))
    with pytest.raises(ValueError, match="mask must be a bool array"):
        cloud_to_fields(msg, ["label"], mask=np.arange(12))
    with pytest.raises(ValueError, match="cannot be combined"):
        cloud_to_fields(msg, ["label"], mask=np.ones(12, dtype=bool), keep_organized=True)
    with pytest.raises(
        PointCloud2Error, match=r"no field 'rgb' \(fields: 'x', 'y', 'z', 'label'\)"
    ):
        cloud_to_fields(msg, ["rgb"])


# --------------------------------------------------------------------------------------
# Writing


def test_xyz_to_cloud_layout_decoded_independently():
    rng = np.random.default_rng(7)
    xyz = rng.normal(size=(25, 3))  # float64 in, float32 stored
    colours = rng.integers(0, 256, size=(25, 3), dtype=np.uint8)
    ids = rng.integers(-5, 1000, size=25)  # int64 -> INT32
    header = Header(frame_id="camera_optical")
    header.stamp.sec, header.stamp.nanosec = 1700000000, 123456789

    msg = xyz_to_cloud(xyz, header, fields={"rgb": pack_rgb(colours), "object_id": ids})

    assert isinstance(msg.data, array.array) and msg.data.typecode == "B"
    assert (
        msg.header == header and msg.header is not header and msg.header.stamp is not header.stamp
    )
    assert [(f.name, f.offset, f.datatype, f.count) for f in msg.fields] == [
        ("x", 0, F32, 1),
        ("y", 4, F32, 1),
        ("z", 8, F32, 1),
        ("rgb", 12, F32, 1),  # FLOAT32 so that RViz shows colours
        ("object_id", 16, PointField.INT32, 1),
    ]
    assert (msg.height, msg.width, msg.point_step, msg.row_step) == (1, 25, 20, 500)
    assert not msg.is_bigendian and msg.is_dense
    assert len(msg.data) == 500
    stored = np.array([decode(msg, name) for name in "xyz"])[:, :, 0].T
    assert np.array_equal(stored, xyz.astype(np.float32))
    rgb_bits = np.array(decode(msg, "rgb"), dtype=np.float32).view(np.uint32).ravel()
    assert np.array_equal(unpack_rgb(rgb_bits), colours)
    assert np.array_equal(np.ravel(decode(msg, "object_id")), ids)


def test_xyz_to_cloud_rgb_follows_pcl_packing():
    msg = xyz_to_cloud(
        np.zeros((3, 3)),
        Header(),
        fields={"rgb": np.array([[255, 0, 0], [0, 128, 0], [1, 2, 3]], np.uint8)},
    )
    packed = cloud_to_fields(msg, ["rgb"])["rgb"]
    assert packed.tolist() == [0x00FF0000, 0x00008000, 0x00010203]
    from_float_bits = xyz_to_cloud(
        np.zeros((3, 3)), Header(), fields={"rgb": packed.view(np.float32).astype(">f4")}
    )
    assert np.array_equal(cloud_to_fields(from_float_bits, ["rgb"])["rgb"], packed)
    float_bits = np.array(decode(msg, "rgb"), dtype=np.float32).ravel()
    assert np.array_equal(float_bits.view(np.uint32), packed)


def test_xyz_to_cloud_aligns_fields_and_zeroes_padding():
    fields = {
        "flag": np.array([True, False]),  # bool -> UINT8 at 12
        "intensity": np.array([0.5, 2.0]),  # float64 -> aligned to 16
        "normal": np.ones((2, 3), np.float32),  # count 3 at 24
    }
    msg = xyz_to_cloud(np.zeros((2, 3)), Header(), fields=fields)
    layout = [(f.name, f.offset, f.datatype, f.count) for f in msg.fields][3:]
    assert layout == [
        ("flag", 12, PointField.UINT8, 1),
        ("intensity", 16, F64, 1),
        ("normal", 24, F32, 3),
    ]
    assert msg.point_step == 40  # 36 rounded up to the float64 alignment
    data = bytes(msg.data)
    assert data[13:16] == b"\0\0\0" and data[36:40] == b"\0\0\0\0"
    assert data[40 + 13 : 40 + 16] == b"\0\0\0"
    out = cloud_to_fields(msg, list(fields))
    assert out["flag"].tolist() == [1, 0] and out["intensity"].tolist() == [0.5, 2.0]
    assert np.array_equal(out["normal"], fields["normal"])


def test_xyz_to_cloud_organized_and_is_dense():
    msg, xyz, labels = organized_with_nans()
    grid = xyz.reshape(3, 4, 3)
    for cloud in (
        xyz_to_cloud(grid, Header(), fields={"label": labels.reshape(3, 4)}),
        xyz_to_cloud(xyz, Header(), fields={"label": labels}, organized_shape=(3, 4)),
    ):
        assert (cloud.height, cloud.width, cloud.row_step) == (3, 4, 4 * cloud.point_step)
        assert not cloud.is_dense  # NaN and Inf points
        assert_same_floats(cloud_to_xyz(cloud, keep_organized=True, dtype=np.float32), grid)
        assert np.array_equal(cloud_to_fields(cloud, ["label"])["label"], labels)
    assert xyz_to_cloud(np.ones((4, 3)), Header()).is_dense
    inf_only = np.ones((4, 3))
    inf_only[2, 1] = -np.inf
    assert not xyz_to_cloud(inf_only, Header()).is_dense


def test_xyz_to_cloud_empty():
    msg = xyz_to_cloud(
        np.empty((0, 3)), Header(frame_id="map"), fields={"rgb": np.empty(0, np.uint32)}
    )
    assert (msg.height, msg.width, len(msg.data)) == (1, 0, 0)
    assert msg.is_dense and msg.header.frame_id == "map"
    assert cloud_to_xyz(msg).shape == (0, 3)
    assert cloud_to_fields(msg, ["rgb"])["rgb"].shape == (0,)


@pytest.mark.parametrize(
    "points, kwargs, match",
    [
        (
            np.zeros((4, 2)),
            {},
            re.escape("points must be a real array of shape (N, 3) or (H, W, 3)"),
        ),
        (np.zeros((4, 3), bool), {}, "points must be a real array"),
        (
            np.zeros((4, 3)),
            {"organized_shape": (3, 2)},
            re.escape("organized_shape (3, 2) must have height * width == N = 4"),
        ),
        (np.zeros((2, 2, 3)), {"organized_shape": (1, 4)}, "disagrees with points"),
        (np.zeros((4, 3)), {"fields": {"x": np.zeros(4)}}, "extra field name 'x' is not allowed"),
        (np.zeros((4, 3)), {"fields": {"": np.zeros(4)}}, "extra field name '' is not allowed"),
        (
            np.zeros((4, 3)),
            {"fields": {"label": np.zeros(3)}},
            re.escape("field 'label' must have shape (4,) or (4, count)"),
        ),
        (
            np.zeros((4, 3)),
            {"fields": {"label": np.array([0, 1, 2, 2**40])}},
            "outside int32 range",
        ),
        (
            np.zeros((4, 3)),
            {"fields": {"label": np.zeros(4, complex)}},
            "has dtype complex128; allowed are",
        ),
        (np.zeros((4, 3)), {"fields": {"rgb": np.zeros(4, np.float64)}}, "field 'rgb' must be"),
        (np.zeros((4, 3)), {"fields": {"rgb": np.array([0, 1, 2, -1])}}, "uint32 packed colours"),
    ],
)
def test_xyz_to_cloud_bad_arguments(points, kwargs, match):
    with pytest.raises(ValueError, match=match):
        xyz_to_cloud(points, Header(), **kwargs)


def test_pack_and_unpack_rgb():
    colours = np.array([[255, 0, 0], [0, 255, 0], [0, 0, 255], [18, 52, 86]], dtype=np.uint8)
    packed = pack_rgb(colours)
    assert packed.dtype == np.uint32
    assert packed.tolist() == [0xFF0000, 0x00FF00, 0x0000FF, 0x123456]
    assert np.array_equal(unpack_rgb(packed), colours)
    assert np.array_equal(unpack_rgb(packed.view(np.float32)), colours)  # float-declared rgb
    assert pack_rgb([[1, 2, 3, 4]]).tolist() == [0x04010203]
    assert unpack_rgb(np.array([0x04010203], np.uint32), alpha=True).tolist() == [[1, 2, 3, 4]]
    assert pack_rgb(np.zeros((2, 5, 3), np.uint8)).shape == (2, 5)
    with pytest.raises(ValueError, match=r"\[0, 255\]"):
        pack_rgb([[0, 0, 256]])
    with pytest.raises(ValueError, match=r"astype\(np.uint8\)"):
        pack_rgb(np.full((2, 3), 0.5))
    with pytest.raises(ValueError, match="uint32"):
        unpack_rgb(np.zeros(3, np.float64))


# --------------------------------------------------------------------------------------
# Properties


@st.composite
def random_layouts(draw):
    """Draw field order, offsets, paddings, row padding, byte order and x/y/z types.

    Values are drawn as raw bit patterns (NaN, Inf, subnormals, -0 included).
    """
    xyz_types = {name: draw(st.sampled_from([F32, F64])) for name in "xyz"}
    extras = {
        f"f{i}": (draw(st.sampled_from(sorted(TYPES))), draw(st.integers(1, 3)))
        for i in range(draw(st.integers(0, 3)))
    }
    entries = [(n, t, 1) for n, t in xyz_types.items()] + [
        (n, t, c) for n, (t, c) in extras.items()
    ]
    offset, specs = 0, []
    for name, datatype, count in draw(st.permutations(entries)):
        offset += draw(st.integers(0, 5))  # any padding, unaligned offsets included
        specs.append(Spec(name, offset, datatype, count))
        offset += np.dtype(TYPES[datatype][1]).itemsize * count
    point_step = offset + draw(st.integers(0, 7))
    height, width = draw(st.integers(1, 4)), draw(st.integers(1, 6))
    row_step = point_step * width + draw(st.integers(0, 9))
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    n = height * width
    columns = {}
    for spec in specs:
        dtype = np.dtype(TYPES[spec.datatype][1])
        bits = rng.integers(0, 256, size=(n, spec.count * dtype.itemsize), dtype=np.uint8)
        values = bits.view(dtype)
        if spec.name in "xyz" and draw(st.booleans()):  # mostly finite, a few special values
            values = rng.uniform(-1e3, 1e3, size=values.shape).astype(dtype)
            special = rng.random(values.shape) < 0.2
            values[special] = rng.choice([np.nan, np.inf, -np.inf, -0.0, 0.0], size=special.sum())
        columns[spec.name] = values
    bigendian = draw(st.booleans())
    msg = make_cloud(
        specs,
        columns,
        height=height,
        width=width,
        point_step=point_step,
        row_step=row_step,
        bigendian=bigendian,
    )
    return msg, columns


@settings(max_examples=150, deadline=None)
@given(random_layouts())
def test_property_random_layouts_round_trip(case):
    msg, columns = case
    before = snapshot(msg)
    n, (height, width) = msg.height * msg.width, (msg.height, msg.width)
    with np.errstate(invalid="ignore"):  # signalling NaN bit patterns
        xyz = np.stack([columns[name][:, 0].astype(np.float64) for name in "xyz"], axis=1)
    finite = np.isfinite(xyz).all(axis=1)

    assert_same_floats(cloud_to_xyz(msg, skip_nans=False), xyz)
    assert_same_floats(cloud_to_xyz(msg, keep_organized=True), xyz.reshape(height, width, 3))
    points, mask = cloud_to_xyz_and_mask(msg)
    assert np.array_equal(mask, finite)
    assert_same_floats(points, xyz[finite])
    extras = [name for name in columns if name not in "xyz"]
    got = cloud_to_fields(msg, extras, mask=mask)
    for name in extras:
        expected = columns[name][finite]
        expected = expected[:, 0] if expected.shape[1] == 1 else expected
        assert got[name].dtype == columns[name].dtype and got[name].dtype.isnative
        assert np.array_equal(got[name], expected, equal_nan=got[name].dtype.kind == "f")
    assert snapshot(msg) == before

    # and back: x, y, z round-trip exactly at float32 precision, organized grid kept
    with np.errstate(over="ignore"):  # random float64 bits beyond the float32 range -> Inf
        again = xyz_to_cloud(cloud_to_xyz(msg, keep_organized=True), msg.header)
        as_float32 = xyz.astype(np.float32).astype(np.float64)
    assert (again.height, again.width) == (height, width)
    assert again.is_dense == bool(np.isfinite(as_float32).all())
    assert_same_floats(cloud_to_xyz(again, skip_nans=False), as_float32)
    assert n == again.height * again.width


FIELD_DTYPES = [np.int8, np.uint8, np.int16, np.uint16, np.int32, np.uint32, np.float32, np.float64]


@settings(max_examples=100, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    shape=st.sampled_from([(0,), (1,), (17,), (2, 3), (4, 1), (1, 5)]),
    extra=st.lists(st.tuples(st.sampled_from(FIELD_DTYPES), st.integers(1, 3)), max_size=3),
    with_rgb=st.booleans(),
)
def test_property_xyz_to_cloud_round_trip(seed, shape, extra, with_rgb):
    rng = np.random.default_rng(seed)
    n = int(np.prod(shape))
    xyz = rng.integers(0, 2**32, size=(n, 3), dtype=np.uint32).view(np.float32)  # any float32
    fields = {}
    if with_rgb:
        fields["rgb"] = rng.integers(0, 2**24, size=n, dtype=np.uint32)
    for i, (dtype, count) in enumerate(extra):
        raw = rng.integers(0, 256, size=(n, count * np.dtype(dtype).itemsize), dtype=np.uint8).view(
            dtype
        )
        fields[f"e{i}"] = raw[:, 0] if count == 1 else raw
    points = xyz.reshape(*shape, 3) if len(shape) == 2 else xyz

    msg = xyz_to_cloud(points, Header(frame_id="f"), fields=fields)

    assert (msg.height, msg.width) == (shape if len(shape) == 2 else (1, n))
    assert msg.point_step % 4 == 0 and msg.row_step == msg.point_step * msg.width
    assert msg.is_dense == bool(np.isfinite(xyz).all())
    stored = np.array([decode(msg, name) for name in "xyz"], dtype=np.float32).reshape(3, n).T
    assert_same_floats(stored, xyz)
    assert_same_floats(cloud_to_xyz(msg, skip_nans=False, dtype=np.float32), xyz)
    back = cloud_to_fields(msg, list(fields))
    for name, values in fields.items():
        assert back[name].dtype == values.dtype
        assert np.array_equal(back[name], values, equal_nan=values.dtype.kind == "f")
    declared = {f.name: f.datatype for f in msg.fields}
    if with_rgb:
        assert declared["rgb"] == F32
