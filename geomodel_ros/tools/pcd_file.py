"""PCD files (PCL's Point Cloud Data format, v0.6 and v0.7): read and write.

:func:`read_pcd` reads ``DATA ascii``, ``binary`` and ``binary_compressed`` and keeps every
field (e.g. the ``label`` of the OSD scenes); :func:`write_pcd` writes ``ascii`` or
``binary``. The LZF stream of ``binary_compressed`` is decoded by liblzf (package
``python-lzf``); everything else is our own thin layer over numpy, because the point is
the checks: every header entry is validated and every size the header implies is compared
with the file before any data are touched, so a corrupt or truncated file raises
:class:`CloudFileError` naming what was wrong, and nothing reads beyond what the file holds.
"""

from __future__ import annotations

import os
import struct
import warnings
from collections.abc import Mapping
from dataclasses import dataclass
from io import TextIOWrapper
from typing import BinaryIO, NamedTuple

import lzf
import numpy as np
from numpy.typing import ArrayLike, DTypeLike, NDArray

from geomodel_ros.tools.cloud_file import (
    Cloud,
    CloudFileError,
    PathLike,
    ascii_text,
    count_lines,
    open_cloud,
    read_records,
    resolve_shape,
    to_xyz,
)

# --------------------------------------------------------------------------------------------
# LZF
# --------------------------------------------------------------------------------------------

#: Most output bytes an LZF stream yields per input byte: its longest token, a 3-byte
#: back-reference, produces 264 bytes. A size claiming more cannot be right, and refusing it
#: keeps a corrupt header from making the decoder allocate memory the file cannot fill.
_LZF_MAX_EXPANSION = 88
#: Longest literal run of an LZF token: incompressible data grow by one control byte per
#: this many bytes, which bounds the compressed size the writer allows for.
_LZF_LITERAL_RUN = 32


def lzf_decompress(data: bytes | bytearray | memoryview, expected_size: int) -> bytes:
    """Decompress an LZF (liblzf) stream, as used by PCD ``binary_compressed``.

    Parameters
    ----------
    data : bytes-like
        The compressed stream.
    expected_size : int
        The size of the decompressed data, in bytes.

    Returns
    -------
    bytes
        Exactly ``expected_size`` bytes.

    Raises
    ------
    CloudFileError
        If the stream is truncated inside a token, refers back before the start of the
        output, or decompresses to a size other than ``expected_size``.

    Notes
    -----
    liblzf (``python-lzf``) decodes; it only says *that* a stream is bad, so a bad stream
    is then walked token by token (sizes only, nothing copied) by :func:`_lzf_defect` to
    say *where* and *what*.
    """
    if expected_size < 0:
        raise CloudFileError(f"LZF expected size must be >= 0, got {expected_size}")
    stream = bytes(data)
    out = b"" if expected_size == 0 and not stream else None
    if 0 < expected_size <= _LZF_MAX_EXPANSION * len(stream):
        try:
            out = lzf.decompress(stream, expected_size)  # None when it would exceed the size
        except ValueError:  # liblzf: back-reference before the start, or input overrun
            out = None
    if out is None or len(out) != expected_size:
        raise _lzf_defect(stream, expected_size)
    return out


def _lzf_defect(stream: bytes, expected_size: int) -> CloudFileError:
    """Describe the first defect of an LZF stream that liblzf rejected.

    A control byte ``c < 32`` is followed by a literal run of ``c + 1`` bytes. Otherwise
    it is a back-reference of length ``(c >> 5) + 2`` (``c >> 5 == 7``: plus the next
    byte) reaching ``((c & 31) << 8) + next byte + 1`` bytes back from the output end.
    """
    size_in = len(stream)
    ip = 0  # input position
    op = 0  # output size so far
    while ip < size_in:
        ctrl = stream[ip]
        if ctrl < 32:  # literal run of ctrl + 1 bytes
            if ip + ctrl + 2 > size_in:
                return CloudFileError(
                    f"corrupt LZF data: literal run of {ctrl + 1} bytes at input byte {ip} "
                    f"goes past the end of the {size_in}-byte stream"
                )
            ip += ctrl + 2
            op += ctrl + 1
            continue
        extra = int(ctrl >= 224)  # long form: one more length byte
        if ip + 2 + extra > size_in:
            return CloudFileError(
                f"corrupt LZF data: stream of {size_in} bytes ends inside a back-reference token"
            )
        length = stream[ip + 1] + 9 if extra else (ctrl >> 5) + 2
        dist = ((ctrl & 31) << 8) + stream[ip + 1 + extra] + 1
        ip += 2 + extra
        if dist > op:
            return CloudFileError(
                f"corrupt LZF data: back-reference at input byte {ip} points {dist} "
                f"bytes back but only {op} bytes have been produced"
            )
        op += length
    return CloudFileError(f"corrupt LZF data: decompressed to {op} bytes, expected {expected_size}")


