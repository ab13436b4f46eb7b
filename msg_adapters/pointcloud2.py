"""``sensor_msgs/PointCloud2`` <-> numpy, as pure functions.

Reading goes through a zero-copy structured view of ``msg.data``: its dtype is built from
``msg.fields`` (names, offsets, datatypes, ``count > 1`` as sub-arrays, byte order from
``is_bigendian``) with ``itemsize = point_step``, laid over the buffer with strides
``(row_step, point_step)`` so point padding and row padding are both respected.  Only the
requested fields are then copied out, converted to native byte order on the way, so the
caller's message is never modified (no in-place byteswap) and the arrays returned never
share memory with it.

Writing builds the message's ``array.array('B')`` buffer first and fills it through a
structured numpy view, so the points are written exactly once and the message's ``data``
setter takes the buffer as is.  (``msg.data = arr.tobytes()`` makes an extra copy and,
with ``ROS_PYTHON_CHECK_FIELDS=1``, runs a per-byte Python check: ~100x slower.)

Nothing here needs ``rclpy.init``.  Messages are read duck-typed: anything with the
``PointCloud2`` attributes works, e.g. messages deserialized by ``rosbags`` whose ``data``
is a ``uint8`` numpy array.

Coordinates are in metres, in the frame named by the header (REP 103).
"""

from __future__ import annotations

import array
from collections.abc import Iterable, Mapping
from typing import Final, NamedTuple

import numpy as np
from builtin_interfaces.msg import Time
from numpy.typing import ArrayLike, DTypeLike, NDArray
from sensor_msgs.msg import PointCloud2, PointField
from std_msgs.msg import Header

__all__ = [
    "CloudSize",
    "PointCloud2Error",
    "ScenePoints",
    "cloud_size",
    "cloud_to_fields",
    "cloud_to_scene",
    "cloud_to_xyz",
    "cloud_to_xyz_and_mask",
    "pack_rgb",
    "structured_view",
    "unpack_rgb",
    "xyz_to_cloud",
]


class PointCloud2Error(ValueError):
    """A ``PointCloud2`` message whose layout is invalid or unsupported.

    The message says what was wrong and what is allowed.  Callers that process a stream
    (the node) catch it, log it and drop that one frame.
    """


#: sensor_msgs/PointField datatype constants -> (name, element dtype without byte order).
_DATATYPES: Final[dict[int, tuple[str, np.dtype]]] = {
    PointField.INT8: ("INT8", np.dtype(np.int8)),
    PointField.UINT8: ("UINT8", np.dtype(np.uint8)),
    PointField.INT16: ("INT16", np.dtype(np.int16)),
    PointField.UINT16: ("UINT16", np.dtype(np.uint16)),
    PointField.INT32: ("INT32", np.dtype(np.int32)),
    PointField.UINT32: ("UINT32", np.dtype(np.uint32)),
    PointField.FLOAT32: ("FLOAT32", np.dtype(np.float32)),
    PointField.FLOAT64: ("FLOAT64", np.dtype(np.float64)),
}
_ALLOWED_DATATYPES: Final = ", ".join(f"{code} ({name})" for code, (name, _) in _DATATYPES.items())
#: Little-endian element dtype (as written by ``xyz_to_cloud``) -> PointField datatype.
_DATATYPE_OF: Final[dict[np.dtype, int]] = {
    dt.newbyteorder("<"): code for code, (_, dt) in _DATATYPES.items()
}
_DATATYPE_NAMES: Final[dict[np.dtype, str]] = {
    dt.newbyteorder("<"): name for name, dt in _DATATYPES.values()
}
_XYZ: Final = ("x", "y", "z")
#: Fields holding colour packed PCL-style in 4 bytes (0x00RRGGBB / 0xAARRGGBB), usually
#: declared FLOAT32 so that RViz shows colours; they are read and written as uint32 bits.
_PACKED_COLOUR_FIELDS: Final = frozenset({"rgb", "rgba"})
#: PCL's name for padding fields; they may repeat and are never read.
_PADDING_FIELD: Final = "_"


