"""Writers and readers of PCD, PLY and NPY agree bit for bit; PCD files follow PCL's rules.

Clouds are generated from raw bit patterns (so NaN payloads, signed zeros, subnormals,
infinities and the extreme finite values all occur) and compared through integer views of
their bits. The PCD layout checks parse the written files by hand, from the PCD v0.7 rules
as PCL's ``PCDWriter`` writes them, not through our reader.
"""

from __future__ import annotations

import struct
import tracemalloc
from pathlib import Path

import lzf
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from geomodel_ros.tools.io import (
    read_npy,
    read_pcd,
    read_ply,
    write_npy,
    write_pcd,
    write_ply,
)

#: Bit patterns every float array draws from besides random ones: +-0, the smallest and
#: largest subnormal, the smallest normal, the largest finite (+-3.4e38 / 1.8e308), +-inf,
#: the canonical quiet NaN, a negative NaN with a payload and a signalling NaN.
SPECIAL_BITS = {
    4: [0x0, 0x80000000, 0x1, 0x007FFFFF, 0x00800000, 0x7F7FFFFF, 0xFF7FFFFF, 0x7F800000,
        0xFF800000, 0x7FC00000, 0xFFC01234, 0x7F800001],
    8: [0x0, 0x8000000000000000, 0x1, 0x000FFFFFFFFFFFFF, 0x0010000000000000,
        0x7FEFFFFFFFFFFFFF, 0xFFEFFFFFFFFFFFFF, 0x7FF0000000000000, 0xFFF0000000000000,
        0x7FF8000000000000, 0xFFF8000000001234, 0x7FF0000000000001],
}
UINT = {1: np.uint8, 2: np.uint16, 4: np.uint32, 8: np.uint64}
#: Field types per format: PCD stores I/U 1-8 bytes and F 4/8 with COUNT >= 1; PLY
#: char..double without 64-bit integers, one value per property.
PCD_TYPES = ["u1", "u2", "u4", "u8", "i1", "i2", "i4", "i8", "f4", "f8"]
PLY_TYPES = ["u1", "u2", "u4", "i1", "i2", "i4", "f4", "f8"]
FIELD_NAMES = ["label", "intensity", "ring", "t", "normal_x", "curvature"]


def widen(values: np.ndarray) -> np.ndarray:
    """Return float64 of ``values`` as the readers make it (signalling NaNs turn quiet)."""
    with np.errstate(invalid="ignore"):
        return values.astype(np.float64)


def bits(values: np.ndarray) -> np.ndarray:
    """View an array as unsigned integers of its item size (NaN payloads and -0 compare)."""
    values = np.ascontiguousarray(values)
    return values.view(UINT[values.dtype.itemsize])


@st.composite
def raw_array(draw: st.DrawFn, dtype: str, shape: tuple[int, ...]) -> np.ndarray:
    """Draw an array of ``dtype`` from random and special bit patterns."""
    size = np.dtype(dtype).itemsize
    top = (1 << (8 * size)) - 1
    pattern = st.integers(0, top)
    if dtype[0] == "f":
        pattern = st.one_of(pattern, st.sampled_from(SPECIAL_BITS[size]))
    count = int(np.prod(shape))
    words = draw(st.lists(pattern, min_size=count, max_size=count))
    return np.array(words, dtype=UINT[size]).view(np.dtype(dtype).newbyteorder("=")).reshape(
        shape
    )


@st.composite
def cloud_shape(draw: st.DrawFn) -> tuple[int, int]:
    """Draw (height, width): unorganized (1, N) with N from 0, or organized (H >= 2, W)."""
    if draw(st.booleans()):
        return 1, draw(st.integers(0, 12))
    return draw(st.integers(2, 4)), draw(st.integers(1, 5))


@st.composite
def pcd_cloud(draw: st.DrawFn) -> tuple[np.ndarray, dict[str, np.ndarray], int, int, str]:
    """Draw points (H, W, 3) or (N, 3), extra fields, width, height and the xyz dtype."""
    height, width = draw(cloud_shape())
    xyz = draw(st.sampled_from(["f4", "f8"]))
    n = height * width
    points = draw(raw_array(xyz, (n, 3)))
    names = draw(st.lists(st.sampled_from(FIELD_NAMES), max_size=3, unique=True))
    fields = {}
    for name in names:
        count = draw(st.integers(1, 3))
        shape = (n,) if count == 1 else (n, count)
        fields[name] = draw(raw_array(draw(st.sampled_from(PCD_TYPES)), shape))
    return points, fields, width, height, xyz


