"""Tests of geomodel_ros.tools.io: PCD / PLY / NPY reading and writing, LZF, dataset helpers."""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np
import pytest

from data_helpers import DATA, require

from geomodel_ros.tools import pcd_file
from geomodel_ros.tools.io import (
    OSD_INVALID_ID,
    OSD_TABLE_ID,
    Cloud,
    CloudFileError,
    load_osd,
    lzf_decompress,
    osd_object_ids,
    read_cloud,
    read_npy,
    read_pcd,
    read_ply,
    write_cloud,
    write_npy,
    write_pcd,
    write_ply,
)

OSD_LEARN0 = DATA / "osd_learn" / "learn0.pcd"
MUG = DATA / "pcl_mug" / "table_scene_mug_stereo_textured.pcd"



# --------------------------------------------------------------------------------------------
# Test-only LZF encoders
# --------------------------------------------------------------------------------------------


def _literal(chunk: bytes) -> bytes:
    assert 1 <= len(chunk) <= 32
    return bytes([len(chunk) - 1]) + chunk


def _backref(length: int, dist: int) -> bytes:
    """One back-reference token: copy `length` (3..264) bytes from `dist` (1..8192) back."""
    assert 3 <= length <= 264 and 1 <= dist <= 8192
    hi, lo = (dist - 1) >> 8, (dist - 1) & 0xFF
    if length <= 8:
        return bytes([((length - 2) << 5) | hi, lo])
    return bytes([(7 << 5) | hi, length - 9, lo])


def _lzf_compress(data: bytes) -> bytes:
    """Greedy LZF compressor (3-byte hash chain of depth 1), for round-trip tests only."""
    out = bytearray()
    literals = bytearray()
    last: dict[bytes, int] = {}
    i = 0

    def flush() -> None:
        for k in range(0, len(literals), 32):
            out.extend(_literal(bytes(literals[k : k + 32])))
        literals.clear()

    while i < len(data):
        key = data[i : i + 3]
        ref = last.get(key) if len(key) == 3 else None
        last[key] = i
        if ref is not None and i - ref <= 8192:
            length = 3
            while (
                length < 264 and i + length < len(data) and data[ref + length] == data[i + length]
            ):
                length += 1
            flush()
            out.extend(_backref(length, i - ref))
            i += length
        else:
            literals.append(data[i])
            i += 1
    flush()
    return bytes(out)


# --------------------------------------------------------------------------------------------
# LZF decoder
# --------------------------------------------------------------------------------------------


def test_lzf_literal_run() -> None:
    assert lzf_decompress(_literal(b"abc"), 3) == b"abc"
    run = bytes(range(32))
    assert lzf_decompress(_literal(run) + _literal(b"z"), 33) == run + b"z"


def test_lzf_empty_stream() -> None:
    assert lzf_decompress(b"", 0) == b""


def test_lzf_back_reference_without_overlap() -> None:
    stream = _literal(b"abcdef") + _backref(3, 6)  # copy "abc"
    assert lzf_decompress(stream, 9) == b"abcdefabc"


def test_lzf_overlapping_back_references() -> None:
    # distance 1: run of one byte
    assert lzf_decompress(_literal(b"a") + _backref(7, 1), 8) == b"a" * 8
    # distance 2 < length 7: "ab" repeated
    assert lzf_decompress(_literal(b"xab") + _backref(7, 2), 10) == b"xab" + b"abababa"
    # long form (length > 8) with overlap, then a plain literal
    stream = _literal(b"123") + _backref(264, 3) + _literal(b"!")
    assert lzf_decompress(stream, 268) == (b"123" * 89)[:267] + b"!"


def test_lzf_long_distance_uses_high_bits() -> None:
    head = bytes(range(256)) * 2  # 512 bytes in 16 literal runs
    stream = b"".join(_literal(head[k : k + 32]) for k in range(0, 512, 32))
    stream += _backref(10, 300)
    assert lzf_decompress(stream, 522) == head + head[212:222]


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_lzf_round_trip_with_test_compressor(seed: int) -> None:
    rng = np.random.default_rng(seed)
    words = [rng.bytes(int(rng.integers(1, 12))) for _ in range(20)]
    data = b"".join(words[int(k)] for k in rng.integers(0, 20, 2000)) + bytes(1000) + rng.bytes(99)
    stream = _lzf_compress(data)
    assert len(stream) < len(data)
    assert lzf_decompress(stream, len(data)) == data


@pytest.mark.parametrize(
    ("stream", "size", "match"),
    [
        (_backref(3, 1), 3, r"points 1 bytes back but only 0 bytes"),
        (_literal(b"ab") + _backref(3, 3), 5, r"points 3 bytes back but only 2"),
        (_literal(b"abcd")[:-1], 4, r"literal run of 4 bytes .* past the end"),
        (_literal(b"ab") + bytes([0x20]), 5, r"ends inside a back-reference"),
        (_literal(b"ab") + bytes([0xE0, 0x01]), 12, r"ends inside a back-reference"),
        (_literal(b"abc"), 4, r"decompressed to 3 bytes, expected 4"),
        (_literal(b"abc") + _backref(3, 3), 5, r"decompressed to 6 bytes, expected 5"),
    ],
)
def test_lzf_corrupt_input_raises(stream: bytes, size: int, match: str) -> None:
    with pytest.raises(CloudFileError, match=match):
        lzf_decompress(stream, size)