class _Layout(NamedTuple):
    """The validated geometry of a PointCloud2 message."""

    height: int
    width: int
    point_step: int
    row_step: int
    dtype: np.dtype  # structured, itemsize == point_step, every non-padding field
    buffer: NDArray[np.uint8]  # read-only flat byte view of msg.data (no copy)


def _field_format(
    index: int, field: PointField, order: str, point_step: int
) -> tuple[str, np.dtype | tuple[np.dtype, tuple[int]], int]:
    """Check one PointField; its name, numpy format (sub-array if count > 1) and offset."""
    name, offset = str(field.name), int(field.offset)
    code, count = int(field.datatype), int(field.count)
    if not name:
        raise PointCloud2Error(f"PointField #{index} has an empty name; every field needs a name")
    if code not in _DATATYPES:
        raise PointCloud2Error(
            f"PointField {name!r} has datatype {code}; allowed datatypes are "
            f"{_ALLOWED_DATATYPES}"
        )
    if count < 1:
        raise PointCloud2Error(f"PointField {name!r} has count {count}; count must be >= 1")
    element = _DATATYPES[code][1].newbyteorder(order)
    end = offset + element.itemsize * count
    if offset < 0 or end > point_step:
        raise PointCloud2Error(
            f"PointField {name!r} ({_DATATYPES[code][0]} x {count}) occupies bytes "
            f"[{offset}, {end}) of each point but point_step is {point_step}; "
            f"fields must lie within [0, point_step)"
        )
    return name, element if count == 1 else (element, (count,)), offset


def _layout(msg: PointCloud2) -> _Layout:
    """Validate ``msg``'s geometry and field table and build its structured dtype.

    Raises
    ------
    PointCloud2Error
        On an unsupported datatype code, a count < 1, an empty or repeated field name, a
        field reaching past ``point_step``, rows too short for ``width`` points, or a data
        length other than ``row_step * height``.
    """
    height, width = int(msg.height), int(msg.width)
    point_step, row_step = int(msg.point_step), int(msg.row_step)
    order = ">" if msg.is_bigendian else "<"

    names: list[str] = []
    formats: list[np.dtype | tuple[np.dtype, tuple[int]]] = []
    offsets: list[int] = []
    for index, field in enumerate(msg.fields):
        name, element, offset = _field_format(index, field, order, point_step)
        if name == _PADDING_FIELD:
            continue
        if name in names:
            raise PointCloud2Error(
                f"PointField name {name!r} appears more than once; field names must be unique "
                f"(only {_PADDING_FIELD!r} padding fields may repeat)"
            )
        names.append(name)
        formats.append(element)
        offsets.append(offset)

    if point_step * width > row_step:
        raise PointCloud2Error(
            f"PointCloud2 point_step*width = {point_step}*{width} = {point_step * width} bytes "
            f"exceeds row_step = {row_step}; a row must hold width points"
        )
    buffer = _byte_view(msg.data)
    if buffer.size != row_step * height:
        raise PointCloud2Error(
            f"PointCloud2 data has {buffer.size} bytes, expected row_step*height = "
            f"{row_step}*{height} = {row_step * height}"
        )
    dtype = np.dtype(
        {"names": names, "formats": formats, "offsets": offsets, "itemsize": point_step}
    )
    return _Layout(height, width, point_step, row_step, dtype, buffer)


def _byte_view(data: object) -> NDArray[np.uint8]:
    """Return a read-only flat ``uint8`` view of ``data`` (array.array, bytes, ndarray, ...)."""
    try:
        buffer = np.frombuffer(data, dtype=np.uint8)  # type: ignore[call-overload]
    except (TypeError, ValueError):  # a list of ints, a strided array: one unavoidable copy
        buffer = np.array(data, dtype=np.uint8).reshape(-1)
    buffer.flags.writeable = False
    return buffer


def _view(layout: _Layout) -> NDArray[np.void]:
    """Return the read-only ``(height, width)`` structured view of the message's points."""
    if layout.height * layout.width == 0:
        view = np.empty((layout.height, layout.width), dtype=layout.dtype)
        view.flags.writeable = False
        return view
    return np.ndarray(
        shape=(layout.height, layout.width),
        dtype=layout.dtype,
        buffer=layout.buffer,
        strides=(layout.row_step, layout.point_step),
    )


