"""Reading and writing point cloud files: PCD, PLY and NPY.

Everything here is plain numpy; no ROS, no PCL.

* PCD v0.6 / v0.7 with ``DATA ascii``, ``binary`` and ``binary_compressed`` (LZF), read by
  :func:`read_pcd` (own parser, keeps every field, e.g. ``label``) and written by
  :func:`write_pcd` (``ascii`` or ``binary``).
* PLY ``ascii`` / ``binary_little_endian`` / ``binary_big_endian`` vertex clouds, read by
  :func:`read_ply` and written (binary little endian) by :func:`write_ply`.
* NPY arrays of shape (N, 3) or (H, W, 3), read by :func:`read_npy`, written by
  :func:`write_npy`.

:func:`read_cloud` and :func:`write_cloud` dispatch on the file suffix. Every problem with
a file being read (missing, unreadable, empty, corrupt, truncated, wrong shape, unknown
suffix) raises :class:`CloudFileError`, whose message names the file and says what was wrong
and what is allowed. Invalid arguments to the writers raise :class:`ValueError`; operating
system errors while writing propagate as :class:`OSError`.

:func:`load_osd` loads a scene of the Object Segmentation Database (``osd_learn``) with the
raw per-point labels mapped to object ids.
"""

from __future__ import annotations

import os
import struct
import warnings
from collections.abc import Mapping
from dataclasses import dataclass, field
from io import BytesIO, StringIO
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike, DTypeLike, NDArray

__all__ = [
    "CloudFileError",
    "Cloud",
    "read_cloud",
    "write_cloud",
    "read_pcd",
    "write_pcd",
    "read_ply",
    "write_ply",
    "read_npy",
    "write_npy",
    "lzf_decompress",
    "load_osd",
    "osd_object_ids",
    "OSD_TABLE_ID",
    "OSD_INVALID_ID",
    "CLOUD_SUFFIXES",
]

#: Anything :func:`open` accepts as a file name.
PathLike = str | os.PathLike[str]

#: File suffixes understood by :func:`read_cloud` and :func:`write_cloud`.
CLOUD_SUFFIXES = (".npy", ".pcd", ".ply")

#: Object id :func:`load_osd` gives the table (raw labels 1-9).
OSD_TABLE_ID = 0
#: Object id :func:`load_osd` gives invalid points (raw label 0).
OSD_INVALID_ID = -1


class CloudFileError(ValueError):
    """A point cloud file could not be read: missing, unreadable, empty, corrupt or
    truncated, of an unsupported kind or holding data of the wrong shape.

    The message names the file, what was wrong and what is allowed.
    """


# --------------------------------------------------------------------------------------------
# The in-memory cloud
# --------------------------------------------------------------------------------------------


@dataclass
class Cloud:
    """A point cloud as read from a file.

    Attributes
    ----------
    points : (N, 3) float64 array [m]
        x, y, z of every point, finite and non-finite (NaN marks invalid points of organized
        clouds) exactly as stored, in row-major order for organized clouds. The constructor
        also accepts an (H, W, 3) array (with width and height left at 0) and flattens it.
    fields : dict[str, ndarray]
        Every other field by name, first axis N: e.g. ``label`` (N,) uint32, ``rgb`` /
        ``rgba`` (N,) uint32 holding the raw packed colour bits (whatever type the file
        declared), fields with COUNT > 1 as (N, COUNT). Arrays read from binary files may be
        views into the file's buffer (writable; copy if you keep only a small part).
    width : int
        Points per row (N for unorganized clouds). ``0`` together with ``height=0`` (the
        defaults) means unorganized: width N, height 1.
    height : int
        Rows; the cloud is organized when ``height > 1``.
    viewpoint : (7,) float64 array or None
        Sensor pose ``tx ty tz qw qx qy qz`` from a PCD header, else None.

    Raises
    ------
    ValueError
        If the shapes do not agree (points not (N, 3), ``width * height != N``, a field whose
        first axis is not N, a viewpoint that is not 7 numbers).
    """

    points: NDArray[np.float64]
    fields: dict[str, np.ndarray] = field(default_factory=dict)
    width: int = 0
    height: int = 0
    viewpoint: NDArray[np.float64] | None = None

    def __post_init__(self) -> None:
        points = np.asarray(self.points, dtype=np.float64)
        if points.ndim == 3 and points.shape[2] == 3 and self.width == 0 and self.height == 0:
            self.height, self.width = int(points.shape[0]), int(points.shape[1])
            points = points.reshape(-1, 3)
        if points.ndim != 2 or points.shape[1] != 3:
            raise ValueError(
                f"Cloud points must have shape (N, 3) (or (H, W, 3)), got {points.shape}"
            )
        self.points = points
        n = points.shape[0]
        if self.width == 0 and self.height == 0:
            self.width, self.height = n, 1
        self.width, self.height = int(self.width), int(self.height)
        if self.width < 0 or self.height < 0 or self.width * self.height != n:
            raise ValueError(
                f"Cloud width {self.width} x height {self.height} must equal the number of "
                f"points {n} (both non-negative)"
            )
        for name, values in self.fields.items():
            if not isinstance(values, np.ndarray) or values.ndim < 1 or values.shape[0] != n:
                shape = getattr(values, "shape", type(values).__name__)
                raise ValueError(
                    f"Cloud field {name!r} must be an array whose first axis is the number of "
                    f"points {n}, got {shape}"
                )
        if self.viewpoint is not None:
            viewpoint = np.asarray(self.viewpoint, dtype=np.float64)
            if viewpoint.shape != (7,):
                raise ValueError(
                    f"Cloud viewpoint must be 7 numbers (tx ty tz qw qx qy qz) or None, "
                    f"got shape {viewpoint.shape}"
                )
            self.viewpoint = viewpoint

    def __len__(self) -> int:
        return int(self.points.shape[0])

    @property
    def is_organized(self) -> bool:
        """True when the cloud is an image of points (``height > 1``)."""
        return self.height > 1

    def organized_points(self) -> NDArray[np.float64]:
        """The points as an image.

        Returns
        -------
        (H, W, 3) float64 array [m]
            A view of :attr:`points`; (1, N, 3) for an unorganized cloud.
        """
        return self.points.reshape(self.height, self.width, 3)

    def finite_mask(self) -> NDArray[np.bool_]:
        """Which points have finite x, y and z.

        Returns
        -------
        (N,) bool array
        """
        return np.isfinite(self.points).all(axis=1)