def canonical_nan(values: np.ndarray) -> np.ndarray:
    """Return ``values`` with every NaN replaced by the quiet NaN text ``nan`` reads as."""
    out = values.copy()
    if out.dtype.kind == "f":
        out[np.isnan(out)] = np.nan
    return out


SETTINGS = settings(
    max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)


# --------------------------------------------------------------------------------------------
# Round trips
# --------------------------------------------------------------------------------------------


@pytest.mark.parametrize("data", ["binary", "binary_compressed", "ascii"])
@SETTINGS
@given(cloud=pcd_cloud())
def test_pcd_round_trip_is_bit_exact(tmp_path: Path, data: str, cloud: tuple) -> None:
    points, fields, width, height, xyz = cloud
    path = tmp_path / f"{data}.pcd"
    write_pcd(
        path,
        points,
        fields,
        width=width,
        height=height,
        binary=data != "ascii",
        compressed=data == "binary_compressed",
        xyz_dtype=np.dtype(xyz),
    )
    back = read_pcd(path)
    # ascii stores every NaN as the text "nan" (PCL's rule): it reads back as the quiet NaN
    expect = canonical_nan if data == "ascii" else np.copy
    # the reader widens x y z to float64: exactly the float64 of each stored value
    assert np.array_equal(bits(back.points), bits(widen(expect(points))))
    assert (back.width, back.height) == (width, height)
    assert back.is_organized == (height > 1)
    assert list(back.fields) == list(fields)
    for name, values in fields.items():
        got = back.fields[name]
        assert got.dtype == values.dtype and got.shape == values.shape, name
        assert np.array_equal(bits(got), bits(expect(values))), name


@pytest.mark.parametrize("encoding", ["binary_little_endian", "binary_big_endian", "ascii"])
@SETTINGS
@given(data=st.data())
def test_ply_round_trip_is_bit_exact(tmp_path: Path, encoding: str, data: st.DataObject) -> None:
    n = data.draw(st.integers(0, 20))
    xyz = data.draw(st.sampled_from(["f4", "f8"]))
    points = data.draw(raw_array(xyz, (n, 3)))
    names = data.draw(st.lists(st.sampled_from(FIELD_NAMES), max_size=3, unique=True))
    fields = {k: data.draw(raw_array(data.draw(st.sampled_from(PLY_TYPES)), (n,))) for k in names}
    path = tmp_path / f"{encoding}.ply"
    write_ply(path, points, xyz_dtype=np.dtype(xyz), fields=fields, encoding=encoding)
    back = read_ply(path)
    expect = canonical_nan if encoding == "ascii" else np.copy
    assert np.array_equal(bits(back.points), bits(widen(expect(points))))
    assert (back.width, back.height) == (n, 1)
    assert list(back.fields) == list(fields)
    for name, values in fields.items():
        assert back.fields[name].dtype == values.dtype, name
        assert np.array_equal(bits(back.fields[name]), bits(expect(values))), name


@SETTINGS
@given(data=st.data())
def test_npy_round_trip_is_bit_exact(tmp_path: Path, data: st.DataObject) -> None:
    height, width = data.draw(cloud_shape())
    organized = height > 1
    shape = (height, width, 3) if organized else (width, 3)
    points = data.draw(raw_array(data.draw(st.sampled_from(["f4", "f8"])), shape))
    write_npy(tmp_path / "c.npy", points)
    back = read_npy(tmp_path / "c.npy")
    assert np.array_equal(bits(back.points), bits(widen(points).reshape(-1, 3)))
    assert (back.width, back.height) == (width, height)
    assert back.is_organized == organized