def _check_xyz(layout: _Layout) -> None:
    fields = layout.dtype.fields or {}
    for name in _XYZ:
        if name not in fields:
            present = ", ".join(repr(n) for n in fields) or "none"
            raise PointCloud2Error(
                f"PointCloud2 has no field {name!r} (fields: {present}); x, y and z are required"
            )
        field_dtype = fields[name][0]
        element, shape = field_dtype.subdtype or (field_dtype, ())
        if shape or element.kind != "f":
            described = _DATATYPE_NAMES[element.newbyteorder("<")] + (
                f" x {shape[0]}" if shape else ""
            )
            raise PointCloud2Error(
                f"PointField {name!r} is {described}; x, y and z must be FLOAT32 or FLOAT64 "
                "with count 1"
            )


def _float_dtype(dtype: DTypeLike) -> np.dtype:
    result = np.dtype(dtype)
    if result.kind != "f":
        raise ValueError(
            f"dtype must be a floating type such as np.float32 or np.float64, got {result}"
        )
    return result


def structured_view(msg: PointCloud2) -> NDArray[np.void]:
    """Zero-copy, read-only structured view of the points of ``msg``.

    Parameters
    ----------
    msg : sensor_msgs.msg.PointCloud2
        Any layout this module accepts; fields named ``'_'`` (padding) are left out.

    Returns
    -------
    view : (height, width) structured array
        Shares memory with ``msg.data`` and is read-only.  Field dtypes carry the message's
        byte order; ``count > 1`` fields are sub-arrays.  While the view is alive, an
        ``array.array`` ``msg.data`` cannot be resized, so do not keep it longer than needed.

    Raises
    ------
    PointCloud2Error
        If the layout is invalid (see ``cloud_to_xyz``).
    """
    return _view(_layout(msg))


def cloud_to_xyz_and_mask(
    msg: PointCloud2, *, skip_nans: bool = True, dtype: DTypeLike = np.float64
) -> tuple[NDArray[np.floating], NDArray[np.bool_]]:
    """Points of ``msg`` as an ``(N, 3)`` array, plus which of the cloud's points they are.

    Parameters
    ----------
    msg : sensor_msgs.msg.PointCloud2
        x, y, z must be FLOAT32 or FLOAT64 fields with count 1 [m].
    skip_nans : bool
        Drop points whose x, y or z is not finite (NaN, and the +-Inf of REP 117).
    dtype : floating dtype
        dtype of the returned points.

    Returns
    -------
    points : (N, 3) array of ``dtype`` [m]
        A new C-contiguous array (never a view of ``msg.data``), in row-major point order.
    mask : (height * width,) bool array
        ``mask[row * width + col]`` is True iff that point is in ``points``;
        ``np.flatnonzero(mask)[i]`` is the original index of ``points[i]``.  Pass it to
        ``cloud_to_fields`` to get other fields aligned with ``points``.

    Raises
    ------
    PointCloud2Error
        If the layout is invalid (see ``cloud_to_xyz``).
    ValueError
        If ``dtype`` is not a floating type.
    """
    out_dtype = _float_dtype(dtype)
    layout = _layout(msg)
    n = layout.height * layout.width
    if n == 0:
        return np.empty((0, 3), dtype=out_dtype), np.zeros(0, dtype=bool)
    _check_xyz(layout)
    view = _view(layout)
    columns = [view[name] for name in _XYZ]  # (H, W) strided views, no copy
    if skip_nans:
        mask = np.isfinite(columns[0])
        mask &= np.isfinite(columns[1])
        mask &= np.isfinite(columns[2])
        mask = mask.reshape(n)
        kept = int(np.count_nonzero(mask))
    else:
        mask, kept = np.ones(n, dtype=bool), n
    points = np.empty((kept, 3), dtype=out_dtype)
    if kept == n:
        grid = points.reshape(layout.height, layout.width, 3)  # a view: points is contiguous
        for i, column in enumerate(columns):
            grid[..., i] = column
    else:
        grid_mask = mask.reshape(layout.height, layout.width)
        for i, column in enumerate(columns):
            points[:, i] = column[grid_mask]
    return points, mask