# --------------------------------------------------------------------------------------------
# Header
# --------------------------------------------------------------------------------------------

_PCD_KEYWORDS = (
    "VERSION",
    "FIELDS",
    "SIZE",
    "TYPE",
    "COUNT",
    "WIDTH",
    "HEIGHT",
    "VIEWPOINT",
    "POINTS",
    "DATA",
)
_PCD_VERSIONS = {"0.7": "0.7", ".7": "0.7", "0.6": "0.6", ".6": "0.6"}
_PCD_DATA = ("ascii", "binary", "binary_compressed")
_PCD_SIZES = {"F": (4, 8), "I": (1, 2, 4, 8), "U": (1, 2, 4, 8)}
_PCD_KIND = {"F": "f", "I": "i", "U": "u"}
_COLOR_FIELDS = ("rgb", "rgba")
#: Header lines before DATA are short; a file without DATA in this many bytes is not a PCD.
MAX_HEADER_BYTES = 1 << 20
#: Largest COUNT accepted (PCL's largest standard field, a 308-bin histogram, is far below).
_PCD_MAX_COUNT = 1 << 20


@dataclass(frozen=True)
class _PcdHeader:
    version: str
    names: tuple[str, ...]
    sizes: tuple[int, ...]
    types: tuple[str, ...]
    counts: tuple[int, ...]
    width: int
    height: int
    viewpoint: NDArray[np.float64] | None
    points: int
    data: str

    def dtypes(self) -> list[np.dtype]:
        """Little-endian scalar dtype of each field."""
        return [
            np.dtype(f"<{_PCD_KIND[t]}{s}") for t, s in zip(self.types, self.sizes, strict=True)
        ]

    def record_dtype(self) -> np.dtype:
        """Packed structured dtype of one point (``_`` padding fields get unique names)."""
        formats: list[tuple] = []
        for index, (name, dtype, count) in enumerate(
            zip(self.names, self.dtypes(), self.counts, strict=True)
        ):
            key = name if name != "_" else f" pad {index}"  # cannot clash: names have no spaces
            formats.append((key, dtype, (count,)) if count > 1 else (key, dtype))
        return np.dtype(formats)


def _parse_int(path: PathLike, keyword: str, token: str, minimum: int) -> int:
    try:
        value = int(token)
    except ValueError:
        value = minimum - 1
    if value < minimum:
        raise CloudFileError(
            f"{os.fspath(path)}: PCD header {keyword} value {token!r} is not an integer >= "
            f"{minimum}"
        )
    return value