def test_colours_and_named_extremes_survive_every_format(tmp_path: Path) -> None:
    """The values the generators aim at, written once by hand: nothing may move."""
    f32 = np.array([[3.4028235e38, -3.4028235e38, -0.0], [1e-45, 1.1754942e-38, np.nan]],
                   dtype=np.float32)
    assert bits(f32)[0, 0] == 0x7F7FFFFF and bits(f32)[1, 0] == 0x1  # the intended values
    rgb = np.array([[255, 0, 7], [1, 2, 3]], dtype=np.uint8)
    for encoding in ("ascii", "binary_big_endian"):
        write_ply(tmp_path / "e.ply", f32, rgb, encoding=encoding)
        back = read_ply(tmp_path / "e.ply")
        assert np.array_equal(bits(back.points), bits(widen(f32)))
        assert np.array_equal(np.stack([back.fields[c] for c in ("red", "green", "blue")], 1), rgb)
    packed = np.array([0xFF102030, 0x00000001], dtype=np.uint32)
    for binary, compressed in ((False, False), (True, False), (True, True)):
        write_pcd(tmp_path / "e.pcd", f32, {"rgba": packed}, binary=binary, compressed=compressed)
        back = read_pcd(tmp_path / "e.pcd")
        assert np.array_equal(bits(back.points), bits(widen(f32)))
        assert np.array_equal(back.fields["rgba"], packed)


# --------------------------------------------------------------------------------------------
# PCL's format rules, checked on the written bytes
# --------------------------------------------------------------------------------------------

#: The header keywords in the order PCL's PCDWriter writes them (and its reader expects).
PCL_KEYWORDS = ["VERSION", "FIELDS", "SIZE", "TYPE", "COUNT", "WIDTH", "HEIGHT", "VIEWPOINT",
                "POINTS", "DATA"]
#: SIZE values PCL allows for each TYPE.
PCL_SIZES = {"F": {4, 8}, "I": {1, 2, 4, 8}, "U": {1, 2, 4, 8}}


def split_pcd(raw: bytes) -> tuple[dict[str, list[str]], list[str], bytes]:
    """Split a PCD file into its header entries, their keyword order and the data bytes."""
    entries: dict[str, list[str]] = {}
    order: list[str] = []
    pos = 0
    while "DATA" not in entries:
        end = raw.index(b"\n", pos) + 1
        line = raw[pos:end].decode("ascii")
        pos = end
        assert line.endswith("\n") and not line.endswith("\r\n")
        if line.startswith("#"):
            assert not order, "comments only before VERSION"
            continue
        keyword, *values = line.split()
        order.append(keyword)
        entries[keyword] = values
    return entries, order, raw[pos:]


def check_pcl_header(entries: dict[str, list[str]], order: list[str]) -> None:
    """Assert the header rules of PCD v0.7 as PCL writes and reads them."""
    assert order == PCL_KEYWORDS
    assert entries["VERSION"] == ["0.7"]
    fields = entries["FIELDS"]
    assert len(entries["SIZE"]) == len(entries["TYPE"]) == len(entries["COUNT"]) == len(fields)
    for size, type_, count in zip(entries["SIZE"], entries["TYPE"], entries["COUNT"]):
        assert int(size) in PCL_SIZES[type_] and int(count) >= 1
    width, height, points = (int(entries[k][0]) for k in ("WIDTH", "HEIGHT", "POINTS"))
    assert points == width * height
    assert len(entries["VIEWPOINT"]) == 7


def columns_le(points: np.ndarray, fields: dict[str, np.ndarray]) -> list[np.ndarray]:
    """Each field as (N, COUNT) little-endian values, x y z as float32, in file order."""
    xyz = points.reshape(-1, 3).astype("<f4")
    out = [xyz[:, 0:1], xyz[:, 1:2], xyz[:, 2:3]]
    n = xyz.shape[0]
    return out + [v.reshape(n, -1).astype(v.dtype.newbyteorder("<")) for v in fields.values()]


@pytest.fixture
def pcl_sample() -> tuple[np.ndarray, dict[str, np.ndarray]]:
    rng = np.random.default_rng(17)
    points = rng.normal(size=(3, 4, 3)).astype(np.float32)
    points[0, 1] = np.nan  # a hole of the organized image
    points[2, 3, 1] = -np.nan
    fields = {
        "label": rng.integers(0, 2**32, size=(3, 4), dtype=np.uint32),
        "normal": rng.normal(size=(3, 4, 3)),  # float64, COUNT 3
        "flag": rng.integers(-128, 128, size=(3, 4), dtype=np.int8),
    }
    return points, fields