def cloud_to_xyz(
    msg: PointCloud2,
    *,
    keep_organized: bool = False,
    skip_nans: bool = True,
    dtype: DTypeLike = np.float64,
) -> NDArray[np.floating]:
    """Points of ``msg`` as a numpy array.

    Parameters
    ----------
    msg : sensor_msgs.msg.PointCloud2
        Any field order, offsets and padding (``point_step`` and ``row_step``), either byte
        order; x, y, z must be FLOAT32 or FLOAT64 fields with count 1 [m].
    keep_organized : bool
        Return the ``(height, width, 3)`` grid with every point, NaNs included
        (``skip_nans`` is then ignored).
    skip_nans : bool
        Drop points whose x, y or z is not finite (NaN, and the +-Inf of REP 117).  Use
        ``cloud_to_xyz_and_mask`` to know which points were kept.
    dtype : floating dtype
        dtype of the returned points.

    Returns
    -------
    points : (N, 3) or (height, width, 3) array of ``dtype`` [m]
        A new C-contiguous array, never a view of ``msg.data``.  An empty cloud
        (``height * width == 0``) gives shape ``(0, 3)`` (or ``(height, width, 3)``), and
        then x, y, z need not be declared.

    Raises
    ------
    PointCloud2Error
        If x, y or z is missing or not FLOAT32/FLOAT64 with count 1; a field has an
        unsupported datatype code, a count < 1, an empty or repeated name, or reaches past
        ``point_step``; ``point_step * width > row_step``; or
        ``len(data) != row_step * height``.
    ValueError
        If ``dtype`` is not a floating type.
    """
    if not keep_organized:
        return cloud_to_xyz_and_mask(msg, skip_nans=skip_nans, dtype=dtype)[0]
    out_dtype = _float_dtype(dtype)
    layout = _layout(msg)
    points = np.empty((layout.height, layout.width, 3), dtype=out_dtype)
    if points.size == 0:
        return points
    _check_xyz(layout)
    view = _view(layout)
    for i, name in enumerate(_XYZ):
        # FLOAT64 fields beyond a float32 output's range become +-inf.
        with np.errstate(over="ignore", invalid="ignore"):
            points[..., i] = view[name]
    return points


class CloudSize(NamedTuple):
    """Grid and payload of a cloud (see :func:`cloud_size`)."""

    height: int
    width: int
    #: Bytes of ``data`` (``row_step * height`` in a well-formed message).
    nbytes: int


def cloud_size(msg: PointCloud2) -> CloudSize:
    """``height``, ``width`` and the size of ``data`` [bytes] of a cloud, as declared."""
    return CloudSize(int(msg.height), int(msg.width), int(len(msg.data)))


class ScenePoints(NamedTuple):
    """A cloud as the core takes it (see :func:`cloud_to_scene`)."""

    #: (N, 3) float64 array [m], every point in row-major order, NaN rows kept.
    points: NDArray[np.float64]
    #: (height, width) of an organized cloud (height > 1), else None.
    organized_shape: tuple[int, int] | None
    #: The input's header, to be copied into the outputs (std_msgs/Header).
    header: Header


def cloud_to_scene(msg: PointCloud2) -> ScenePoints:
    """Every point of ``msg`` (NaNs included, so labels stay pixel-aligned) and its grid.

    Parameters
    ----------
    msg : sensor_msgs.msg.PointCloud2
        Any layout :func:`cloud_to_xyz` reads.  Not modified.

    Returns
    -------
    ScenePoints
        ``points`` is ``(height * width, 3)`` float64 [m]; ``organized_shape`` is
        ``(height, width)`` when ``height > 1``.

    Raises
    ------
    PointCloud2Error
        As :func:`cloud_to_xyz`.
    """
    grid = cloud_to_xyz(msg, keep_organized=True)
    organized = (int(grid.shape[0]), int(grid.shape[1])) if grid.shape[0] > 1 else None
    return ScenePoints(grid.reshape(-1, 3), organized, msg.header)