def _header_entries(buf: bytearray, name: str) -> tuple[dict[str, list[str]], int]:
    """Split the header into keyword -> words; return it and the offset of the data."""
    entries: dict[str, list[str]] = {}
    pos = 0
    line_no = 0
    while "DATA" not in entries:
        if pos >= len(buf) or pos > MAX_HEADER_BYTES:
            raise CloudFileError(
                f"{name}: PCD header ends without a DATA line (not a PCD file, or truncated)"
            )
        newline = buf.find(b"\n", pos)
        end = len(buf) if newline < 0 else newline + 1
        raw = bytes(buf[pos:end])
        line_no += 1
        pos = end
        try:
            line = raw.decode("ascii").strip()
        except UnicodeDecodeError:
            raise CloudFileError(
                f"{name}: line {line_no} of the PCD header is not ASCII text (not a PCD file?)"
            ) from None
        if not line or line.startswith("#"):
            continue
        keyword, *values = line.split()
        keyword = keyword.upper()
        if keyword not in _PCD_KEYWORDS:
            raise CloudFileError(
                f"{name}: unknown PCD header keyword {keyword[:40]!r} on line {line_no}; "
                f"allowed: {' '.join(_PCD_KEYWORDS)}"
            )
        if keyword in entries:
            raise CloudFileError(f"{name}: PCD header keyword {keyword} given twice")
        entries[keyword] = values
    return entries, pos


def _field_layout(
    entries: dict[str, list[str]], path: PathLike
) -> tuple[tuple[str, ...], tuple[int, ...], tuple[str, ...], tuple[int, ...]]:
    """Check FIELDS, SIZE, TYPE and COUNT; return names, sizes, types and counts."""
    name = os.fspath(path)
    for keyword in ("FIELDS", "SIZE", "TYPE"):
        if not entries.get(keyword):
            raise CloudFileError(f"{name}: PCD header has no {keyword} line (or it is empty)")
    names = tuple(entries["FIELDS"])
    counts_tokens = entries.get("COUNT", ["1"] * len(names))
    for keyword, tokens in (
        ("SIZE", entries["SIZE"]),
        ("TYPE", entries["TYPE"]),
        ("COUNT", counts_tokens),
    ):
        if len(tokens) != len(names):
            raise CloudFileError(
                f"{name}: PCD header {keyword} has {len(tokens)} entries but FIELDS has "
                f"{len(names)}; they must match"
            )
    sizes = tuple(_parse_int(path, "SIZE", t, 1) for t in entries["SIZE"])
    types = tuple(t.upper() for t in entries["TYPE"])
    counts = tuple(_parse_int(path, "COUNT", t, 1) for t in counts_tokens)
    for field_name, count in zip(names, counts, strict=True):
        if count > _PCD_MAX_COUNT:
            raise CloudFileError(
                f"{name}: field {field_name!r} has COUNT {count}; allowed: 1 to {_PCD_MAX_COUNT}"
            )
    for field_name, type_, size in zip(names, types, sizes, strict=True):
        if type_ not in _PCD_SIZES:
            raise CloudFileError(
                f"{name}: field {field_name!r} has TYPE {type_!r}; allowed: F, I, U"
            )
        if size not in _PCD_SIZES[type_]:
            raise CloudFileError(
                f"{name}: field {field_name!r} of TYPE {type_} has SIZE {size}; allowed: "
                f"{', '.join(map(str, _PCD_SIZES[type_]))}"
            )
    _check_field_names(names, name)
    return names, sizes, types, counts


def _check_field_names(names: tuple[str, ...], name: str) -> None:
    """Refuse FIELDS that repeat a name or lack x, y or z."""
    seen = [n for n in names if n != "_"]
    if len(set(seen)) != len(seen):
        duplicates = sorted({n for n in seen if seen.count(n) > 1})
        raise CloudFileError(f"{name}: PCD FIELDS names {duplicates} more than once")
    missing = [axis for axis in "xyz" if axis not in names]
    if missing:
        raise CloudFileError(
            f"{name}: PCD FIELDS {' '.join(names)!r} lack {', '.join(missing)}; "
            "x, y and z are required"
        )


def _organization(entries: dict[str, list[str]], path: PathLike) -> tuple[int, int, int]:
    """Check WIDTH, HEIGHT and POINTS; return width, height and the number of points."""
    name = os.fspath(path)

    def single(keyword: str) -> int | None:
        tokens = entries.get(keyword)
        if tokens is None:
            return None
        if len(tokens) != 1:
            raise CloudFileError(
                f"{name}: PCD header {keyword} must be one integer, got {' '.join(tokens)!r}"
            )
        return _parse_int(path, keyword, tokens[0], 0)

    width, height, points = single("WIDTH"), single("HEIGHT"), single("POINTS")
    if width is None and points is None:
        raise CloudFileError(f"{name}: PCD header has neither WIDTH nor POINTS")
    if height is None:
        height = 1
    if width is None:
        assert points is not None
        width = points // height if height else 0
    if points is None:
        points = width * height
    if width * height != points:
        raise CloudFileError(
            f"{name}: PCD header WIDTH {width} x HEIGHT {height} != POINTS {points}; "
            "they must agree"
        )
    return width, height, points


