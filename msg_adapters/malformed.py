"""Build PointCloud2 messages with any layout, including invalid ones, for robustness tests.

:func:`msg_adapters.pointcloud2.xyz_to_cloud` only writes valid messages.  The fuzzers and
reliability tests also need messages that lie: fields missing, repeated, overlapping or
reaching past ``point_step``, unknown datatypes, ``count`` other than 1, either byte
order, ``row_step`` / ``point_step`` / ``width * height`` that disagree with ``data``,
truncated data.  :func:`pack_points` writes point values into bytes following a field
table (whatever it declares), and :func:`raw_cloud` puts any header, geometry, field table
and bytes together into a message without checking anything.
"""

from __future__ import annotations

import array
from collections.abc import Sequence
from typing import NamedTuple

import numpy as np
from numpy.typing import ArrayLike
from sensor_msgs.msg import PointCloud2, PointField
from std_msgs.msg import Header

__all__ = ["FieldSpec", "ELEMENT_DTYPES", "pack_points", "raw_cloud"]

#: PointField datatype code -> element dtype (without byte order); codes outside this
#: table are written as raw zero bytes of :data:`UNKNOWN_ELEMENT_SIZE` each.
ELEMENT_DTYPES: dict[int, np.dtype] = {
    PointField.INT8: np.dtype(np.int8),
    PointField.UINT8: np.dtype(np.uint8),
    PointField.INT16: np.dtype(np.int16),
    PointField.UINT16: np.dtype(np.uint16),
    PointField.INT32: np.dtype(np.int32),
    PointField.UINT32: np.dtype(np.uint32),
    PointField.FLOAT32: np.dtype(np.float32),
    PointField.FLOAT64: np.dtype(np.float64),
}
#: Bytes written per element of a field whose datatype code is unknown (a guess a
#: malformed message could make; a reader must reject the code, not the size).
UNKNOWN_ELEMENT_SIZE = 4
_AXES = {"x": 0, "y": 1, "z": 2}


class FieldSpec(NamedTuple):
    """One PointField as declared (nothing is checked): name, byte offset, code, count."""

    name: str
    offset: int
    datatype: int
    count: int = 1


def _element_values(values: np.ndarray, dtype: np.dtype) -> np.ndarray:
    """``values`` (N,) float64 cast to ``dtype``; integer casts of NaN/inf/huge become 0."""
    if dtype.kind == "f":
        with np.errstate(over="ignore", invalid="ignore"):
            return values.astype(dtype)
    info = np.iinfo(dtype)
    ok = np.isfinite(values) & (values >= info.min) & (values <= info.max)
    return np.where(ok, values, 0.0).astype(dtype)


def pack_points(points: ArrayLike, fields: Sequence[FieldSpec], point_step: int, *,
                big_endian: bool = False) -> bytes:
    """Write points into ``N * point_step`` bytes following a (possibly invalid) field table.

    Parameters
    ----------
    points : (N, 3) float array [m]
        Values of the fields named ``x``, ``y`` and ``z``; every other field gets its point's
        index (so that overlapping fields overwrite each other visibly).
    fields : sequence of FieldSpec
        Written in order; later fields overwrite earlier ones where they overlap.  Bytes of
        a field that would reach past ``point_step`` (or start before 0) are cut off.
    point_step : int
        Bytes per point (>= 0).
    big_endian : bool
        Byte order of every element.

    Returns
    -------
    bytes
        ``N * point_step`` bytes, zero where no field writes.
    """
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    n, step = len(pts), max(0, int(point_step))
    buf = np.zeros((n, step), dtype=np.uint8)
    order = ">" if big_endian else "<"
    for f in fields:
        dtype = ELEMENT_DTYPES.get(f.datatype)
        if dtype is None:
            continue  # unknown code: leave its bytes zero
        values = pts[:, _AXES[f.name]] if f.name in _AXES else np.arange(n, dtype=np.float64)
        element = _element_values(values, dtype.newbyteorder(order))
        raw = np.repeat(element[:, None], max(0, f.count), axis=1).view(np.uint8)
        start, stop = f.offset, f.offset + raw.shape[1]
        lo, hi = max(start, 0), min(stop, step)
        if n and hi > lo:
            buf[:, lo:hi] = raw[:, lo - start:hi - start]
    return buf.tobytes()


def raw_cloud(header: Header, fields: Sequence[FieldSpec], *, height: int, width: int,
              point_step: int, row_step: int, data: bytes, big_endian: bool = False,
              is_dense: bool = False) -> PointCloud2:
    """Assemble a PointCloud2 exactly as given (no field, size or data check).

    Parameters
    ----------
    header : std_msgs.msg.Header
        Copied into the message as is.
    fields : sequence of FieldSpec
        The declared field table.
    height, width, point_step, row_step : int
        Declared geometry (each must fit the message's uint32 fields: 0 .. 2**32 - 1).
    data : bytes
        The payload, of any length.
    big_endian, is_dense : bool
        Declared flags.

    Returns
    -------
    sensor_msgs.msg.PointCloud2
    """
    msg = PointCloud2(header=header, height=int(height), width=int(width),
                      is_bigendian=bool(big_endian), point_step=int(point_step),
                      row_step=int(row_step), is_dense=bool(is_dense),
                      fields=[PointField(name=f.name, offset=int(f.offset),
                                         datatype=int(f.datatype), count=int(f.count))
                              for f in fields])
    msg.data = array.array("B", memoryview(data))
    return msg