def cloud_to_fields(
    msg: PointCloud2,
    names: Iterable[str],
    *,
    mask: ArrayLike | None = None,
    keep_organized: bool = False,
) -> dict[str, NDArray[np.generic]]:
    """Other fields of ``msg`` (colour, labels, intensity...), aligned with the points.

    Parameters
    ----------
    msg : sensor_msgs.msg.PointCloud2
        The cloud; see ``cloud_to_xyz`` for the layouts accepted.
    names : iterable of str
        Field names to return, e.g. ``("rgb", "object_id")``.
    mask : (height * width,) or (height, width) bool array, optional
        Keep only these points, e.g. the mask from ``cloud_to_xyz_and_mask`` so that the
        fields line up with the points it returned.
    keep_organized : bool
        Return ``(height, width, ...)`` grids instead of ``(N, ...)`` arrays.

    Returns
    -------
    fields : dict of str to array
        One new array per name, in native byte order, shape ``(N,)`` (``(N, count)`` for
        ``count > 1``) or ``(height, width[, count])`` when ``keep_organized``.  The dtype
        is the field's declared one, except that a 4-byte ``'rgb'``/``'rgba'`` field
        (usually declared FLOAT32, PCL-style) is returned as its ``uint32`` bits
        (``0x00RRGGBB``; see ``unpack_rgb``).

    Raises
    ------
    PointCloud2Error
        If a requested field is not in the message, or the layout is invalid.
    ValueError
        If ``mask`` is not a boolean array of ``height * width`` points, or is given
        together with ``keep_organized``.
    """
    wanted = [names] if isinstance(names, str) else list(names)
    layout = _layout(msg)
    fields = layout.dtype.fields or {}
    for name in wanted:
        if name not in fields:
            present = ", ".join(repr(n) for n in fields) or "none"
            raise PointCloud2Error(f"PointCloud2 has no field {name!r} (fields: {present})")
    n = layout.height * layout.width
    grid_mask: NDArray[np.bool_] | None = None
    if mask is not None:
        if keep_organized:
            raise ValueError("mask and keep_organized=True cannot be combined; pass one of them")
        grid_mask = np.asarray(mask)
        if grid_mask.dtype != np.bool_ or grid_mask.size != n or grid_mask.ndim not in (1, 2):
            raise ValueError(
                f"mask must be a bool array of shape ({n},) or ({layout.height}, {layout.width}), "
                f"got {grid_mask.dtype} array of shape {grid_mask.shape}"
            )
        grid_mask = grid_mask.reshape(layout.height, layout.width)
    view = _view(layout)
    result: dict[str, NDArray[np.generic]] = {}
    for name in wanted:
        values = view[name]  # (H, W[, count]) strided view, message byte order
        base = values.dtype
        if name in _PACKED_COLOUR_FIELDS and base.itemsize == 4 and values.ndim == 2:
            base = np.dtype(np.uint32).newbyteorder(base.byteorder)
            values = values.view(base)
        if grid_mask is not None:
            values = values[grid_mask]
        elif not keep_organized:
            values = values.reshape((n, *values.shape[2:]))
        result[name] = np.array(values, dtype=base.newbyteorder("="), order="C", copy=True)
    return result