def _viewpoint(entries: dict[str, list[str]], name: str) -> NDArray[np.float64] | None:
    """Check VIEWPOINT; return it as 7 numbers, or None when the header has none."""
    if "VIEWPOINT" not in entries:
        return None
    try:
        viewpoint = np.array([float(t) for t in entries["VIEWPOINT"]], dtype=np.float64)
    except ValueError:
        viewpoint = np.zeros(0)
    if viewpoint.shape != (7,) or not np.isfinite(viewpoint).all():
        raise CloudFileError(
            f"{name}: PCD VIEWPOINT {' '.join(entries['VIEWPOINT'])!r} must be 7 finite "
            "numbers (tx ty tz qw qx qy qz)"
        )
    return viewpoint


def _parse_pcd_header(buf: bytearray, path: PathLike) -> tuple[_PcdHeader, int]:
    """Parse and check the header; return it and the offset of the first data byte."""
    name = os.fspath(path)
    entries, data_start = _header_entries(buf, name)
    version = _PCD_VERSIONS.get(" ".join(entries.get("VERSION", ["0.7"])))
    if version is None:
        raise CloudFileError(
            f"{name}: unsupported PCD VERSION {' '.join(entries['VERSION'])!r}; "
            "supported: 0.6, 0.7"
        )
    data = " ".join(entries["DATA"]).lower()
    if data not in _PCD_DATA:
        raise CloudFileError(
            f"{name}: unsupported PCD DATA {' '.join(entries['DATA'])!r}; "
            f"allowed: {', '.join(_PCD_DATA)}"
        )
    names, sizes, types, counts = _field_layout(entries, path)
    width, height, points = _organization(entries, path)
    header = _PcdHeader(
        version, names, sizes, types, counts, width, height, _viewpoint(entries, name), points,
        data,
    )
    return header, data_start


# --------------------------------------------------------------------------------------------
# Reading
# --------------------------------------------------------------------------------------------


def read_pcd(path: PathLike) -> Cloud:
    """Read a PCD file (v0.6 or v0.7; DATA ascii, binary or binary_compressed).

    Parameters
    ----------
    path : str or os.PathLike
        The file.

    Returns
    -------
    Cloud
        ``points`` (N, 3) float64 [m] from the x, y, z fields (NaN kept), every other field
        in ``fields`` (``_`` padding dropped; ``rgb``/``rgba`` as raw uint32 bits),
        ``width``/``height`` and ``viewpoint`` from the header (None when absent).

    Raises
    ------
    CloudFileError
        If the file is missing, empty, has a malformed header (unknown keyword, FIELDS /
        SIZE / TYPE / COUNT disagreeing, no x y z, WIDTH x HEIGHT != POINTS, unsupported
        VERSION, TYPE, SIZE or DATA) or its data are truncated or corrupt.

    Notes
    -----
    Memory: the file is never held whole. ``binary`` records are read through a small
    buffer straight into the output arrays (every field owns its memory); ``ascii`` text
    is parsed from the file in chunks; ``binary_compressed`` holds the LZF stream
    (``uint32`` compressed and uncompressed sizes, little endian, then the data), then the
    decompressed data (the fields one after another, structure of arrays; a COUNT K field
    is N x K values, point after point) while the fields are copied out of it. Bytes after
    the data (PCL pads files to a page) are ignored.
    """
    stream, size, head = open_cloud(path)
    with stream:
        header, start = _parse_pcd_header(head, path)
        del head
        if header.data == "binary":
            return _read_pcd_binary(stream, size, start, header, path)
        if header.data == "binary_compressed":
            return _read_pcd_compressed(stream, size, start, header, path)
        return _read_pcd_ascii(stream, size, start, header, path)