def test_binary_pcd_follows_pcl_layout(tmp_path: Path, pcl_sample: tuple) -> None:
    points, fields = pcl_sample
    write_pcd(tmp_path / "b.pcd", points, fields)
    entries, order, body = split_pcd((tmp_path / "b.pcd").read_bytes())
    check_pcl_header(entries, order)
    assert entries["FIELDS"] == ["x", "y", "z", "label", "normal", "flag"]
    assert entries["SIZE"] == ["4", "4", "4", "4", "8", "1"]
    assert entries["TYPE"] == ["F", "F", "F", "U", "F", "I"]
    assert entries["COUNT"] == ["1", "1", "1", "1", "3", "1"]
    assert (entries["WIDTH"], entries["HEIGHT"], entries["POINTS"]) == (["4"], ["3"], ["12"])
    assert entries["DATA"] == ["binary"]
    # points one after another, each with its fields in FIELDS order (array of structures)
    rows = [c.view(np.uint8).reshape(12, -1) for c in columns_le(points, fields)]
    assert body == np.hstack(rows).tobytes()


def test_compressed_pcd_follows_pcl_layout(tmp_path: Path, pcl_sample: tuple) -> None:
    points, fields = pcl_sample
    write_pcd(tmp_path / "c.pcd", points, fields, compressed=True)
    entries, order, body = split_pcd((tmp_path / "c.pcd").read_bytes())
    check_pcl_header(entries, order)
    assert entries["DATA"] == ["binary_compressed"]
    compressed, uncompressed = struct.unpack("<II", body[:8])
    assert uncompressed == 12 * (4 + 4 + 4 + 4 + 3 * 8 + 1)
    assert compressed == len(body) - 8
    payload = lzf.decompress(body[8:], uncompressed)
    # each field's values contiguous, field after field (structure of arrays)
    assert payload == b"".join(c.tobytes() for c in columns_le(points, fields))


def test_compressed_pcd_of_incompressible_and_empty_data(tmp_path: Path) -> None:
    noise = np.random.default_rng(3).integers(0, 2**32, size=(1000, 3), dtype=np.uint32)
    write_pcd(tmp_path / "n.pcd", noise.view(np.float32), compressed=True)
    _, _, body = split_pcd((tmp_path / "n.pcd").read_bytes())
    compressed, uncompressed = struct.unpack("<II", body[:8])
    assert uncompressed == 12000 and compressed == len(body) - 8
    assert lzf.decompress(body[8:], uncompressed) == noise.T.astype("<u4").tobytes()
    write_pcd(tmp_path / "e.pcd", np.zeros((0, 3)), compressed=True)
    entries, order, body = split_pcd((tmp_path / "e.pcd").read_bytes())
    check_pcl_header(entries, order)
    assert entries["POINTS"] == ["0"] and body == struct.pack("<II", 0, 0)


def test_ascii_pcd_follows_pcl_layout(tmp_path: Path, pcl_sample: tuple) -> None:
    points, fields = pcl_sample
    write_pcd(tmp_path / "a.pcd", points, fields, binary=False)
    entries, order, body = split_pcd((tmp_path / "a.pcd").read_bytes())
    check_pcl_header(entries, order)
    assert entries["DATA"] == ["ascii"]
    lines = body.decode("ascii").split("\n")
    assert lines[-1] == "" and len(lines) == 13  # one line per point, newline-terminated
    columns = [c[:, k] for c in columns_le(points, fields) for k in range(c.shape[1])]
    for i, line in enumerate(lines[:-1]):
        tokens = line.split(" ")
        assert len(tokens) == len(columns) == 1 + 1 + 1 + 1 + 3 + 1
        for token, column in zip(tokens, columns):
            value = column[i]
            if column.dtype.kind != "f":
                assert int(token) == value  # integers in full
            elif np.isnan(value):
                assert token == "nan"  # PCL writes NaN of any sign as "nan"
            else:  # a decimal that reads back to the same float32 / float64
                assert column.dtype.type(float(token)) == value and "nan" not in token
    assert lines[1].split(" ")[:3] == ["nan", "nan", "nan"]
    assert lines[11].split(" ")[1] == "nan"  # a negative NaN too


def test_ascii_float32_needs_nine_digits(tmp_path: Path) -> None:
    """8 digits (PCL's default precision) lose float32 bits; the writer keeps them."""
    value = np.float32(15991.7294921875)  # exactly a float32: 15991 + 747/1024
    assert float(value) == 15991.7294921875
    assert np.float32(float(f"{float(value):.8g}")) != value  # the failure 9 digits avoid
    write_pcd(tmp_path / "a.pcd", np.full((1, 3), value), binary=False)
    assert read_pcd(tmp_path / "a.pcd").points[0, 0] == float(value)