def pack_rgb(rgb: ArrayLike) -> NDArray[np.uint32]:
    """Pack 8-bit colours PCL/RViz-style into ``uint32``.

    Parameters
    ----------
    rgb : (..., 3) or (..., 4) integer array in [0, 255]
        Red, green, blue (and alpha) channels.

    Returns
    -------
    packed : (...,) uint32 array
        ``0x00RRGGBB`` (``0xAARRGGBB`` with alpha).  Store it in a FLOAT32 field named
        ``'rgb'`` (``'rgba'``) -- ``xyz_to_cloud`` does -- for RViz to show the colours.

    Raises
    ------
    ValueError
        If ``rgb`` is not an integer array with a last axis of 3 or 4 and values in [0, 255].
    """
    channels = np.asarray(rgb)
    if channels.ndim < 1 or channels.shape[-1] not in (3, 4) or channels.dtype.kind not in "ui":
        raise ValueError(
            f"rgb must be an integer array of shape (..., 3) or (..., 4) with values in [0, 255], "
            f"got {channels.dtype} array of shape {channels.shape}; "
            "convert colours in [0, 1] with (rgb * 255).round().astype(np.uint8)"
        )
    if (
        channels.dtype != np.uint8
        and channels.size
        and (channels.min() < 0 or channels.max() > 255)
    ):
        raise ValueError(
            f"rgb values must lie in [0, 255], got [{channels.min()}, {channels.max()}]"
        )
    c = channels.astype(np.uint32)
    packed = (c[..., 0] << 16) | (c[..., 1] << 8) | c[..., 2]
    if channels.shape[-1] == 4:
        packed |= c[..., 3] << 24
    return packed


def unpack_rgb(packed: ArrayLike, *, alpha: bool = False) -> NDArray[np.uint8]:
    """Unpack PCL/RViz-style colours, the inverse of ``pack_rgb``.

    Parameters
    ----------
    packed : (...,) uint32 array (or the float32 whose bits hold it)
        ``0x00RRGGBB`` / ``0xAARRGGBB`` values, e.g. ``cloud_to_fields(msg, ["rgb"])["rgb"]``.
    alpha : bool
        Also return the alpha channel (bits 24..31).

    Returns
    -------
    rgb : (..., 3) uint8 array, or (..., 4) when ``alpha``

    Raises
    ------
    ValueError
        If ``packed`` is neither an integer nor a float32 array.
    """
    values = np.asarray(packed)
    if values.dtype.kind == "f" and values.dtype.itemsize == 4:
        bits = values.view(np.uint32)  # the colour is in the float's bit pattern
    elif values.dtype.kind in "ui":
        bits = values.astype(np.uint32)
    else:
        raise ValueError(
            f"packed colours must be uint32 (or float32 bit patterns), got {values.dtype}"
        )
    shifts = np.array([16, 8, 0, 24] if alpha else [16, 8, 0], dtype=np.uint32)
    return ((bits[..., np.newaxis] >> shifts) & 0xFF).astype(np.uint8)


class _OutField(NamedTuple):
    name: str
    values: NDArray[np.generic]  # (N,) or (N, count), little-endian storage dtype
    datatype: int  # declared PointField datatype
    count: int


def _packed_colours(name: str, arr: NDArray) -> NDArray[np.uint32]:
    """Convert a colour field to little-endian uint32 ``0xAARRGGBB`` bits."""
    if arr.ndim == 2 and arr.shape[1] in (3, 4) and arr.dtype.kind in "ui":
        arr = pack_rgb(arr)
    elif arr.ndim == 1 and arr.dtype.kind == "f" and arr.dtype.itemsize == 4:
        arr = arr.view(np.dtype(np.uint32).newbyteorder(arr.dtype.byteorder))  # same bits
    elif arr.ndim == 1 and arr.dtype.kind in "ui":
        if arr.size and (arr.min() < 0 or arr.max() > 0xFFFFFFFF):
            raise ValueError(f"field {name!r} must hold uint32 packed colours (see pack_rgb)")
        arr = arr.astype(np.uint32)
    else:
        raise ValueError(
            f"field {name!r} must be (N,) uint32 packed colours (see pack_rgb), (N,) float32 "
            f"bit patterns or (N, 3|4) uint8 channels, got {arr.dtype} array of shape "
            f"{arr.shape}"
        )
    return arr.astype("<u4", copy=False)