def _columns_to_cloud(
    path: PathLike, header: _PcdHeader, columns: dict[str, np.ndarray]
) -> Cloud:
    """Build the Cloud from one array per (non-padding) field, first axis N."""
    points = to_xyz(path, (columns.pop("x"), columns.pop("y"), columns.pop("z")))
    return _pcd_cloud(header, points, columns)


def _pcd_cloud(header: _PcdHeader, points: np.ndarray, columns: dict[str, np.ndarray]) -> Cloud:
    """Build the Cloud from the points and the other fields (colours as raw uint32 bits)."""
    for color in _COLOR_FIELDS:
        values = columns.get(color)
        if values is not None and values.dtype.itemsize == 4 and values.dtype != np.uint32:
            columns[color] = values.view(np.uint32)
    return Cloud(points, columns, header.width, header.height, header.viewpoint)


def _read_pcd_binary(
    stream: BinaryIO, size: int, start: int, header: _PcdHeader, path: PathLike
) -> Cloud:
    dtype = header.record_dtype()
    needed = header.points * dtype.itemsize
    available = size - start
    if available < needed:
        raise CloudFileError(
            f"{os.fspath(path)}: truncated PCD: DATA binary needs {needed} bytes "
            f"({header.points} points of {dtype.itemsize} bytes), the file has {available}"
        )
    points, columns = read_records(
        stream, path, start, dtype, header.points, lambda key: not key.startswith(" ")
    )
    return _pcd_cloud(header, points, columns)


def _compressed_payload(
    stream: BinaryIO, size: int, start: int, points: int, point_size: int, name: str
) -> bytes:
    """Check the two sizes before the LZF stream, then decompress it (``points`` records)."""
    expected = points * point_size
    if size - start < 8:
        if expected == 0:
            return b""
        raise CloudFileError(
            f"{name}: truncated PCD: DATA binary_compressed has {size - start} bytes, "
            "needs at least the 8-byte size header"
        )
    stream.seek(start)
    compressed_size, uncompressed_size = struct.unpack("<II", stream.read(8))
    if uncompressed_size != expected:
        raise CloudFileError(
            f"{name}: corrupt PCD: binary_compressed uncompressed size {uncompressed_size} "
            f"!= {expected} ({points} points of {point_size} bytes)"
        )
    available = size - start - 8
    if compressed_size > available:
        raise CloudFileError(
            f"{name}: truncated PCD: binary_compressed says {compressed_size} compressed "
            f"bytes, the file has {available}"
        )
    try:
        return lzf_decompress(stream.read(compressed_size), expected)
    except CloudFileError as exc:
        raise CloudFileError(f"{name}: {exc}") from None


def _read_pcd_compressed(
    stream: BinaryIO, size: int, start: int, header: _PcdHeader, path: PathLike
) -> Cloud:
    dtypes = header.dtypes()
    point_size = sum(d.itemsize * c for d, c in zip(dtypes, header.counts, strict=True))
    payload = _compressed_payload(
        stream, size, start, header.points, point_size, os.fspath(path)
    )
    columns: dict[str, np.ndarray] = {}
    offset = 0
    for field_name, dtype, count in zip(header.names, dtypes, header.counts, strict=True):
        values = np.frombuffer(payload, dtype=dtype, count=header.points * count, offset=offset)
        offset += values.nbytes
        if field_name == "_":
            continue
        if field_name not in ("x", "y", "z"):  # own, writable memory, not the whole payload
            values = values.copy()
        columns[field_name] = values.reshape(header.points, count) if count > 1 else values
    return _columns_to_cloud(path, header, columns)