# --------------------------------------------------------------------------------------------
# Memory while reading
# --------------------------------------------------------------------------------------------

#: Points of the memory test cloud: large next to the readers' fixed buffers (1 MiB), small
#: enough to write and read in about a second per format (ascii, slower, uses a quarter).
MEMORY_POINTS = 400_000


def peak_while(read, path: Path) -> tuple[int, int]:
    """Return the peak traced bytes while ``read(path)`` runs and the bytes of its result."""
    tracemalloc.start()
    try:
        tracemalloc.reset_peak()
        before = tracemalloc.get_traced_memory()[0]
        cloud = read(path)
        peak = tracemalloc.get_traced_memory()[1] - before
    finally:
        tracemalloc.stop()
    result = cloud.points.nbytes + sum(v.nbytes for v in cloud.fields.values())
    return peak, result


@pytest.mark.parametrize(
    "kind", ["pcd binary", "pcd binary_compressed", "pcd ascii", "ply binary", "ply ascii", "npy"]
)
def test_reading_holds_at_most_the_result_and_one_file(tmp_path: Path, kind: str) -> None:
    fmt, _, data = kind.partition(" ")
    n = MEMORY_POINTS // 4 if data == "ascii" else MEMORY_POINTS
    rng = np.random.default_rng(5)
    points = rng.normal(size=(n, 3)).astype(np.float32)
    label = rng.integers(0, 50, size=n, dtype=np.uint32)
    path = tmp_path / f"big.{fmt}"
    if fmt == "pcd":
        write_pcd(path, points, {"label": label}, binary=data != "ascii",
                  compressed=data == "binary_compressed")
        read, data_bytes = read_pcd, path.stat().st_size
        if data == "binary_compressed":  # what the file holds, uncompressed
            data_bytes = n * 16
    elif fmt == "ply":
        write_ply(path, points, fields={"label": label},
                  encoding="ascii" if data == "ascii" else "binary_little_endian")
        read, data_bytes = read_ply, path.stat().st_size
    else:
        write_npy(path, points)
        read, data_bytes = read_npy, path.stat().st_size
    peak, result = peak_while(read, path)
    # the result itself, plus at most about one copy of the file's data (e.g. the
    # decompressed payload), never the whole file held twice on top of the result
    assert peak <= result + 1.1 * data_bytes, (peak, result, data_bytes)
    if data in ("binary", ""):  # binary and npy: the result and small buffers only
        assert peak <= result + (2 << 20) + 0.02 * data_bytes, (peak, result)


def test_open3d_reads_our_compressed_pcd(tmp_path: Path) -> None:
    """An independent PCD reader (open3d's, from PCL's code) reads binary_compressed back."""
    o3d = pytest.importorskip("open3d")
    points = np.random.default_rng(8).normal(size=(500, 3)).astype(np.float32)
    write_pcd(tmp_path / "c.pcd", points, {"label": np.arange(500, dtype=np.uint32)},
              compressed=True)
    theirs = np.asarray(o3d.io.read_point_cloud(str(tmp_path / "c.pcd")).points)
    assert np.array_equal(theirs, points.astype(np.float64))


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"encoding": "binary"}, r"encoding 'binary' not allowed; allowed: ascii, binary_l"),
        ({"fields": {"t": np.zeros(4, np.uint64)}}, r"field 't' has dtype uint64; allowed:"),
        ({"fields": {"t": np.zeros((4, 2), np.uint8)}}, r"field 't' has shape \(4, 2\)"),
        ({"fields": {"x": np.zeros(4, np.uint8)}}, r"field name 'x' not allowed"),
    ],
)
def test_ply_writer_refuses_what_ply_cannot_hold(tmp_path: Path, kwargs: dict, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        write_ply(tmp_path / "r.ply", np.zeros((4, 3)), **kwargs)
    assert not (tmp_path / "r.ply").exists()  # refused before anything is written


def test_pcd_writer_refuses_compressed_ascii(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match=r"compressed=True needs binary=True"):
        write_pcd(tmp_path / "r.pcd", np.zeros((2, 3)), binary=False, compressed=True)
    assert not (tmp_path / "r.pcd").exists()