def _out_field(name: object, values: ArrayLike, n: int, grid: tuple[int, int]) -> _OutField:
    """Validate one extra field for ``xyz_to_cloud`` and convert it to its storage dtype."""
    if not isinstance(name, str) or not name or name == _PADDING_FIELD or name in _XYZ:
        raise ValueError(
            f"extra field name {name!r} is not allowed; use a non-empty str other than "
            f"'x', 'y', 'z' and {_PADDING_FIELD!r}"
        )
    arr = np.asarray(values)
    if arr.ndim >= 2 and arr.shape[:2] == grid:
        arr = arr.reshape((n, *arr.shape[2:]))
    if arr.ndim not in (1, 2) or arr.shape[0] != n or (arr.ndim == 2 and arr.shape[1] < 1):
        raise ValueError(
            f"field {name!r} must have shape ({n},) or ({n}, count) (or {grid}[+ (count,)] for an "
            f"organized cloud), got {arr.shape}"
        )

    if name in _PACKED_COLOUR_FIELDS:
        # Stored as uint32 bits, declared FLOAT32: the PCL/RViz convention.
        return _OutField(name, _packed_colours(name, arr), PointField.FLOAT32, 1)

    kind, size = arr.dtype.kind, arr.dtype.itemsize
    if kind == "b":
        arr = arr.astype(np.uint8)
    elif kind == "f" and size == 2:
        arr = arr.astype(np.float32)
    elif kind in "ui" and size == 8:
        narrow = np.dtype(np.int32 if kind == "i" else np.uint32)
        info = np.iinfo(narrow)
        if arr.size and (arr.min() < info.min or arr.max() > info.max):
            raise ValueError(
                f"field {name!r} has values in [{arr.min()}, {arr.max()}], outside {narrow} "
                "range; PointField integers are at most 32 bits"
            )
        arr = arr.astype(narrow)
    storage = arr.dtype.newbyteorder("<")
    if storage not in _DATATYPE_OF:
        raise ValueError(
            f"field {name!r} has dtype {arr.dtype}; allowed are bool, int8..int64, uint8..uint64 "
            "(64-bit only when the values fit in 32 bits), float16, float32, float64"
        )
    count = 1 if arr.ndim == 1 else arr.shape[1]
    return _OutField(name, arr.astype(storage, copy=False), _DATATYPE_OF[storage], count)


def _copy_header(header: Header) -> Header:
    return Header(
        stamp=Time(sec=int(header.stamp.sec), nanosec=int(header.stamp.nanosec)),
        frame_id=str(header.frame_id),
    )


def _grid(pts: NDArray, organized_shape: tuple[int, int] | None) -> tuple[int, int]:
    """``(height, width)`` of the output cloud for ``(N, 3)`` or ``(H, W, 3)`` points."""
    if pts.dtype.kind not in "uif" or pts.ndim not in (2, 3) or pts.shape[-1] != 3:
        raise ValueError(
            f"points must be a real array of shape (N, 3) or (H, W, 3), got {pts.dtype} "
            f"array of shape {pts.shape}"
        )
    if pts.ndim == 3:
        if organized_shape is not None and tuple(organized_shape) != pts.shape[:2]:
            raise ValueError(
                f"organized_shape {tuple(organized_shape)} disagrees with points of shape "
                f"{pts.shape}"
            )
        return pts.shape[0], pts.shape[1]
    if organized_shape is None:
        return 1, pts.shape[0]
    height, width = (int(v) for v in organized_shape)
    if height < 0 or width < 0 or height * width != pts.shape[0]:
        raise ValueError(
            f"organized_shape {tuple(organized_shape)} must have height * width == N = "
            f"{pts.shape[0]} and no negative size"
        )
    return height, width