def _read_pcd_ascii(
    stream: BinaryIO, size: int, start: int, header: _PcdHeader, path: PathLike
) -> Cloud:
    name = os.fspath(path)
    # Parse colour fields declared F as float64: PCL writes them as the packed uint32
    # integer (newer PCL) or as the float value of the bits (older writers).
    parse_types: list[tuple] = []
    for index, (field_name, dtype, count) in enumerate(
        zip(header.names, header.dtypes(), header.counts, strict=True)
    ):
        if field_name in _COLOR_FIELDS and dtype.kind == "f":
            dtype = np.dtype(np.float64)
        key = field_name if field_name != "_" else f" pad {index}"
        parse_types.append((key, dtype, (count,)) if count > 1 else (key, dtype))
    dtype = np.dtype(parse_types)
    lines = count_lines(stream, start, size)
    if lines < header.points:  # checked first: loadtxt allocates max_rows rows up front
        raise CloudFileError(
            f"{name}: truncated PCD: DATA ascii has {lines} lines, POINTS says {header.points}"
        )
    if header.points == 0:
        records = np.zeros(0, dtype=dtype)
    else:
        records = _parse_ascii(stream, start, dtype, header.points, name)
        if records.shape[0] != header.points:
            raise CloudFileError(
                f"{name}: truncated PCD: DATA ascii has {records.shape[0]} rows, POINTS says "
                f"{header.points}"
            )
    columns: dict[str, np.ndarray] = {}
    for field_name, dtype_ in zip(header.names, header.dtypes(), strict=True):
        if field_name == "_":
            continue
        values = records[field_name]
        if field_name in _COLOR_FIELDS and dtype_.kind == "f":
            values = _ascii_color_bits(values, dtype_)
        # x y z go into the points as they are; other fields get their own memory
        if field_name not in ("x", "y", "z"):
            values = np.ascontiguousarray(values)
        columns[field_name] = values
    return _columns_to_cloud(path, header, columns)


def _parse_ascii(
    stream: BinaryIO, start: int, dtype: np.dtype, points: int, name: str
) -> np.ndarray:
    """Parse ``points`` text lines from ``start`` into records, reading the file in chunks."""
    stream.seek(start)
    text = TextIOWrapper(stream, encoding="ascii", newline="\n")  # type: ignore[arg-type]
    try:
        with warnings.catch_warnings():  # an empty DATA section is reported by the caller
            warnings.simplefilter("ignore", UserWarning)
            return np.loadtxt(text, dtype=dtype, ndmin=1, max_rows=points, comments=None)
    except UnicodeDecodeError:
        raise CloudFileError(f"{name}: PCD DATA ascii section is not ASCII text") from None
    except ValueError as exc:
        raise CloudFileError(f"{name}: corrupt PCD DATA ascii: {exc}") from None
    finally:
        text.detach()  # leave the file to its owner


def _ascii_color_bits(values: np.ndarray, dtype: np.dtype) -> np.ndarray:
    """Return the raw bits of a float-declared ascii colour column (see `_read_pcd_ascii`)."""
    finite = np.isfinite(values)
    as_int = finite.all() and np.all(values == np.round(values))
    as_int = bool(as_int and values.size and values.min() >= 0 and values.max() < 2.0**32)
    if as_int and dtype.itemsize == 4:
        return values.astype(np.uint32)
    return values.astype(dtype)


# --------------------------------------------------------------------------------------------
# Writing
# --------------------------------------------------------------------------------------------


class _Column(NamedTuple):
    """One field as written: its values (N,) or (N, COUNT) and its header entries."""

    name: str
    values: np.ndarray
    dtype: np.dtype  # little-endian storage type
    type_: str
    size: int
    count: int


def _pcd_type(dtype: np.dtype, what: str) -> tuple[str, int]:
    """Return the TYPE letter and SIZE of a numpy dtype, or raise ValueError."""
    if dtype.kind == "b":
        return "U", 1
    kind = {"f": "F", "i": "I", "u": "U"}.get(dtype.kind)
    if kind is None or dtype.itemsize not in _PCD_SIZES[kind]:
        raise ValueError(
            f"{what} has dtype {dtype}; allowed: float32, float64, int8/16/32/64, "
            "uint8/16/32/64, bool"
        )
    return kind, dtype.itemsize


def _format_number(value: float) -> str:
    return np.format_float_positional(float(value), trim="-")