# --------------------------------------------------------------------------------------------
# Dispatch on the suffix
# --------------------------------------------------------------------------------------------


def read_cloud(path: PathLike) -> Cloud:
    """Read a point cloud file, choosing the format by its suffix.

    Parameters
    ----------
    path : str or os.PathLike
        A ``.pcd``, ``.ply`` or ``.npy`` file (suffix case-insensitive).

    Returns
    -------
    Cloud

    Raises
    ------
    CloudFileError
        If the suffix is not one of :data:`CLOUD_SUFFIXES` or the file cannot be read.
    """
    suffix = Path(path).suffix.lower()
    if suffix == ".pcd":
        return read_pcd(path)
    if suffix == ".ply":
        return read_ply(path)
    if suffix == ".npy":
        return read_npy(path)
    raise CloudFileError(
        f"{os.fspath(path)}: unsupported file suffix {suffix or '(none)'!r}; "
        f"allowed: {', '.join(CLOUD_SUFFIXES)}"
    )


def write_cloud(path: PathLike, cloud: Cloud, *, binary: bool = True) -> None:
    """Write a :class:`Cloud`, choosing the format by the suffix of ``path``.

    Parameters
    ----------
    path : str or os.PathLike
        Output file (overwritten): ``.pcd`` keeps all fields, the organization and the
        viewpoint (x y z as float32); ``.ply`` keeps xyz only (float32); ``.npy`` keeps xyz
        (float64) and the organization ((H, W, 3) when organized).
    cloud : Cloud
        The cloud.
    binary : bool
        For ``.pcd``: ``DATA binary`` when True, else ``DATA ascii``.

    Raises
    ------
    ValueError
        If the suffix is not one of :data:`CLOUD_SUFFIXES`, or a field cannot be stored.
    OSError
        If the file cannot be written.
    """
    suffix = Path(path).suffix.lower()
    if suffix == ".pcd":
        write_pcd(
            path,
            cloud.points,
            cloud.fields,
            width=cloud.width,
            height=cloud.height,
            binary=binary,
            viewpoint=cloud.viewpoint,
        )
    elif suffix == ".ply":
        write_ply(path, cloud.points)
    elif suffix == ".npy":
        write_npy(path, cloud.organized_points() if cloud.is_organized else cloud.points)
    else:
        raise ValueError(
            f"cannot write {os.fspath(path)}: unsupported file suffix {suffix or '(none)'!r}; "
            f"allowed: {', '.join(CLOUD_SUFFIXES)}"
        )


def _read_bytes(path: PathLike) -> bytearray:
    """The whole file in a writable buffer (so arrays viewing it are writable)."""
    name = os.fspath(path)
    try:
        with open(path, "rb") as stream:
            size = os.fstat(stream.fileno()).st_size
            buf = bytearray(size)
            got = stream.readinto(buf)
            rest = stream.read()  # the file grew, or st_size is not meaningful
    except FileNotFoundError:
        raise CloudFileError(f"{name}: no such file") from None
    except IsADirectoryError:
        raise CloudFileError(f"{name}: is a directory, not a point cloud file") from None
    except OSError as exc:
        raise CloudFileError(f"{name}: cannot read the file: {exc.strerror or exc}") from exc
    if got < size:
        del buf[got:]
    buf += rest
    if not buf:
        raise CloudFileError(f"{name}: file is empty")
    return buf


def _to_xyz(path: PathLike, columns: tuple[np.ndarray, np.ndarray, np.ndarray]) -> np.ndarray:
    n = columns[0].shape[0]
    points = np.empty((n, 3), dtype=np.float64)
    for axis, values in enumerate(columns):
        if values.ndim != 1:
            raise CloudFileError(
                f"{os.fspath(path)}: field {'xyz'[axis]!r} has COUNT {values.shape[1]}; "
                "x, y and z must have COUNT 1"
            )
        with np.errstate(invalid="ignore"):  # signalling-NaN payloads stay NaN, silently
            points[:, axis] = values
    return points


# --------------------------------------------------------------------------------------------
# LZF
# --------------------------------------------------------------------------------------------