def _record_layout(extras: list[_OutField]) -> tuple[list[PointField], np.dtype]:
    """PointFields and the structured dtype (``itemsize = point_step``) of x, y, z + extras."""
    point_fields = [
        PointField(name=name, offset=4 * i, datatype=PointField.FLOAT32, count=1)
        for i, name in enumerate(_XYZ)
    ]
    names, formats, offsets = list(_XYZ), ["<f4"] * 3, [0, 4, 8]
    offset, alignment = 12, 4
    for extra in extras:
        element = extra.values.dtype.itemsize
        offset = -(-offset // element) * element  # align to the element size
        point_fields.append(
            PointField(name=extra.name, offset=offset, datatype=extra.datatype, count=extra.count)
        )
        names.append(extra.name)
        storage = extra.values.dtype.str  # e.g. '<i4'
        formats.append(storage if extra.count == 1 else f"({extra.count},){storage}")
        offsets.append(offset)
        offset += element * extra.count
        alignment = max(alignment, element)
    point_step = -(-offset // alignment) * alignment
    dtype = np.dtype(
        {"names": names, "formats": formats, "offsets": offsets, "itemsize": point_step}
    )
    return point_fields, dtype


def _fill(flat: NDArray, extras: list[_OutField], dtype: np.dtype) -> tuple[array.array, bool]:
    """Fill a new data buffer with the points and extras; also whether all are finite."""
    n = len(flat)
    # The message owns this buffer; fill it in place through a structured view.
    data = array.array("B", b"\0") * (n * dtype.itemsize)
    is_dense = True
    if n:
        record = np.frombuffer(data, dtype=dtype)
        for i, name in enumerate(_XYZ):
            # Coordinates beyond float32's range become +-inf (not finite: not dense).
            with np.errstate(over="ignore", invalid="ignore"):
                record[name] = flat[:, i]
            is_dense = is_dense and bool(np.isfinite(record[name]).all())
        for extra in extras:
            record[extra.name] = extra.values
        del record  # release the buffer export so that the array.array stays resizable
    return data, is_dense


def xyz_to_cloud(
    points: ArrayLike,
    header: Header,
    *,
    fields: Mapping[str, ArrayLike] | None = None,
    organized_shape: tuple[int, int] | None = None,
) -> PointCloud2:
    """Build a ``PointCloud2`` with FLOAT32 x, y, z and optional extra fields.

    Parameters
    ----------
    points : (N, 3) or (H, W, 3) real array [m]
        Stored as little-endian float32 (values beyond its range as +-inf); NaNs are kept
        (organized clouds need them).
    header : std_msgs.msg.Header
        ``frame_id`` and ``stamp`` are copied into a new header of the output.
    fields : dict of str to array, optional
        Extra per-point fields in the given order, each ``(N,)`` or ``(N, count)`` (or
        ``(H, W[, count])``).  ``'rgb'``/``'rgba'`` take ``uint32`` packed colours
        (``pack_rgb``) or ``(N, 3|4)`` uint8 channels and are declared FLOAT32 holding those
        bits, as PCL and RViz expect.  Other fields keep their dtype (bool -> UINT8, float16
        -> FLOAT32; int64/uint64 -> INT32/UINT32 when the values fit), e.g. ``object_id``.
    organized_shape : (H, W), optional
        Grid of an organized cloud for ``(N, 3)`` points (``H * W == N``); by default
        ``(N, 3)`` points give ``height = 1, width = N`` and ``(H, W, 3)`` points a grid.

    Returns
    -------
    msg : sensor_msgs.msg.PointCloud2
        x, y, z at offsets 0, 4, 8, extra fields after them aligned to their element size,
        ``point_step`` a multiple of 4 (16 for x, y, z, rgb); ``row_step = point_step *
        width``; padding bytes zero; ``is_bigendian`` False; ``is_dense`` True iff every
        x, y, z is finite.

    Raises
    ------
    ValueError
        If the shapes disagree, a dtype cannot be stored in a PointField, or a field name is
        empty, repeated ('x', 'y', 'z') or ``'_'``.
    """
    pts = np.asarray(points)
    height, width = _grid(pts, organized_shape)
    n = height * width
    flat = pts.reshape(n, 3)
    extras = [
        _out_field(name, values, n, (height, width)) for name, values in (fields or {}).items()
    ]
    point_fields, dtype = _record_layout(extras)
    point_step = dtype.itemsize
    data, is_dense = _fill(flat, extras, dtype)

    msg = PointCloud2(
        header=_copy_header(header),
        height=height,
        width=width,
        fields=point_fields,
        is_bigendian=False,
        point_step=point_step,
        row_step=point_step * width,
        is_dense=is_dense,
    )
    # Assigned after construction: the constructor copies a ``data`` argument into a new
    # array.array, the property takes an array.array('B') as it is.
    msg.data = data
    return msg