def _field_column(field_name: object, raw: ArrayLike, n: int, width: int, height: int) -> _Column:
    """Check one extra field of :func:`write_pcd` and return it as a column."""
    if (
        not isinstance(field_name, str)
        or not field_name
        or field_name.split() != [field_name]
        or not field_name.isascii()
        or field_name in ("x", "y", "z", "_")
    ):
        raise ValueError(
            f"field name {field_name!r} not allowed: it must be one ASCII word other "
            "than x, y, z and _"
        )
    values = np.asarray(raw)
    for lead in ((n,), (height, width)):  # per point, or per pixel
        if values.shape[: len(lead)] == lead and values.ndim <= len(lead) + 1:
            break
    else:
        raise ValueError(
            f"field {field_name!r} has shape {values.shape}; allowed: ({n},) or ({n}, K), "
            f"or ({height}, {width}) or ({height}, {width}, K), to match the points"
        )
    count = 1 if values.ndim == len(lead) else int(values.shape[-1])
    values = values.reshape(n, count)
    if count < 1:
        raise ValueError(f"field {field_name!r} has COUNT 0; it needs at least 1 value")
    type_, size = _pcd_type(values.dtype, f"field {field_name!r}")
    if values.dtype.kind == "b":
        values = values.astype(np.uint8)
    return _Column(
        field_name,
        values if count > 1 else values[:, 0],
        values.dtype.newbyteorder("<"),
        type_,
        size,
        count,
    )


def _pcd_header(
    columns: list[_Column], width: int, height: int, viewpoint: np.ndarray, data: str
) -> bytes:
    """Return the v0.7 header text, ending with the DATA line."""
    lines = [
        "# .PCD v0.7 - Point Cloud Data file format",
        "VERSION 0.7",
        "FIELDS " + " ".join(c.name for c in columns),
        "SIZE " + " ".join(str(c.size) for c in columns),
        "TYPE " + " ".join(c.type_ for c in columns),
        "COUNT " + " ".join(str(c.count) for c in columns),
        f"WIDTH {width}",
        f"HEIGHT {height}",
        "VIEWPOINT " + " ".join(_format_number(v) for v in viewpoint),
        f"POINTS {width * height}",
        f"DATA {data}",
        "",
    ]
    return "\n".join(lines).encode("ascii")


def write_pcd(
    path: PathLike,
    points: ArrayLike,
    fields: Mapping[str, ArrayLike] | None = None,
    *,
    width: int | None = None,
    height: int | None = None,
    binary: bool = True,
    viewpoint: ArrayLike | None = None,
    xyz_dtype: DTypeLike = np.float32,
    compressed: bool = False,
) -> None:
    """Write a PCD v0.7 file, ``DATA binary`` (default), ``binary_compressed`` or ``ascii``.

    Parameters
    ----------
    path : str or os.PathLike
        Output file (overwritten).
    points : (N, 3) or (H, W, 3) array_like [m]
        Point coordinates; NaN/inf are written as they are. An (H, W, 3) array makes an
        organized cloud of width W and height H.
    fields : mapping of str to array_like, optional
        Extra fields written after x y z in this order: shape (N,) or (N, K), or (H, W) or
        (H, W, K) for an organized cloud; K > 1 becomes COUNT K. Allowed dtypes: float32,
        float64, int8..int64, uint8..uint64, bool (written as U 1). Names must be single
        words other than x, y, z and ``_``. E.g. ``{"label": labels.astype(np.uint32),
        "rgb": packed_uint32}``.
    width, height : int, optional
        Organization of (N, 3) points; ``width * height`` must be N. Default: width N,
        height 1 (or the other one inferred when only one is given).
    binary : bool
        ``DATA binary`` when True, else ``DATA ascii`` (floats with round-trip precision;
        ``rgb``/``rgba`` written as the packed uint32 integer, like PCL).
    viewpoint : (7,) array_like, optional
        ``tx ty tz qw qx qy qz``; default identity ``0 0 0 1 0 0 0``.
    xyz_dtype : {numpy.float32, numpy.float64}
        Storage type of x, y, z.
    compressed : bool
        With ``binary``: ``DATA binary_compressed`` (LZF, fields stored column by column,
        as PCL writes it).

    Raises
    ------
    ValueError
        If shapes, dtypes or names are not allowed, ``compressed`` is asked for with
        ``binary=False``, or the data exceed the 4 GiB binary_compressed can hold.
    OSError
        If the file cannot be written.
    """
    xyz_type = np.dtype(xyz_dtype)
    if xyz_type not in (np.dtype(np.float32), np.dtype(np.float64)):
        raise ValueError(f"xyz_dtype must be float32 or float64, got {xyz_type}")
    xyz, width, height = resolve_shape(points, width, height)
    n = xyz.shape[0]
    view = np.array([0, 0, 0, 1, 0, 0, 0] if viewpoint is None else viewpoint, dtype=np.float64)
    if view.shape != (7,) or not np.isfinite(view).all():
        raise ValueError(f"viewpoint must be 7 finite numbers (tx ty tz qw qx qy qz), got {view}")
    store = xyz_type.newbyteorder("<")
    columns = [
        _Column(axis, xyz[:, k], store, "F", xyz_type.itemsize, 1) for k, axis in enumerate("xyz")
    ]
    columns += [_field_column(k, v, n, width, height) for k, v in (fields or {}).items()]
    if compressed and not binary:
        raise ValueError("compressed=True needs binary=True (DATA binary_compressed)")
    data = ("binary_compressed" if compressed else "binary") if binary else "ascii"
    _write_file(path, _pcd_header(columns, width, height, view, data), columns, data)