def test_lzf_accepts_any_bytes_like() -> None:
    stream = _literal(b"abc") + _backref(3, 3)
    for data in (bytearray(stream), memoryview(stream)):
        assert lzf_decompress(data, 6) == b"abcabc"


class _DecoderSpy:
    """Stands in for liblzf and records the (input, output) sizes it is asked for."""

    def __init__(self) -> None:
        self.calls: list[tuple[int, int]] = []

    def decompress(self, data: bytes, size: int) -> None:
        self.calls.append((len(data), size))


def test_lzf_size_beyond_what_the_stream_can_hold_is_refused_without_allocating(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    # 6 input bytes yield at most 6 * 88 bytes: a claimed 1 GB is refused before liblzf
    # (which allocates the claimed size up front) is called.
    spy = _DecoderSpy()
    monkeypatch.setattr(pcd_file, "lzf", spy)
    stream = _literal(b"abc") + _backref(3, 3)
    with pytest.raises(CloudFileError, match=r"decompressed to 6 bytes, expected 1000000000"):
        lzf_decompress(stream, 10**9)
    assert spy.calls == []
    with pytest.raises(CloudFileError, match=r"decompressed to 6 bytes, expected 528"):
        lzf_decompress(stream, 6 * 88)  # the largest size still handed to the decoder
    assert spy.calls == [(6, 6 * 88)]


# --------------------------------------------------------------------------------------------
# PCD
# --------------------------------------------------------------------------------------------


def _sample(n: int = 50, seed: int = 0) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    rng = np.random.default_rng(seed)
    points = rng.normal(size=(n, 3)) * 2.0
    points[3] = np.nan
    points[5, 2] = np.inf
    fields = {
        "label": rng.integers(0, 2**32, n, dtype=np.uint32),
        "rgb": rng.integers(0, 2**32, n, dtype=np.uint32),
        "normal": rng.normal(size=(n, 3)).astype(np.float32),
        "ring": rng.integers(-(2**15), 2**15, n, dtype=np.int16),
        "time": rng.random(n),
        "seen": rng.random(n) > 0.5,
    }
    return points, fields


def _check_fields(read: dict[str, np.ndarray], written: dict[str, np.ndarray]) -> None:
    assert list(read) == list(written)
    for name, values in written.items():
        expected = values.astype(np.uint8) if values.dtype == bool else values
        assert read[name].dtype == expected.dtype, name
        np.testing.assert_array_equal(read[name], expected, err_msg=name)


@pytest.mark.parametrize("binary", [True, False])
def test_pcd_round_trip_float32(tmp_path: Path, binary: bool) -> None:
    points, fields = _sample()
    viewpoint = np.array([0.5, -1.0, 2.0, 0.0, 1.0, 0.0, 0.0])
    path = tmp_path / "cloud.pcd"
    write_pcd(path, points, fields, binary=binary, viewpoint=viewpoint)
    cloud = read_cloud(path)
    assert cloud.points.dtype == np.float64 and cloud.points.shape == (50, 3)
    np.testing.assert_array_equal(cloud.points, points.astype(np.float32).astype(np.float64))
    _check_fields(cloud.fields, fields)
    assert (cloud.width, cloud.height, cloud.is_organized) == (50, 1, False)
    np.testing.assert_array_equal(cloud.viewpoint, viewpoint)
    assert cloud.finite_mask().sum() == 48


@pytest.mark.parametrize("binary", [True, False])
def test_pcd_round_trip_float64_is_exact(tmp_path: Path, binary: bool) -> None:
    points, _ = _sample(seed=3)
    path = tmp_path / "cloud.pcd"
    write_pcd(path, points, binary=binary, xyz_dtype=np.float64)
    cloud = read_pcd(path)
    np.testing.assert_array_equal(cloud.points, points)
    assert cloud.fields == {}
    np.testing.assert_array_equal(cloud.viewpoint, [0, 0, 0, 1, 0, 0, 0])


@pytest.mark.parametrize("binary", [True, False])
def test_pcd_organized_with_nan(tmp_path: Path, binary: bool) -> None:
    rng = np.random.default_rng(7)
    image = rng.random((4, 5, 3)).astype(np.float32)
    image[1, 2] = np.nan
    image[3, :, 2] = np.nan  # only z invalid, as in the OSD files
    labels = np.arange(20, dtype=np.uint32).reshape(4, 5)
    path = tmp_path / "organized.pcd"
    write_pcd(path, image, {"label": labels, "flat": labels.ravel()}, binary=binary)
    cloud = read_pcd(path)
    assert (cloud.width, cloud.height, cloud.is_organized) == (5, 4, True)
    np.testing.assert_array_equal(cloud.organized_points(), image.astype(np.float64))
    np.testing.assert_array_equal(cloud.fields["label"], labels.ravel())
    np.testing.assert_array_equal(cloud.fields["flat"], labels.ravel())
    mask = cloud.finite_mask()
    assert mask.shape == (20,) and mask.sum() == 20 - 1 - 5
    assert not mask.reshape(4, 5)[1, 2] and not mask.reshape(4, 5)[3].any()


def test_pcd_organized_from_flat_points_and_width(tmp_path: Path) -> None:
    points = np.arange(24, dtype=np.float64).reshape(8, 3)
    write_pcd(tmp_path / "a.pcd", points, width=4)
    cloud = read_pcd(tmp_path / "a.pcd")
    assert (cloud.width, cloud.height) == (4, 2)
    assert cloud.organized_points().shape == (2, 4, 3)


def test_pcd_empty_cloud_round_trip(tmp_path: Path) -> None:
    for binary in (True, False):
        label = np.zeros(0, np.uint32)
        write_pcd(tmp_path / "e.pcd", np.zeros((0, 3)), {"label": label}, binary=binary)
        cloud = read_pcd(tmp_path / "e.pcd")
        assert cloud.points.shape == (0, 3) and cloud.fields["label"].shape == (0,)


def test_write_cloud_dispatch_keeps_everything(tmp_path: Path) -> None:
    points, fields = _sample(12, seed=4)
    fields = {"label": fields["label"]}
    cloud = Cloud(points.reshape(3, 4, 3), fields, viewpoint=[1, 2, 3, 1, 0, 0, 0])
    assert (cloud.width, cloud.height) == (4, 3)
    write_cloud(tmp_path / "c.pcd", cloud)
    again = read_cloud(tmp_path / "c.pcd")
    assert (again.width, again.height) == (4, 3)
    _check_fields(again.fields, fields)
    np.testing.assert_array_equal(again.viewpoint, cloud.viewpoint)
    write_cloud(tmp_path / "c.npy", cloud)
    assert read_cloud(tmp_path / "c.npy").organized_points().shape == (3, 4, 3)
    write_cloud(tmp_path / "c.ply", cloud)
    np.testing.assert_array_equal(
        read_cloud(tmp_path / "c.ply").points, points.astype(np.float32).astype(np.float64)
    )
    with pytest.raises(ValueError, match=r"unsupported file suffix '.xyz'; allowed: .npy"):
        write_cloud(tmp_path / "c.xyz", cloud)


def _compressed_pcd(
    fields: list[tuple[str, np.ndarray, str]],
    width: int,
    height: int,
    *,
    literal_only: bool = False,
) -> bytes:
    """Build a binary_compressed PCD as PCL writes it: fields one by one, LZF, page padding."""
    names, sizes, types, counts, blocks = [], [], [], [], []
    for name, values, type_ in fields:
        values = np.ascontiguousarray(values).reshape(width * height, -1)
        names.append(name)
        sizes.append(str(values.dtype.itemsize))
        types.append(type_)
        counts.append(str(values.shape[1]))
        blocks.append(values.astype(values.dtype.newbyteorder("<")).tobytes())
    raw = b"".join(blocks)
    if literal_only:
        packed = b"".join(_literal(raw[k : k + 32]) for k in range(0, len(raw), 32))
    else:
        packed = _lzf_compress(raw)
    header = (
        "# .PCD v0.7 - Point Cloud Data file format\nVERSION 0.7\n"
        f"FIELDS {' '.join(names)}\nSIZE {' '.join(sizes)}\nTYPE {' '.join(types)}\n"
        f"COUNT {' '.join(counts)}\nWIDTH {width}\nHEIGHT {height}\n"
        f"VIEWPOINT 0 0 0 1 0 0 0\nPOINTS {width * height}\nDATA binary_compressed\n"
    ).encode()
    body = header + struct.pack("<II", len(packed), len(raw)) + packed
    return body + bytes(-len(body) % 4096)  # PCL pads the file to whole pages


@pytest.mark.parametrize("literal_only", [False, True])
def test_pcd_binary_compressed_synthetic(tmp_path: Path, literal_only: bool) -> None:
    rng = np.random.default_rng(11)
    h, w = 6, 7
    xyz = rng.random((h * w, 3)).astype(np.float32)
    xyz[::5] = np.nan
    label = (rng.integers(0, 4, h * w) * 10).astype(np.uint32)
    normal = rng.random((h * w, 3)).astype(np.float32)
    rgb = rng.integers(0, 2**24, h * w, dtype=np.uint32) | np.uint32(0xFF000000)
    fields = [
        ("label", label, "U"),
        ("x", xyz[:, 0], "F"),
        ("y", xyz[:, 1], "F"),
        ("z", xyz[:, 2], "F"),
        ("normal", normal, "F"),
        ("rgb", rgb.view(np.float32), "F"),  # PCL stores packed rgb in a float field
    ]
    path = tmp_path / "c.pcd"
    path.write_bytes(_compressed_pcd(fields, w, h, literal_only=literal_only))
    cloud = read_pcd(path)
    assert (cloud.width, cloud.height) == (w, h)
    np.testing.assert_array_equal(cloud.points, xyz.astype(np.float64))
    np.testing.assert_array_equal(cloud.fields["label"], label)
    np.testing.assert_array_equal(cloud.fields["normal"], normal)
    assert cloud.fields["rgb"].dtype == np.uint32
    np.testing.assert_array_equal(cloud.fields["rgb"], rgb)


def test_pcd_ascii_rgb_float_field_as_pcl_writes_it(tmp_path: Path) -> None:
    # PCL writes a float rgb field in ascii as the packed uint32 integer; older writers
    # wrote the float value of the bits.
    packed = np.array([0xFF7F0000, 0x00102030], dtype=np.uint32)
    head = "VERSION .7\nFIELDS x y z rgb\nSIZE 4 4 4 4\nTYPE F F F F\nCOUNT 1 1 1 1\n"
    head += "WIDTH 2\nHEIGHT 1\nPOINTS 2\nDATA ascii\n"
    new_style = head + "".join(f"1 2 3 {int(v)}\n" for v in packed)
    (tmp_path / "new.pcd").write_text(new_style)
    np.testing.assert_array_equal(read_pcd(tmp_path / "new.pcd").fields["rgb"], packed)
    old = np.array([0x00102030, 0x00FF0000], dtype=np.uint32)
    old_style = head + "".join(f"1 2 3 {v!r}\n" for v in old.view(np.float32).tolist())
    (tmp_path / "old.pcd").write_text(old_style)
    np.testing.assert_array_equal(read_pcd(tmp_path / "old.pcd").fields["rgb"], old)


def test_pcd_v06_header_without_viewpoint_and_padding_field(tmp_path: Path) -> None:
    text = (
        "# .PCD v.6\nVERSION .6\nFIELDS x y z _ intensity\nSIZE 4 4 4 1 2\nTYPE F F F U U\n"
        "COUNT 1 1 1 3 1\nWIDTH 2\nHEIGHT 1\nPOINTS 2\nDATA binary\n"
    ).encode()
    record = np.dtype([("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("_", "u1", 3), ("i", "<u2")])
    data = np.array([(1, 2, 3, (0, 0, 0), 7), (4, 5, 6, (9, 9, 9), 8)], dtype=record)
    (tmp_path / "v6.pcd").write_bytes(text + data.tobytes())
    cloud = read_pcd(tmp_path / "v6.pcd")
    np.testing.assert_array_equal(cloud.points, [[1, 2, 3], [4, 5, 6]])
    assert list(cloud.fields) == ["intensity"] and cloud.fields["intensity"].tolist() == [7, 8]
    assert cloud.viewpoint is None


def test_open3d_reads_our_pcd(tmp_path: Path) -> None:
    o3d = pytest.importorskip("open3d")
    points, fields = _sample(30, seed=5)
    finite = np.isfinite(points).all(axis=1)
    for binary in (True, False):
        path = tmp_path / f"o3d_{binary}.pcd"
        write_pcd(path, points[finite], {"label": fields["label"][finite]}, binary=binary)
        ours = np.asarray(o3d.io.read_point_cloud(str(path)).points)
        np.testing.assert_allclose(ours, points[finite], rtol=1e-6, atol=1e-6)


# --- real data ---------------------------------------------------------------------------


@pytest.fixture(scope="module")
def learn0() -> Cloud:
    return read_cloud(require(OSD_LEARN0))


@pytest.fixture(scope="module")
def mug() -> Cloud:
    return read_cloud(require(MUG))


def test_osd_learn0_loads(learn0: Cloud) -> None:
    assert learn0.points.shape == (307200, 3)
    assert (learn0.width, learn0.height, learn0.is_organized) == (640, 480, True)
    assert list(learn0.fields) == ["label", "rgba"]
    assert learn0.fields["label"].dtype == np.uint32 and learn0.fields["label"].shape == (307200,)
    assert learn0.fields["rgba"].dtype == np.uint32
    assert set(np.unique(learn0.fields["label"]).tolist()) == {0, 1, 20, 30}
    finite = learn0.finite_mask()
    assert finite.sum() == 182292
    np.testing.assert_array_equal(finite, learn0.fields["label"] != 0)


def test_mug_loads_with_known_finite_count(mug: Cloud) -> None:
    assert mug.points.shape == (307200, 3)
    assert (mug.width, mug.height) == (640, 480)
    assert list(mug.fields) == ["rgb"] and mug.fields["rgb"].dtype == np.uint32
    assert mug.finite_mask().sum() == 209_280
    z = mug.points[mug.finite_mask(), 2]
    assert ((z >= 0) & (z <= 1.5)).sum() == 139_897  # the tutorial's pass-through count


@pytest.mark.parametrize(
    ("fixture", "path"),
    [
        pytest.param("learn0", OSD_LEARN0),
        pytest.param("mug", MUG),
    ],
)
def test_real_pcd_matches_open3d(request: pytest.FixtureRequest, fixture: str, path: Path) -> None:
    o3d = pytest.importorskip("open3d")
    cloud: Cloud = request.getfixturevalue(fixture)
    pcd = o3d.io.read_point_cloud(str(path), remove_nan_points=True, remove_infinite_points=True)
    finite = cloud.finite_mask()
    np.testing.assert_array_equal(cloud.points[finite], np.asarray(pcd.points))
    # the raw colour bits decode to open3d's colours
    packed = cloud.fields["rgba" if "rgba" in cloud.fields else "rgb"][finite]
    rgb = np.stack([(packed >> shift) & 0xFF for shift in (16, 8, 0)], axis=1) / 255.0
    np.testing.assert_allclose(rgb, np.asarray(pcd.colors), atol=1e-12)


def test_load_osd_maps_labels_to_object_ids() -> None:
    points, labels = load_osd(require(OSD_LEARN0))
    assert points.shape == (307200, 3) and points.dtype == np.float64
    assert labels.shape == (307200,) and labels.dtype == np.int64
    ids, counts = np.unique(labels, return_counts=True)
    assert ids.tolist() == [OSD_INVALID_ID, OSD_TABLE_ID, 2, 3]
    assert counts.tolist() == [124908, 153323, 20792, 8177]
    assert np.isnan(points[labels == OSD_INVALID_ID]).any(axis=1).all()


def test_osd_object_ids() -> None:
    raw = np.array([0, 1, 9, 20, 29, 30, 31, 47, 120], dtype=np.uint32)
    assert osd_object_ids(raw).tolist() == [-1, 0, 0, 2, 2, 3, 3, 4, 12]
    with pytest.raises(ValueError, match=r"OSD labels \[15\] are not allowed; allowed: 0"):
        osd_object_ids([0, 15, 20])


def test_load_osd_without_label_field(tmp_path: Path) -> None:
    write_pcd(tmp_path / "nolabel.pcd", np.zeros((2, 3)))
    with pytest.raises(CloudFileError, match=r"nolabel.pcd: OSD scene needs an integer 'label'"):
        load_osd(tmp_path / "nolabel.pcd")


# --- errors --------------------------------------------------------------------------------


def test_missing_directory_empty_and_wrong_suffix(tmp_path: Path) -> None:
    with pytest.raises(CloudFileError, match=r"missing.pcd: no such file"):
        read_cloud(tmp_path / "missing.pcd")
    (tmp_path / "dir.pcd").mkdir()
    with pytest.raises(CloudFileError, match=r"dir.pcd: is a directory"):
        read_cloud(tmp_path / "dir.pcd")
    for suffix in (".pcd", ".ply", ".npy"):
        (tmp_path / f"empty{suffix}").write_bytes(b"")
        with pytest.raises(CloudFileError, match=rf"empty{suffix}: file is empty"):
            read_cloud(tmp_path / f"empty{suffix}")
    (tmp_path / "cloud.xyz").write_text("1 2 3\n")
    with pytest.raises(
        CloudFileError, match=r"cloud.xyz: unsupported file suffix '.xyz'; allowed: .npy, .pcd"
    ):
        read_cloud(tmp_path / "cloud.xyz")
    with pytest.raises(CloudFileError, match=r"unsupported file suffix '\(none\)'"):
        read_cloud(tmp_path / "noext")


_GOOD_HEAD = {
    "VERSION": "0.7",
    "FIELDS": "x y z",
    "SIZE": "4 4 4",
    "TYPE": "F F F",
    "COUNT": "1 1 1",
    "WIDTH": "2",
    "HEIGHT": "1",
    "VIEWPOINT": "0 0 0 1 0 0 0",
    "POINTS": "2",
    "DATA": "ascii",
}


def _pcd_text(body: str = "1 2 3\n4 5 6\n", **changes: str | None) -> str:
    head = dict(_GOOD_HEAD)
    head.update(changes)
    return "".join(f"{k} {v}\n" for k, v in head.items() if v is not None) + body


@pytest.mark.parametrize(
    ("text", "match"),
    [
        ("not a point cloud\n", r"unknown PCD header keyword 'NOT' on line 1; allowed: VERSION"),
        (_pcd_text(DATA=None, body=""), r"header ends without a DATA line"),
        (_pcd_text(VERSION="0.5"), r"unsupported PCD VERSION '0.5'; supported: 0.6, 0.7"),
        (_pcd_text(DATA="binary_lz4"), r"unsupported PCD DATA 'binary_lz4'; allowed: ascii, bin"),
        (_pcd_text(SIZE="4 4"), r"SIZE has 2 entries but FIELDS has 3; they must match"),
        (_pcd_text(TYPE="F F D"), r"field 'z' has TYPE 'D'; allowed: F, I, U"),
        (_pcd_text(SIZE="4 4 3"), r"field 'z' of TYPE F has SIZE 3; allowed: 4, 8"),
        (_pcd_text(COUNT="1 1 0"), r"COUNT value '0' is not an integer >= 1"),
        (_pcd_text(FIELDS="x y w"), r"FIELDS 'x y w' lack z; x, y and z are required"),
        (_pcd_text(FIELDS="x y y"), r"FIELDS names \['y'\] more than once"),
        (_pcd_text(POINTS="3"), r"WIDTH 2 x HEIGHT 1 != POINTS 3; they must agree"),
        (_pcd_text(WIDTH="two"), r"WIDTH value 'two' is not an integer >= 0"),
        (_pcd_text(VIEWPOINT="0 0 0 1"), r"VIEWPOINT '0 0 0 1' must be 7 finite numbers"),
        (_pcd_text(body="1 2 3\n"), r"truncated PCD: DATA ascii has 1 lines, POINTS says 2"),
        (_pcd_text(body="\n\n\n"), r"truncated PCD: DATA ascii has 0 rows, POINTS says 2"),
        (_pcd_text(COUNT="1 1 99999999999"), r"field 'z' has COUNT 99999999999; allowed: 1 to"),
        (_pcd_text(body="1 2 3\n4 five 6\n"), r"corrupt PCD DATA ascii: could not convert"),
        (_pcd_text(body="1 2 3\n4 5\n"), r"corrupt PCD DATA ascii: .* requires 3 columns"),
        (_pcd_text(COUNT="1 1 2", body="1 2 3 4\n5 6 7 8\n"), r"field 'z' has COUNT 2"),
        ("VERSION 0.7\n" + _pcd_text(), r"PCD header keyword VERSION given twice"),
    ],
)
def test_bad_pcd_headers_and_ascii_data(tmp_path: Path, text: str, match: str) -> None:
    path = tmp_path / "bad.pcd"
    path.write_text(text)
    with pytest.raises(CloudFileError, match=r"bad.pcd: (PCD )?(header )?" + match):
        read_pcd(path)


def test_binary_garbage_named_pcd(tmp_path: Path) -> None:
    (tmp_path / "garbage.pcd").write_bytes(bytes(range(128, 256)) * 4)
    with pytest.raises(CloudFileError, match=r"garbage.pcd: line 1 of the PCD header is not ASCII"):
        read_pcd(tmp_path / "garbage.pcd")


def test_truncated_binary_pcd(tmp_path: Path) -> None:
    path = tmp_path / "t.pcd"
    write_pcd(path, np.ones((10, 3)), {"label": np.ones(10, np.uint32)})
    path.write_bytes(path.read_bytes()[:-5])
    with pytest.raises(
        CloudFileError, match=r"t.pcd: truncated PCD: DATA binary needs 160 bytes .* has 155"
    ):
        read_pcd(path)


def test_truncated_and_corrupt_binary_compressed(tmp_path: Path) -> None:
    xyz = np.tile(np.arange(6, dtype=np.float32), 20).reshape(-1, 3)
    good = _compressed_pcd([(axis, xyz[:, k], "F") for k, axis in enumerate("xyz")], 40, 1)
    start = good.index(b"DATA binary_compressed\n") + len(b"DATA binary_compressed\n")
    compressed, raw = struct.unpack_from("<II", good, start)
    path = tmp_path / "c.pcd"

    path.write_bytes(good[: start + 5])
    with pytest.raises(CloudFileError, match=r"c.pcd: truncated PCD: .* needs at least the 8-byte"):
        read_pcd(path)
    path.write_bytes(good[: start + 8 + compressed - 4])
    with pytest.raises(
        CloudFileError, match=rf"c.pcd: truncated PCD: binary_compressed says {compressed}"
    ):
        read_pcd(path)
    path.write_bytes(good[:start] + struct.pack("<II", compressed, raw + 4) + good[start + 8 :])
    with pytest.raises(
        CloudFileError, match=rf"uncompressed size {raw + 4} != {raw} \(40 points of 12"
    ):
        read_pcd(path)
    bad_first_token = bytes([0x20, 0x00])  # a back-reference before any output
    path.write_bytes(good[: start + 8] + bad_first_token + good[start + 10 :])
    with pytest.raises(CloudFileError, match=r"c.pcd: corrupt LZF data: back-reference"):
        read_pcd(path)
    # the compressed stream cut short (sizes in the header shrunk accordingly)
    cut = good[start + 8 : start + 8 + compressed // 2]
    path.write_bytes(good[:start] + struct.pack("<II", len(cut), raw) + cut)
    with pytest.raises(CloudFileError, match=r"c.pcd: corrupt LZF data"):
        read_pcd(path)


def test_compressed_header_claiming_huge_cloud_is_refused_without_allocating(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    xyz = np.zeros((4, 3), np.float32)
    good = _compressed_pcd([(axis, xyz[:, k], "F") for k, axis in enumerate("xyz")], 4, 1)
    points = 80_000_000  # 960 MB of x y z claimed by a file of a few hundred bytes
    start = good.index(b"DATA binary_compressed\n") + len(b"DATA binary_compressed\n")
    compressed, _ = struct.unpack_from("<II", good, start)
    head = good[:start].replace(b"WIDTH 4\n", f"WIDTH {points}\n".encode())
    head = head.replace(b"POINTS 4\n", f"POINTS {points}\n".encode())
    body = struct.pack("<II", compressed, points * 12) + good[start + 8 :]
    (tmp_path / "huge.pcd").write_bytes(head + body)
    spy = _DecoderSpy()
    monkeypatch.setattr(pcd_file, "lzf", spy)
    with pytest.raises(CloudFileError, match=r"huge.pcd: corrupt LZF data: decompressed to 48 b"):
        read_pcd(tmp_path / "huge.pcd")
    assert spy.calls == []


def test_compressed_fields_are_writable_and_own_their_memory(learn0: Cloud) -> None:
    # a field kept alone must not pin the whole decompressed payload (or be read-only)
    for name in ("label", "rgba"):
        values = learn0.fields[name]
        assert values.flags.writeable and values.flags.owndata, name


def test_mutated_files_raise_only_cloud_file_error(tmp_path: Path) -> None:
    """Random byte flips, cuts and insertions never escape as another exception type."""
    rng = np.random.default_rng(2024)
    points, fields = _sample(20, seed=6)
    write_pcd(tmp_path / "b.pcd", points, fields)
    write_pcd(tmp_path / "a.pcd", points, fields, binary=False)
    write_ply(tmp_path / "p.ply", points, np.zeros((20, 3), np.uint8))
    write_npy(tmp_path / "n.npy", points)
    xyz = points.astype(np.float32)
    (tmp_path / "c.pcd").write_bytes(
        _compressed_pcd([("x", xyz[:, 0], "F"), ("y", xyz[:, 1], "F"), ("z", xyz[:, 2], "F")], 5, 4)
    )
    for name in ("b.pcd", "a.pcd", "c.pcd", "p.ply", "n.npy"):
        good = (tmp_path / name).read_bytes()
        target = tmp_path / f"mutated_{name}"
        for _ in range(150):
            data = bytearray(good)
            where = int(rng.integers(0, min(len(data), 300) if rng.random() < 0.5 else len(data)))
            action = rng.integers(0, 3)
            if action == 0:
                data[where] = int(rng.integers(0, 256))
            elif action == 1:
                del data[where:]
            else:
                data[where:where] = rng.bytes(int(rng.integers(1, 4)))
            target.write_bytes(bytes(data))
            try:
                read_cloud(target)
            except CloudFileError:
                pass


def test_truncated_real_compressed_file(tmp_path: Path) -> None:
    path = tmp_path / "mug_cut.pcd"
    path.write_bytes(require(MUG).read_bytes()[:100_000])
    with pytest.raises(CloudFileError, match=r"mug_cut.pcd: truncated PCD: binary_compressed says"):
        read_pcd(path)


# --------------------------------------------------------------------------------------------
# PLY
# --------------------------------------------------------------------------------------------


def test_ply_round_trip_with_colors(tmp_path: Path) -> None:
    points, _ = _sample(40, seed=8)
    colors = np.random.default_rng(8).integers(0, 256, (40, 3), dtype=np.uint8)
    write_ply(tmp_path / "c.ply", points, colors)
    cloud = read_cloud(tmp_path / "c.ply")
    np.testing.assert_array_equal(cloud.points, points.astype(np.float32).astype(np.float64))
    assert list(cloud.fields) == ["red", "green", "blue"]
    np.testing.assert_array_equal(
        np.stack([cloud.fields[c] for c in ("red", "green", "blue")], axis=1), colors
    )
    assert (cloud.width, cloud.height, cloud.viewpoint) == (40, 1, None)


def test_ply_float64_and_float_colors(tmp_path: Path) -> None:
    points, _ = _sample(10, seed=9)
    write_ply(tmp_path / "d.ply", points, np.full((10, 3), 0.5), xyz_dtype=np.float64)
    cloud = read_ply(tmp_path / "d.ply")
    np.testing.assert_array_equal(cloud.points, points)
    assert cloud.fields["green"].tolist() == [128] * 10


def test_ply_interop_with_open3d(tmp_path: Path) -> None:
    o3d = pytest.importorskip("open3d")
    rng = np.random.default_rng(10)
    points = rng.random((25, 3))
    write_ply(tmp_path / "ours.ply", points, rng.random((25, 3)))
    theirs = np.asarray(o3d.io.read_point_cloud(str(tmp_path / "ours.ply")).points)
    np.testing.assert_allclose(theirs, points, rtol=1e-6)
    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
    pcd.normals = o3d.utility.Vector3dVector(rng.random((25, 3)))
    for ascii_ in (False, True):
        o3d.io.write_point_cloud(str(tmp_path / "theirs.ply"), pcd, write_ascii=ascii_)
        cloud = read_ply(tmp_path / "theirs.ply")
        if ascii_:  # open3d writes 6 significant digits
            np.testing.assert_allclose(cloud.points, points, rtol=0, atol=1e-6)
        else:
            np.testing.assert_array_equal(cloud.points, points)
        assert {"nx", "ny", "nz"} <= set(cloud.fields)


def test_ply_ascii_with_faces_and_big_endian(tmp_path: Path) -> None:
    ascii_text = (
        "ply\nformat ascii 1.0\ncomment hand made\nelement vertex 3\nproperty float x\n"
        "property float y\nproperty float z\nproperty uchar red\nelement face 1\n"
        "property list uchar int vertex_indices\nend_header\n"
        "0 0 0 10\n1 0 0 20\n0 1 nan 30\n3 0 1 2\n"
    )
    (tmp_path / "a.ply").write_text(ascii_text)
    cloud = read_ply(tmp_path / "a.ply")
    np.testing.assert_array_equal(cloud.points, [[0, 0, 0], [1, 0, 0], [0, 1, np.nan]])
    assert cloud.fields["red"].tolist() == [10, 20, 30]
    head = b"ply\nformat binary_big_endian 1.0\nelement vertex 2\nproperty double x\n"
    head += b"property double y\nproperty double z\nend_header\n"
    (tmp_path / "b.ply").write_bytes(head + np.arange(6, dtype=">f8").tobytes())
    np.testing.assert_array_equal(read_ply(tmp_path / "b.ply").points, [[0, 1, 2], [3, 4, 5]])


@pytest.mark.parametrize(
    ("content", "match"),
    [
        (b"plx\nformat ascii 1.0\n", r"not a PLY file"),
        (b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\n", r"no end_header"),
        (b"ply\nformat binary_middle_endian 1.0\nend_header\n", r"unsupported PLY format"),
        (b"ply\nformat ascii 1.0\nelement face 0\nend_header\n", r"no 'vertex' element"),
        (
            b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\n"
            b"end_header\n0 0\n",
            r"vertex element lacks z",
        ),
        (
            b"ply\nformat ascii 1.0\nelement vertex 1\nproperty quad x\nend_header\n",
            r"property line 4 .* not understood; allowed types: char",
        ),
        (
            b"ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\n"
            b"property float z\nend_header\n1 2 3\n",
            r"truncated PLY: 1 body lines, the header needs at least 2",
        ),
        (
            b"ply\nformat binary_little_endian 1.0\nelement vertex 2\nproperty float x\n"
            b"property float y\nproperty float z\nend_header\n" + bytes(20),
            r"truncated PLY: 2 vertices need 24 bytes, the file has 20",
        ),
    ],
)
def test_bad_ply(tmp_path: Path, content: bytes, match: str) -> None:
    (tmp_path / "bad.ply").write_bytes(content)
    with pytest.raises(CloudFileError, match=r"bad.ply: .*" + match):
        read_ply(tmp_path / "bad.ply")


# --------------------------------------------------------------------------------------------
# NPY
# --------------------------------------------------------------------------------------------


def test_npy_round_trip_flat_and_organized(tmp_path: Path) -> None:
    flat = np.random.default_rng(12).random((9, 3))
    write_npy(tmp_path / "f.npy", flat)
    cloud = read_npy(tmp_path / "f.npy")
    np.testing.assert_array_equal(cloud.points, flat)
    assert (cloud.width, cloud.height, cloud.is_organized) == (9, 1, False)
    image = flat.reshape(3, 3, 3).astype(np.float32)
    image[0, 0] = np.nan
    np.save(tmp_path / "o.npy", image)
    cloud = read_cloud(tmp_path / "o.npy")
    assert (cloud.width, cloud.height, cloud.is_organized) == (3, 3, True)
    np.testing.assert_array_equal(cloud.organized_points(), image.astype(np.float64))
    assert cloud.finite_mask().sum() == 8
    np.save(tmp_path / "fortran.npy", np.asfortranarray(flat))
    np.testing.assert_array_equal(read_npy(tmp_path / "fortran.npy").points, flat)


@pytest.mark.parametrize(
    ("array", "match"),
    [
        (np.zeros((4, 4)), r"array shape \(4, 4\) is not allowed; it must be \(N, 3\) or \(H"),
        (np.zeros(3), r"array shape \(3,\) is not allowed"),
        (np.zeros((2, 3), dtype=np.int32), r"array dtype int32 is not allowed; it must be a float"),
        (np.array([[None, 1, 2]], dtype=object), r"array dtype object is not allowed"),
    ],
)
def test_bad_npy(tmp_path: Path, array: np.ndarray, match: str) -> None:
    np.save(tmp_path / "bad.npy", array, allow_pickle=True)
    with pytest.raises(CloudFileError, match=r"bad.npy: " + match):
        read_npy(tmp_path / "bad.npy")


def test_truncated_and_non_npy(tmp_path: Path) -> None:
    np.save(tmp_path / "t.npy", np.zeros((100, 3)))
    (tmp_path / "t.npy").write_bytes((tmp_path / "t.npy").read_bytes()[:-10])
    with pytest.raises(
        CloudFileError, match=r"t.npy: truncated .npy array: shape \(100, 3\) of float64 needs 2400"
    ):
        read_npy(tmp_path / "t.npy")
    (tmp_path / "text.npy").write_text("1 2 3\n")
    with pytest.raises(CloudFileError, match=r"text.npy: not a readable .npy array"):
        read_npy(tmp_path / "text.npy")


# --------------------------------------------------------------------------------------------
# Argument checks
# --------------------------------------------------------------------------------------------


def test_cloud_validates_shapes() -> None:
    with pytest.raises(ValueError, match=r"points must have shape \(N, 3\)"):
        Cloud(np.zeros((4, 2)))
    with pytest.raises(ValueError, match=r"width 3 x height 2 must equal the number of points 4"):
        Cloud(np.zeros((4, 3)), {}, 3, 2)
    with pytest.raises(ValueError, match=r"field 'label' must be an array whose first axis"):
        Cloud(np.zeros((4, 3)), {"label": np.zeros(3)})
    with pytest.raises(ValueError, match=r"viewpoint must be 7 numbers"):
        Cloud(np.zeros((4, 3)), viewpoint=np.zeros(3))


def test_write_pcd_rejects_bad_arguments(tmp_path: Path) -> None:
    path = tmp_path / "w.pcd"
    points = np.zeros((4, 3))
    with pytest.raises(ValueError, match=r"points must have shape \(N, 3\) or \(H, W, 3\)"):
        write_pcd(path, np.zeros((4, 2)))
    with pytest.raises(ValueError, match=r"width 3 x height 1 must equal the number of points 4"):
        write_pcd(path, points, width=3, height=1)
    with pytest.raises(ValueError, match=r"field name 'a b' not allowed: it must be one ASCII"):
        write_pcd(path, points, {"a b": np.zeros(4)})
    with pytest.raises(ValueError, match=r"field name 'x' not allowed"):
        write_pcd(path, points, {"x": np.zeros(4)})
    with pytest.raises(ValueError, match=r"field 'c' has dtype complex128; allowed: float32"):
        write_pcd(path, points, {"c": np.zeros(4, complex)})
    with pytest.raises(ValueError, match=r"field 'label' has shape \(5,\); allowed: \(4,\) or"):
        write_pcd(path, points, {"label": np.zeros(5)})
    with pytest.raises(ValueError, match=r"xyz_dtype must be float32 or float64"):
        write_pcd(path, points, xyz_dtype=np.float16)
    with pytest.raises(ValueError, match=r"viewpoint must be 7 finite numbers"):
        write_pcd(path, points, viewpoint=[0, 0, 0])
    with pytest.raises(ValueError, match=r"colors must have one RGB triple per point"):
        write_ply(tmp_path / "w.ply", points, np.zeros((3, 3), np.uint8))
    with pytest.raises(ValueError, match=r"float colors must be finite and within \[0, 1\]"):
        write_ply(tmp_path / "w.ply", points, np.full((4, 3), 2.0))
