"""The in-memory point cloud and what every file format shares.

:class:`Cloud` is what the readers return, :class:`CloudFileError` what they raise; the
helpers read a whole file into a writable buffer, assemble x y z and check point arrays
handed to the writers. Plain numpy; no ROS.
"""

from __future__ import annotations

import os
import stat
from collections.abc import Callable
from dataclasses import dataclass, field
from io import BytesIO
from typing import BinaryIO

import numpy as np
from numpy.typing import ArrayLike, NDArray

#: Anything :func:`open` accepts as a file name.
PathLike = str | os.PathLike[str]


class CloudFileError(ValueError):
    """A point cloud file could not be read.

    Raised when the file is missing, unreadable, empty, corrupt or truncated, of an
    unsupported kind or holds data of the wrong shape. The message names the file, what was
    wrong and what is allowed.
    """


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
        declared), fields with COUNT > 1 as (N, COUNT). Every field read from a file owns
        its memory (the points of an ``.npy`` file are a writable view of its buffer).
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
        """Return the points as an image.

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


def read_bytes(path: PathLike) -> bytearray:
    """Read the whole file into a writable buffer (so arrays viewing it are writable).

    Raises
    ------
    CloudFileError
        If the file is missing, a directory, unreadable or empty.
    """
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


#: Bytes read from the start of a file to parse its header: the longest header the readers
#: accept (1 MiB) plus room for the line that crosses that limit.
HEAD_BYTES = (1 << 20) + (1 << 16)
#: Size of the buffer binary records are read through. Small next to the clouds it reads
#: (1 MiB against tens or hundreds), large enough that the per-chunk overhead is nil.
CHUNK_BYTES = 1 << 20


def open_cloud(path: PathLike) -> tuple[BinaryIO, int, bytearray]:
    """Open a file for reading; return the stream, the file size and its first bytes.

    The first ``min(size, HEAD_BYTES)`` bytes (the header, and for small files all data)
    are returned as a writable buffer; the stream is left after them. Pipes and other
    files without a meaningful size are read whole (stream over the buffered bytes).

    Raises
    ------
    CloudFileError
        If the file is missing, a directory, unreadable or empty.
    """
    name = os.fspath(path)
    try:
        stream = open(path, "rb")  # noqa: SIM115 - returned to the caller, who closes it
    except FileNotFoundError:
        raise CloudFileError(f"{name}: no such file") from None
    except IsADirectoryError:
        raise CloudFileError(f"{name}: is a directory, not a point cloud file") from None
    except OSError as exc:
        raise CloudFileError(f"{name}: cannot read the file: {exc.strerror or exc}") from exc
    try:
        info = os.fstat(stream.fileno())
        if not stat.S_ISREG(info.st_mode):  # a pipe can be read once: keep what it gives
            data = stream.read()
            stream.close()
            stream, size = BytesIO(data), len(data)
        else:
            size = info.st_size
        head = bytearray(min(size, HEAD_BYTES))
        del head[stream.readinto(head) :]
    except OSError as exc:
        stream.close()
        raise CloudFileError(f"{name}: cannot read the file: {exc.strerror or exc}") from exc
    if not head:
        stream.close()
        raise CloudFileError(f"{name}: file is empty")
    return stream, max(size, len(head)), head


def read_records(
    stream: BinaryIO,
    path: PathLike,
    offset: int,
    dtype: np.dtype,
    count: int,
    keep: Callable[[str], bool],
) -> tuple[NDArray[np.float64], dict[str, np.ndarray]]:
    """Read ``count`` packed records of ``dtype`` from ``offset`` into one array per field.

    Records pass through a buffer of :data:`CHUNK_BYTES`, so reading holds the result plus
    that buffer, never the file: x, y, z go straight into the (N, 3) float64 points [m],
    every other field for which ``keep(name)`` is true into its own native-order array
    ((N,) or (N, COUNT)).

    Raises
    ------
    CloudFileError
        If x, y or z has COUNT > 1, or the file ends early (it changed while being read).
    """
    for axis in "xyz":
        shape = dtype[axis].shape
        if shape:
            raise CloudFileError(
                f"{os.fspath(path)}: field {axis!r} has COUNT {shape[0]}; "
                "x, y and z must have COUNT 1"
            )
    points = np.empty((count, 3), dtype=np.float64)
    names = [n for n in dtype.names if n not in ("x", "y", "z") and keep(n)]
    fields = {
        n: np.empty((count, *dtype[n].shape), dtype=dtype[n].base.newbyteorder("="))
        for n in names
    }
    rows = max(1, CHUNK_BYTES // max(dtype.itemsize, 1))
    chunk = bytearray(min(rows, count) * dtype.itemsize)
    stream.seek(offset)
    done = 0
    while done < count:
        k = min(rows, count - done)
        got = stream.readinto(memoryview(chunk)[: k * dtype.itemsize])
        if got != k * dtype.itemsize:
            raise CloudFileError(f"{os.fspath(path)}: file ended early (changed while read?)")
        records = np.frombuffer(chunk, dtype=dtype, count=k)
        with np.errstate(invalid="ignore"):  # signalling-NaN payloads stay NaN, silently
            for axis, axis_name in enumerate("xyz"):
                points[done : done + k, axis] = records[axis_name]
        for n in names:
            fields[n][done : done + k] = records[n]
        done += k
    return points, fields


def count_lines(stream: BinaryIO, offset: int, size: int) -> int:
    """Count the text lines from ``offset`` to the end (a last line without newline counts).

    Reads through a :data:`CHUNK_BYTES` buffer, never the whole file.
    """
    stream.seek(max(min(offset, size) - 1, 0))
    last = stream.read(1)  # the last byte of the file when no data follow
    stream.seek(offset)
    lines = 0
    while block := stream.read(CHUNK_BYTES):
        lines += block.count(b"\n")
        last = block[-1:]
    return lines + (0 if last == b"\n" else 1)


#: Text format of each value kind in :func:`ascii_text`: the fewest digits that read back
#: to the same bits. float32 needs 9 significant digits (its 24-bit significand spans
#: 10^7.2); float64 uses Python's repr, the shortest string that round-trips (at most 17
#: digits). NaN of any sign or payload is written ``nan``, as PCL does.
_ASCII_FORMATS = {"f4": "%.9g", "f8": "%r"}


def ascii_text(columns: list[np.ndarray]) -> str:
    """Format one text line per point, values separated by single spaces.

    Parameters
    ----------
    columns : list of (N,) or (N, K) arrays
        Integer, float32 or float64 values; a (N, K) array gives K values per line.

    Returns
    -------
    str
        ``N`` lines, each ending with a newline; empty for N = 0. Integers in full, floats
        with round-trip precision (see :data:`_ASCII_FORMATS`).
    """
    n = columns[0].shape[0] if columns else 0
    if n == 0:
        return ""
    formats: list[str] = []
    values_by_column: list[list] = []
    for values in columns:
        flat = values.reshape(n, -1)  # n > 0 here
        fmt = _ASCII_FORMATS[f"f{flat.dtype.itemsize}"] if flat.dtype.kind == "f" else "%d"
        for k in range(flat.shape[1]):  # per value column, not per point
            formats.append(fmt)
            values_by_column.append(flat[:, k].tolist())
    row = " ".join(formats)
    # map() applies the row format to one tuple per point inside C, without a Python loop.
    return "\n".join(map(row.__mod__, zip(*values_by_column))) + "\n"


def to_xyz(path: PathLike, columns: tuple[np.ndarray, np.ndarray, np.ndarray]) -> np.ndarray:
    """Stack the x, y and z columns, each (N,) of any real dtype, into (N, 3) float64 [m].

    Raises
    ------
    CloudFileError
        If a column is not one value per point (a field with COUNT > 1).
    """
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


def resolve_shape(
    points: ArrayLike, width: int | None, height: int | None
) -> tuple[np.ndarray, int, int]:
    """Flatten (N, 3) or (H, W, 3) points to (N, 3); return them, the width and the height.

    Raises
    ------
    ValueError
        If the points are not real numbers of an allowed shape, or width x height != N.
    """
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