def _write_file(path: PathLike, header: bytes, columns: list[_Column], data: str) -> None:
    """Write the header, then the points as packed little-endian records, LZF or text."""
    n = columns[0].values.shape[0]
    if data != "binary":
        if data == "ascii":
            body = _ascii_body(columns, n).encode("ascii")
        else:
            body = _compressed_body(columns, n)
        with open(path, "wb") as stream:
            stream.write(header)
            stream.write(body)
        return
    record = np.dtype(
        [(c.name, c.dtype, (c.count,)) if c.count > 1 else (c.name, c.dtype) for c in columns]
    )
    table = np.empty(n, dtype=record)
    for column in columns:
        table[column.name] = column.values
    with open(path, "wb") as stream:
        stream.write(header)
        table.tofile(stream)


def _ascii_body(columns: list[_Column], n: int) -> str:
    """Return one text line per point (``rgb``/``rgba`` as the packed uint32 integer)."""
    arrays = []
    for column in columns:
        values = column.values.reshape(n, column.count).astype(column.dtype, copy=False)
        if column.name in _COLOR_FIELDS and column.dtype.itemsize == 4:
            values = values.view(np.uint32)
        arrays.append(values)
    return ascii_text(arrays)


def _compressed_body(columns: list[_Column], n: int) -> bytes:
    """Return the ``binary_compressed`` data: two uint32 sizes, then LZF of the columns.

    The columns are stored one after another (structure of arrays; a COUNT K field as
    N x K values, point after point), little endian, then compressed as one LZF stream;
    the sizes are the compressed and the uncompressed length, as PCL writes them.
    """
    payload = bytearray(n * sum(c.dtype.itemsize * c.count for c in columns))
    offset = 0
    for column in columns:
        block = np.frombuffer(payload, dtype=column.dtype, count=n * column.count, offset=offset)
        block.reshape(n, column.count)[...] = column.values.reshape(n, column.count)
        offset += block.nbytes
    if not payload:
        return struct.pack("<II", 0, 0)
    packed = lzf.compress(bytes(payload), len(payload) + len(payload) // _LZF_LITERAL_RUN + 16)
    if packed is None or len(packed) >= 1 << 32 or len(payload) >= 1 << 32:
        raise ValueError(
            f"cannot write binary_compressed: {len(payload)} bytes of data do not fit the "
            "format's 32-bit sizes"
        )
    return struct.pack("<II", len(packed), len(payload)) + packed