def lzf_decompress(data: bytes | bytearray | memoryview, expected_size: int) -> bytes:
    """Decompress an LZF (liblzf) stream, as used by PCD ``binary_compressed``.

    The stream is a sequence of tokens. A control byte ``c < 32`` is followed by a literal
    run of ``c + 1`` bytes. Otherwise it is a back-reference: length ``(c >> 5) + 2``
    (``c >> 5 == 7``: plus the next byte), distance ``((c & 31) << 8) + next byte + 1``
    back from the current output end; the referenced bytes may overlap the bytes being
    produced (a period-``distance`` repetition).

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
    Pure Python, one loop iteration per token (not per byte): literal runs and
    back-references are copied with bytes slices, overlapping back-references by repeating
    their period. About 0.1-0.3 s for a 640x480 PCD (600,000 tokens, 5-6 MB of output).
    """
    return bytes(_lzf_decompress(data, expected_size))


def _lzf_decompress(data: bytes | bytearray | memoryview, expected_size: int) -> bytearray:
    """:func:`lzf_decompress` returning the (writable) output buffer itself."""
    if expected_size < 0:
        raise CloudFileError(f"LZF expected size must be >= 0, got {expected_size}")
    # Indexing bytes is the fastest way to get at single ints in CPython; slices of the
    # memoryview are copied straight into the output without an intermediate object copy.
    src = data if isinstance(data, bytes) else bytes(data)
    view = memoryview(src)
    size_in = len(src)
    out = bytearray()
    ip = 0  # input position
    op = 0  # output size == len(out)
    try:
        while ip < size_in:
            ctrl = src[ip]
            if ctrl >= 32:  # back-reference
                if ctrl >= 224:  # long form: an extra length byte
                    length = src[ip + 1] + 9
                    dist = ((ctrl & 31) << 8) + src[ip + 2] + 1
                    ip += 3
                else:
                    length = (ctrl >> 5) + 2
                    dist = ((ctrl & 31) << 8) + src[ip + 1] + 1
                    ip += 2
                if dist > op:
                    raise CloudFileError(
                        f"corrupt LZF data: back-reference at input byte {ip} points {dist} "
                        f"bytes back but only {op} bytes have been produced"
                    )
                if dist >= length:  # source and destination do not overlap
                    start = op - dist
                    out += out[start : start + length]
                else:  # overlapping: the last `dist` bytes repeat
                    out += (out[-dist:] * (length // dist + 1))[:length]
                op += length
            else:  # literal run of ctrl + 1 bytes
                end = ip + ctrl + 2
                if end > size_in:
                    raise CloudFileError(
                        f"corrupt LZF data: literal run of {ctrl + 1} bytes at input byte {ip} "
                        f"goes past the end of the {size_in}-byte stream"
                    )
                out += view[ip + 1 : end]
                op += ctrl + 1
                ip = end
    except IndexError:
        raise CloudFileError(
            f"corrupt LZF data: stream of {size_in} bytes ends inside a back-reference token"
        ) from None
    if op != expected_size:
        raise CloudFileError(
            f"corrupt LZF data: decompressed to {op} bytes, expected {expected_size}"
        )
    return out


# --------------------------------------------------------------------------------------------
# PCD
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
_PCD_MAX_HEADER = 1 << 20
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


def _parse_pcd_header(buf: bytearray, path: PathLike) -> tuple[_PcdHeader, int]:
    """Parse the header; return it and the offset of the first data byte."""
    name = os.fspath(path)
    entries: dict[str, list[str]] = {}
    pos = 0
    line_no = 0
    data_start = -1
    while data_start < 0:
        if pos >= len(buf) or pos > _PCD_MAX_HEADER:
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
        if keyword == "DATA":
            data_start = pos

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
    for keyword in ("FIELDS", "SIZE", "TYPE"):
        if not entries.get(keyword):
            raise CloudFileError(f"{name}: PCD header has no {keyword} line (or it is empty)")
    names = tuple(entries["FIELDS"])
    n_fields = len(names)
    counts_tokens = entries.get("COUNT", ["1"] * n_fields)
    for keyword, tokens in (
        ("SIZE", entries["SIZE"]),
        ("TYPE", entries["TYPE"]),
        ("COUNT", counts_tokens),
    ):
        if len(tokens) != n_fields:
            raise CloudFileError(
                f"{name}: PCD header {keyword} has {len(tokens)} entries but FIELDS has "
                f"{n_fields}; they must match"
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
    viewpoint = None
    if "VIEWPOINT" in entries:
        try:
            viewpoint = np.array([float(t) for t in entries["VIEWPOINT"]], dtype=np.float64)
        except ValueError:
            viewpoint = np.zeros(0)
        if viewpoint.shape != (7,) or not np.isfinite(viewpoint).all():
            raise CloudFileError(
                f"{name}: PCD VIEWPOINT {' '.join(entries['VIEWPOINT'])!r} must be 7 finite "
                "numbers (tx ty tz qw qx qy qz)"
            )
    header = _PcdHeader(
        version, names, sizes, types, counts, width, height, viewpoint, points, data
    )
    return header, data_start


def _columns_to_cloud(
    path: PathLike, header: _PcdHeader, columns: dict[str, np.ndarray]
) -> Cloud:
    """Build the Cloud from one array per (non-padding) field, first axis N."""
    points = _to_xyz(path, (columns.pop("x"), columns.pop("y"), columns.pop("z")))
    for color in _COLOR_FIELDS:
        values = columns.get(color)
        if values is not None and values.dtype.itemsize == 4 and values.dtype != np.uint32:
            columns[color] = values.view(np.uint32)
    return Cloud(points, columns, header.width, header.height, header.viewpoint)


def _read_pcd_binary(buf: bytearray, start: int, header: _PcdHeader, path: PathLike) -> Cloud:
    dtype = header.record_dtype()
    needed = header.points * dtype.itemsize
    available = len(buf) - start
    if available < needed:
        raise CloudFileError(
            f"{os.fspath(path)}: truncated PCD: DATA binary needs {needed} bytes "
            f"({header.points} points of {dtype.itemsize} bytes), the file has {available}"
        )
    records = np.frombuffer(buf, dtype=dtype, count=header.points, offset=start)
    columns = {n: records[n] for n in header.names if n != "_"}
    return _columns_to_cloud(path, header, columns)


def _read_pcd_compressed(
    buf: bytearray, start: int, header: _PcdHeader, path: PathLike
) -> Cloud:
    name = os.fspath(path)
    dtypes = header.dtypes()
    point_size = sum(d.itemsize * c for d, c in zip(dtypes, header.counts, strict=True))
    expected = header.points * point_size
    if len(buf) - start < 8:
        if header.points == 0:
            decompressed = bytearray()
        else:
            raise CloudFileError(
                f"{name}: truncated PCD: DATA binary_compressed has {len(buf) - start} bytes, "
                "needs at least the 8-byte size header"
            )
    else:
        compressed_size, uncompressed_size = struct.unpack_from("<II", buf, start)
        if uncompressed_size != expected:
            raise CloudFileError(
                f"{name}: corrupt PCD: binary_compressed uncompressed size {uncompressed_size} "
                f"!= {expected} ({header.points} points of {point_size} bytes)"
            )
        available = len(buf) - start - 8
        if compressed_size > available:
            raise CloudFileError(
                f"{name}: truncated PCD: binary_compressed says {compressed_size} compressed "
                f"bytes, the file has {available}"
            )
        payload = memoryview(buf)[start + 8 : start + 8 + compressed_size]
        try:
            decompressed = _lzf_decompress(payload, expected)
        except CloudFileError as exc:
            raise CloudFileError(f"{name}: {exc}") from None
    # Structure of arrays: all N values of one field, then the next field.
    columns: dict[str, np.ndarray] = {}
    offset = 0
    for field_name, dtype, count in zip(header.names, dtypes, header.counts, strict=True):
        values = np.frombuffer(
            decompressed, dtype=dtype, count=header.points * count, offset=offset
        )
        offset += values.nbytes
        if field_name != "_":
            columns[field_name] = values.reshape(header.points, count) if count > 1 else values
    return _columns_to_cloud(path, header, columns)


def _read_pcd_ascii(buf: bytearray, start: int, header: _PcdHeader, path: PathLike) -> Cloud:
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
    lines = buf.count(b"\n", start) + (0 if buf.endswith(b"\n") else 1)
    if lines < header.points:  # checked first: loadtxt allocates max_rows rows up front
        raise CloudFileError(
            f"{name}: truncated PCD: DATA ascii has {lines} lines, POINTS says {header.points}"
        )
    if header.points == 0:
        records = np.zeros(0, dtype=dtype)
    else:
        try:
            text = bytes(buf[start:]).decode("ascii")
        except UnicodeDecodeError:
            raise CloudFileError(f"{name}: PCD DATA ascii section is not ASCII text") from None
        try:
            with warnings.catch_warnings():  # an empty DATA section is reported below
                warnings.simplefilter("ignore", UserWarning)
                records = np.loadtxt(
                    StringIO(text), dtype=dtype, ndmin=1, max_rows=header.points, comments=None
                )
        except ValueError as exc:
            raise CloudFileError(f"{name}: corrupt PCD DATA ascii: {exc}") from None
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
        columns[field_name] = np.ascontiguousarray(values)
    return _columns_to_cloud(path, header, columns)


def _ascii_color_bits(values: np.ndarray, dtype: np.dtype) -> np.ndarray:
    """Raw bits of a float-declared ascii colour column (see :func:`_read_pcd_ascii`)."""
    finite = np.isfinite(values)
    as_int = finite.all() and np.all(values == np.round(values))
    as_int = bool(as_int and values.size and values.min() >= 0 and values.max() < 2.0**32)
    if as_int and dtype.itemsize == 4:
        return values.astype(np.uint32)
    return values.astype(dtype)


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
    ``binary``: a single structured dtype view of the file buffer (``np.frombuffer``, no
    copy). ``binary_compressed``: the LZF stream (``uint32`` compressed and uncompressed
    sizes, little endian, then the data) decompresses to the fields one after another
    (structure of arrays). Bytes after the data (PCL pads files to a page) are ignored.
    """
    buf = _read_bytes(path)
    header, start = _parse_pcd_header(buf, path)
    if header.data == "binary":
        return _read_pcd_binary(buf, start, header, path)
    if header.data == "binary_compressed":
        return _read_pcd_compressed(buf, start, header, path)
    return _read_pcd_ascii(buf, start, header, path)


def _pcd_type(dtype: np.dtype, what: str) -> tuple[str, int]:
    """TYPE letter and SIZE of a numpy dtype, or ValueError naming what is allowed."""
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


def _resolve_shape(
    points: ArrayLike, width: int | None, height: int | None
) -> tuple[np.ndarray, int, int]:
    """Flatten points to (N, 3); return them, width and height."""
    array = np.asarray(points)
    if array.dtype.kind not in "fiu":
        raise ValueError(f"points must be real numbers, got dtype {array.dtype}")
    if array.ndim == 3 and array.shape[2] == 3:
        rows, cols = int(array.shape[0]), int(array.shape[1])
        if (width is not None and width != cols) or (height is not None and height != rows):
            raise ValueError(
                f"width/height {width}/{height} disagree with organized points of shape "
                f"{array.shape} (H, W, 3)"
            )
        return array.reshape(-1, 3), cols, rows
    if array.ndim != 2 or array.shape[1] != 3:
        raise ValueError(f"points must have shape (N, 3) or (H, W, 3), got {array.shape}")
    n = int(array.shape[0])
    if width is None and height is None:
        width, height = n, 1
    elif width is None:
        width = n // height if height else -1
    elif height is None:
        height = n // width if width else -1
    assert width is not None and height is not None
    if width < 0 or height < 0 or width * height != n:
        raise ValueError(
            f"width {width} x height {height} must equal the number of points {n}"
        )
    return array, width, height


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
) -> None:
    """Write a PCD v0.7 file, ``DATA binary`` (default) or ``ascii``.

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

    Raises
    ------
    ValueError
        If shapes, dtypes or names are not allowed.
    OSError
        If the file cannot be written.
    """
    xyz_type = np.dtype(xyz_dtype)
    if xyz_type not in (np.dtype(np.float32), np.dtype(np.float64)):
        raise ValueError(f"xyz_dtype must be float32 or float64, got {xyz_type}")
    xyz, width, height = _resolve_shape(points, width, height)
    n = xyz.shape[0]
    if viewpoint is None:
        view = np.array([0, 0, 0, 1, 0, 0, 0], dtype=np.float64)
    else:
        view = np.asarray(viewpoint, dtype=np.float64)
        if view.shape != (7,) or not np.isfinite(view).all():
            raise ValueError(
                f"viewpoint must be 7 finite numbers (tx ty tz qw qx qy qz), got {view}"
            )

    names = ["x", "y", "z"]
    columns: list[np.ndarray] = [xyz[:, 0], xyz[:, 1], xyz[:, 2]]
    dtypes = [xyz_type.newbyteorder("<")] * 3
    types, sizes, counts = ["F"] * 3, [xyz_type.itemsize] * 3, [1, 1, 1]
    for field_name, raw in (fields or {}).items():
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
        names.append(field_name)
        columns.append(values if count > 1 else values[:, 0])
        dtypes.append(values.dtype.newbyteorder("<"))
        types.append(type_)
        sizes.append(size)
        counts.append(count)

    header = "\n".join(
        [
            "# .PCD v0.7 - Point Cloud Data file format",
            "VERSION 0.7",
            "FIELDS " + " ".join(names),
            "SIZE " + " ".join(map(str, sizes)),
            "TYPE " + " ".join(types),
            "COUNT " + " ".join(map(str, counts)),
            f"WIDTH {width}",
            f"HEIGHT {height}",
            "VIEWPOINT " + " ".join(_format_number(v) for v in view),
            f"POINTS {n}",
            f"DATA {'binary' if binary else 'ascii'}",
            "",
        ]
    ).encode("ascii")

    if binary:
        record = np.dtype(
            [
                (name, dt, (c,)) if c > 1 else (name, dt)
                for name, dt, c in zip(names, dtypes, counts, strict=True)
            ]
        )
        table = np.empty(n, dtype=record)
        for name, values in zip(names, columns, strict=True):
            table[name] = values
        with open(path, "wb") as stream:
            stream.write(header)
            table.tofile(stream)
    else:
        body = _ascii_body(names, columns, dtypes, n).encode("ascii")
        with open(path, "wb") as stream:
            stream.write(header)
            stream.write(body)


def _ascii_body(
    names: list[str], columns: list[np.ndarray], dtypes: list[np.dtype], n: int
) -> str:
    """One text line per point, values separated by single spaces."""
    if n == 0:
        return ""
    formats: list[str] = []
    values_by_column: list[list] = []
    for name, values, dtype in zip(names, columns, dtypes, strict=True):
        values = values.reshape(n, -1).astype(dtype, copy=False)
        if name in _COLOR_FIELDS and dtype.itemsize == 4:
            values, fmt = values.view(np.uint32), "%d"
        elif dtype.kind == "f":
            fmt = "%.9g" if dtype.itemsize == 4 else "%.17g"  # round-trip precision
        else:
            fmt = "%d"
        for k in range(values.shape[1]):  # per value column, not per point
            formats.append(fmt)
            values_by_column.append(values[:, k].tolist())
    row = " ".join(formats)
    # map() applies the row format to one tuple per point inside C, without a Python loop.
    return "\n".join(map(row.__mod__, zip(*values_by_column))) + "\n"


# --------------------------------------------------------------------------------------------
# PLY
# --------------------------------------------------------------------------------------------

_PLY_TYPES = {
    "char": "i1",
    "int8": "i1",
    "uchar": "u1",
    "uint8": "u1",
    "short": "i2",
    "int16": "i2",
    "ushort": "u2",
    "uint16": "u2",
    "int": "i4",
    "int32": "i4",
    "uint": "u4",
    "uint32": "u4",
    "float": "f4",
    "float32": "f4",
    "double": "f8",
    "float64": "f8",
}
_PLY_FORMATS = {"ascii": "", "binary_little_endian": "<", "binary_big_endian": ">"}


@dataclass
class _PlyElement:
    name: str
    count: int
    properties: list[tuple[str, str]] = field(default_factory=list)  # (name, dtype code)
    has_list: bool = False


def _parse_ply_header(buf: bytearray, path: PathLike) -> tuple[str, list[_PlyElement], int]:
    """Parse the header; return the format, the elements and the offset of the body."""
    name = os.fspath(path)
    if not buf.startswith(b"ply") or buf[3:4] not in (b"\n", b"\r"):
        raise CloudFileError(f"{name}: not a PLY file (it must start with a 'ply' line)")
    fmt: str | None = None
    elements: list[_PlyElement] = []
    pos = buf.find(b"\n") + 1
    number = 1
    while True:
        if pos <= 0 or pos >= len(buf) or pos > _PCD_MAX_HEADER:
            raise CloudFileError(f"{name}: PLY header has no end_header line (truncated?)")
        newline = buf.find(b"\n", pos)
        end = len(buf) if newline < 0 else newline + 1
        try:
            line = bytes(buf[pos:end]).decode("ascii").strip()
        except UnicodeDecodeError:
            raise CloudFileError(f"{name}: PLY header line {number + 1} is not ASCII") from None
        pos = end
        number += 1
        words = line.split()
        if not words or words[0] in ("comment", "obj_info"):
            continue
        bad = CloudFileError(f"{name}: malformed PLY header line {number}: {line[:80]!r}")
        if words[0] == "end_header":
            break
        if words[0] == "format":
            if len(words) != 3 or words[1] not in _PLY_FORMATS:
                raise CloudFileError(
                    f"{name}: unsupported PLY format line {line[:80]!r}; allowed: "
                    f"{', '.join(_PLY_FORMATS)}"
                )
            fmt = words[1]
        elif words[0] == "element":
            if len(words) != 3 or not words[2].isdigit():
                raise bad
            elements.append(_PlyElement(words[1], int(words[2])))
        elif words[0] == "property":
            if not elements:
                raise bad
            if len(words) == 5 and words[1] == "list":
                elements[-1].has_list = True
                elements[-1].properties.append((words[4], "list"))
            elif len(words) == 3 and words[1] in _PLY_TYPES:
                elements[-1].properties.append((words[2], _PLY_TYPES[words[1]]))
            else:
                raise CloudFileError(
                    f"{name}: PLY property line {number} {line[:80]!r} not understood; "
                    f"allowed types: {', '.join(_PLY_TYPES)} (or list)"
                )
        else:
            raise bad
    if fmt is None:
        raise CloudFileError(f"{name}: PLY header has no format line")
    return fmt, elements, pos


def read_ply(path: PathLike) -> Cloud:
    """Read the vertices of a PLY file as a point cloud.

    Parameters
    ----------
    path : str or os.PathLike
        An ``ascii``, ``binary_little_endian`` or ``binary_big_endian`` PLY file with a
        ``vertex`` element that has x, y and z properties.

    Returns
    -------
    Cloud
        ``points`` (N, 3) float64 [m]; every other vertex property (e.g. ``red``, ``nx``) in
        ``fields`` by name, native byte order; unorganized; no viewpoint. Other elements
        (faces, ...) are ignored.

    Raises
    ------
    CloudFileError
        If the file is missing, empty, not a PLY file, has no vertex x y z, has list
        properties in the vertex element (or, binary, in an element before it), or is
        truncated or corrupt.
    """
    name = os.fspath(path)
    buf = _read_bytes(path)
    fmt, elements, start = _parse_ply_header(buf, path)
    vertex_index = next((i for i, e in enumerate(elements) if e.name == "vertex"), None)
    if vertex_index is None:
        raise CloudFileError(f"{name}: PLY file has no 'vertex' element")
    vertex = elements[vertex_index]
    props = [p for p, _ in vertex.properties]
    missing = [axis for axis in "xyz" if axis not in props]
    if missing:
        raise CloudFileError(
            f"{name}: PLY vertex element lacks {', '.join(missing)}; x, y and z are required"
        )
    if vertex.has_list:
        raise CloudFileError(
            f"{name}: PLY vertex element has list properties; only scalar properties are "
            "supported"
        )
    if len(set(props)) != len(props):
        raise CloudFileError(f"{name}: PLY vertex element names a property twice")
    order = _PLY_FORMATS[fmt]
    n = vertex.count

    if fmt == "ascii":
        dtype = np.dtype([(p, code) for p, code in vertex.properties])
        skip = sum(e.count for e in elements[:vertex_index])
        if n == 0:
            records = np.zeros(0, dtype=dtype)
        else:
            try:
                lines = bytes(buf[start:]).decode("ascii").splitlines()
            except UnicodeDecodeError:
                raise CloudFileError(f"{name}: PLY ascii body is not ASCII text") from None
            if len(lines) < skip + n:
                raise CloudFileError(
                    f"{name}: truncated PLY: {len(lines)} body lines, the header needs at "
                    f"least {skip + n}"
                )
            try:
                with warnings.catch_warnings():  # blank lines are reported below
                    warnings.simplefilter("ignore", UserWarning)
                    records = np.loadtxt(lines[skip : skip + n], dtype=dtype, ndmin=1)
            except ValueError as exc:
                raise CloudFileError(f"{name}: corrupt PLY ascii vertex data: {exc}") from None
            if records.shape[0] != n:
                raise CloudFileError(
                    f"{name}: corrupt PLY: {n - records.shape[0]} of the {n} vertex lines "
                    "are blank"
                )
    else:
        offset = start
        for element in elements[:vertex_index]:
            if element.has_list:
                raise CloudFileError(
                    f"{name}: PLY element {element.name!r} before 'vertex' has list "
                    "properties; cannot skip it in a binary file"
                )
            size = np.dtype([(f"p{i}", c) for i, (_, c) in enumerate(element.properties)])
            offset += element.count * size.itemsize
        dtype = np.dtype([(p, order + code) for p, code in vertex.properties])
        needed = n * dtype.itemsize
        if len(buf) - offset < needed:
            raise CloudFileError(
                f"{name}: truncated PLY: {n} vertices need {needed} bytes, the file has "
                f"{max(len(buf) - offset, 0)}"
            )
        records = np.frombuffer(buf, dtype=dtype, count=n, offset=offset)
    points = _to_xyz(path, (records["x"], records["y"], records["z"]))
    fields = {
        p: records[p].astype(records[p].dtype.newbyteorder("="), copy=False)
        for p in props
        if p not in ("x", "y", "z")
    }
    return Cloud(points, fields)


def write_ply(
    path: PathLike,
    points: ArrayLike,
    colors: ArrayLike | None = None,
    *,
    xyz_dtype: DTypeLike = np.float32,
) -> None:
    """Write points (and optional colours) as a binary little-endian PLY file.

    Parameters
    ----------
    path : str or os.PathLike
        Output file (overwritten).
    points : (N, 3) or (H, W, 3) array_like [m]
        Coordinates (organized input is flattened row by row).
    colors : (N, 3) or (H, W, 3) array_like, optional
        RGB as uint8, or as floats in [0, 1] (scaled by 255 and rounded); written as
        ``uchar red green blue``.
    xyz_dtype : {numpy.float32, numpy.float64}
        Storage type of x, y, z (``float`` or ``double``).

    Raises
    ------
    ValueError
        If shapes or dtypes are not allowed.
    OSError
        If the file cannot be written.
    """
    xyz_type = np.dtype(xyz_dtype)
    if xyz_type not in (np.dtype(np.float32), np.dtype(np.float64)):
        raise ValueError(f"xyz_dtype must be float32 or float64, got {xyz_type}")
    xyz, _, _ = _resolve_shape(points, None, None)
    n = xyz.shape[0]
    ply_name = "float" if xyz_type.itemsize == 4 else "double"
    layout: list[tuple[str, str]] = [(axis, "<" + xyz_type.str[1:]) for axis in "xyz"]
    rgb = None
    if colors is not None:
        rgb = np.asarray(colors)
        if rgb.shape[-1:] != (3,) or rgb.size != 3 * n:
            raise ValueError(
                f"colors must have one RGB triple per point ({n}, 3), got shape {rgb.shape}"
            )
        rgb = rgb.reshape(n, 3)
        if rgb.dtype.kind == "f":
            if n and not (np.isfinite(rgb).all() and rgb.min() >= 0.0 and rgb.max() <= 1.0):
                raise ValueError("float colors must be finite and within [0, 1]")
            rgb = np.rint(rgb * 255.0).astype(np.uint8)
        elif rgb.dtype != np.uint8:
            raise ValueError(f"colors must be uint8 or float in [0, 1], got dtype {rgb.dtype}")
        layout += [("red", "u1"), ("green", "u1"), ("blue", "u1")]
    table = np.empty(n, dtype=np.dtype(layout))
    table["x"], table["y"], table["z"] = xyz[:, 0], xyz[:, 1], xyz[:, 2]
    lines = [
        "ply",
        "format binary_little_endian 1.0",
        "comment written by geomodel_ros",
        f"element vertex {n}",
        *(f"property {ply_name} {axis}" for axis in "xyz"),
    ]
    if rgb is not None:
        table["red"], table["green"], table["blue"] = rgb[:, 0], rgb[:, 1], rgb[:, 2]
        lines += ["property uchar red", "property uchar green", "property uchar blue"]
    lines += ["end_header", ""]
    with open(path, "wb") as stream:
        stream.write("\n".join(lines).encode("ascii"))
        table.tofile(stream)


# --------------------------------------------------------------------------------------------
# NPY
# --------------------------------------------------------------------------------------------


def read_npy(path: PathLike) -> Cloud:
    """Read an ``.npy`` array of points.

    Parameters
    ----------
    path : str or os.PathLike
        A file written by :func:`numpy.save` (format version 1.0 or 2.0) holding a float
        (N, 3) or (H, W, 3) array [m]. Pickled objects are refused.

    Returns
    -------
    Cloud
        Unorganized for (N, 3), organized width W, height H for (H, W, 3); no fields.

    Raises
    ------
    CloudFileError
        If the file is missing, not an NPY array, truncated, or of another dtype or shape.

    Notes
    -----
    The header is checked against the file size before any data is touched (a corrupt
    shape cannot trigger a huge allocation); the data are then a view of the file buffer.
    """
    name = os.fspath(path)
    buf = _read_bytes(path)
    stream = BytesIO(buf)
    try:
        with warnings.catch_warnings():  # a mangled header can make literal_eval warn
            warnings.simplefilter("ignore")
            version = np.lib.format.read_magic(stream)
            if version == (1, 0):
                shape, fortran_order, dtype = np.lib.format.read_array_header_1_0(stream)
            elif version == (2, 0):
                shape, fortran_order, dtype = np.lib.format.read_array_header_2_0(stream)
            else:
                raise ValueError(
                    f"format version {version[0]}.{version[1]} (allowed: 1.0, 2.0)"
                )
    except Exception as exc:  # noqa: BLE001 - numpy's header parser raises many kinds
        raise CloudFileError(f"{name}: not a readable .npy array: {exc}") from None
    if dtype.kind != "f":
        raise CloudFileError(
            f"{name}: array dtype {dtype} is not allowed; it must be a float dtype"
        )
    shape = tuple(int(d) for d in shape)
    if not (len(shape) in (2, 3) and shape[-1] == 3):
        raise CloudFileError(
            f"{name}: array shape {shape} is not allowed; it must be (N, 3) or (H, W, 3)"
        )
    count = int(np.prod(shape))
    offset = stream.tell()
    if len(buf) - offset < count * dtype.itemsize:
        raise CloudFileError(
            f"{name}: truncated .npy array: shape {shape} of {dtype} needs "
            f"{count * dtype.itemsize} bytes, the file has {len(buf) - offset}"
        )
    flat = np.frombuffer(buf, dtype=dtype, count=count, offset=offset)
    array = flat.reshape(shape[::-1]).transpose() if fortran_order else flat.reshape(shape)
    points = np.ascontiguousarray(array.reshape(-1, 3), dtype=np.float64)
    if len(shape) == 3:
        return Cloud(points, {}, shape[1], shape[0])
    return Cloud(points)


def write_npy(path: PathLike, points: ArrayLike) -> None:
    """Save points as an ``.npy`` float64 array, keeping an (H, W, 3) organization.

    Parameters
    ----------
    path : str or os.PathLike
        Output file (overwritten; no ``.npy`` suffix is appended).
    points : (N, 3) or (H, W, 3) array_like [m]
        Real coordinates.

    Raises
    ------
    ValueError
        If ``points`` is not a real (N, 3) or (H, W, 3) array.
    OSError
        If the file cannot be written.
    """
    array = np.asarray(points)
    if array.dtype.kind not in "fiu" or array.ndim not in (2, 3) or array.shape[-1] != 3:
        raise ValueError(
            f"points must be a real (N, 3) or (H, W, 3) array, got {array.dtype} "
            f"{array.shape}"
        )
    with open(path, "wb") as stream:
        np.save(stream, array.astype(np.float64, copy=False), allow_pickle=False)


# --------------------------------------------------------------------------------------------
# Datasets
# --------------------------------------------------------------------------------------------


def osd_object_ids(raw_labels: ArrayLike) -> NDArray[np.int64]:
    """Map raw OSD labels to object ids.

    Parameters
    ----------
    raw_labels : (N,) array_like of int
        The ``label`` field of an OSD scene: 0 invalid, 1-9 parts of the table, 20-29 parts
        of object 1, 30-39 parts of object 2, ...

    Returns
    -------
    (N,) int64 array
        ``label // 10`` for labels >= 20 (so objects get ids 2, 3, ...),
        :data:`OSD_TABLE_ID` (0) for the table, :data:`OSD_INVALID_ID` (-1) for label 0.

    Raises
    ------
    ValueError
        If a label is negative or in 10-19 (not used by the database).
    """
    raw = np.asarray(raw_labels).astype(np.int64)
    bad = (raw < 0) | ((raw >= 10) & (raw < 20))
    if bad.any():
        values = np.unique(raw[bad])[:5].tolist()
        raise ValueError(
            f"OSD labels {values} are not allowed; allowed: 0 (invalid), 1-9 (table), "
            ">= 20 (objects)"
        )
    ids = raw // 10
    ids[(raw >= 1) & (raw <= 9)] = OSD_TABLE_ID
    ids[raw == 0] = OSD_INVALID_ID
    return ids


def load_osd(path: PathLike) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
    """Load one scene of the Object Segmentation Database (e.g. ``osd_learn/learn0.pcd``).

    Parameters
    ----------
    path : str or os.PathLike
        An OSD PCD file (organized 640x480, fields ``label x y z rgba``).

    Returns
    -------
    points : (H*W, 3) float64 array [m]
        Row-major pixels, invalid points NaN (kept, so the organization is preserved).
    labels : (H*W,) int64 array
        Object id of each point, see :func:`osd_object_ids`: ``label // 10`` for objects
        (2, 3, ...), 0 for the table, -1 for invalid points.

    Raises
    ------
    CloudFileError
        If the file cannot be read, has no ``label`` field, or holds labels the database
        does not use.
    """
    cloud = read_pcd(path)
    raw = cloud.fields.get("label")
    if raw is None or raw.ndim != 1 or raw.dtype.kind not in "iu":
        raise CloudFileError(
            f"{os.fspath(path)}: OSD scene needs an integer 'label' field with COUNT 1; "
            f"fields are: {', '.join(cloud.fields) or '(none)'}"
        )
    try:
        labels = osd_object_ids(raw)
    except ValueError as exc:
        raise CloudFileError(f"{os.fspath(path)}: {exc}") from None
    return cloud.points, labels
