"""PLY vertex clouds: read and write (ascii, binary little and big endian).

:func:`read_ply` reads the ``vertex`` element of any PLY file (other elements, e.g. faces,
are skipped); :func:`write_ply` writes xyz with optional colours and further properties.
Our own small parser on numpy: every size the header implies is checked against the file
before data are viewed, and problems raise :class:`CloudFileError` naming what was wrong.
"""

from __future__ import annotations

import itertools
import os
import warnings
from collections.abc import Mapping
from dataclasses import dataclass, field
from io import TextIOWrapper
from typing import BinaryIO

import numpy as np
from numpy.typing import ArrayLike, DTypeLike

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
#: Header lines are short; a file without end_header in this many bytes is not a PLY.
_PLY_MAX_HEADER = 1 << 20


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
        if pos <= 0 or pos >= len(buf) or pos > _PLY_MAX_HEADER:
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
    stream, size, head = open_cloud(path)
    with stream:
        fmt, elements, start = _parse_ply_header(head, name)
        del head  # the file's first MiB; not needed any more
        return _read_ply(stream, size, fmt, elements, start, name)


def _read_ply(
    stream: BinaryIO, size: int, fmt: str, elements: list[_PlyElement], start: int, name: str
) -> Cloud:
    """Read the vertices of the body starting at byte ``start`` (see :func:`read_ply`)."""
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
    if fmt != "ascii":
        points, fields = _binary_vertices(stream, size, start, elements, vertex_index, fmt, name)
        return Cloud(points, {p: fields[p] for p in props if p not in ("x", "y", "z")})
    records = _ascii_vertices(stream, size, start, elements, vertex_index, name)
    points = to_xyz(name, (records["x"], records["y"], records["z"]))
    fields = {p: np.ascontiguousarray(records[p]) for p in props if p not in ("x", "y", "z")}
    return Cloud(points, fields)


def _ascii_vertices(
    stream: BinaryIO,
    size: int,
    start: int,
    elements: list[_PlyElement],
    vertex_index: int,
    name: str,
) -> np.ndarray:
    """Parse the vertex lines of an ascii body into a structured array (one row a vertex)."""
    vertex = elements[vertex_index]
    n = vertex.count
    dtype = np.dtype([(p, code) for p, code in vertex.properties])
    skip = sum(e.count for e in elements[:vertex_index])
    if n == 0:
        return np.zeros(0, dtype=dtype)
    lines = count_lines(stream, start, size)
    if lines < skip + n:
        raise CloudFileError(
            f"{name}: truncated PLY: {lines} body lines, the header needs at least {skip + n}"
        )
    stream.seek(start)
    text = TextIOWrapper(stream, encoding="ascii", newline=None)  # type: ignore[arg-type]
    try:
        with warnings.catch_warnings():  # blank lines are reported below
            warnings.simplefilter("ignore", UserWarning)
            records = np.loadtxt(itertools.islice(text, skip, skip + n), dtype=dtype, ndmin=1)
    except UnicodeDecodeError:
        raise CloudFileError(f"{name}: PLY ascii body is not ASCII text") from None
    except ValueError as exc:
        raise CloudFileError(f"{name}: corrupt PLY ascii vertex data: {exc}") from None
    finally:
        text.detach()  # leave the file to its owner
    if records.shape[0] != n:
        raise CloudFileError(
            f"{name}: corrupt PLY: {n - records.shape[0]} of the {n} vertex lines are blank"
        )
    return records


def _binary_vertices(
    stream: BinaryIO,
    size: int,
    start: int,
    elements: list[_PlyElement],
    vertex_index: int,
    fmt: str,
    name: str,
) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """Read the vertex records of a binary body (after checking the file holds them all).

    Returns the (N, 3) float64 points and every other property as its own array.
    """
    offset = start
    for element in elements[:vertex_index]:
        if element.has_list:
            raise CloudFileError(
                f"{name}: PLY element {element.name!r} before 'vertex' has list "
                "properties; cannot skip it in a binary file"
            )
        size = np.dtype([(f"p{i}", c) for i, (_, c) in enumerate(element.properties)])
        offset += element.count * size.itemsize
    vertex = elements[vertex_index]
    n = vertex.count
    dtype = np.dtype([(p, _PLY_FORMATS[fmt] + code) for p, code in vertex.properties])
    needed = n * dtype.itemsize
    if size - offset < needed:
        raise CloudFileError(
            f"{name}: truncated PLY: {n} vertices need {needed} bytes, the file has "
            f"{max(size - offset, 0)}"
        )
    return read_records(stream, name, offset, dtype, n, lambda _: True)


#: PLY type name of each dtype a written property may have (PLY has no 64-bit integers).
_PLY_NAMES = {"i1": "char", "u1": "uchar", "i2": "short", "u2": "ushort", "i4": "int",
              "u4": "uint", "f4": "float", "f8": "double"}


def write_ply(
    path: PathLike,
    points: ArrayLike,
    colors: ArrayLike | None = None,
    *,
    xyz_dtype: DTypeLike = np.float32,
    fields: Mapping[str, ArrayLike] | None = None,
    encoding: str = "binary_little_endian",
) -> None:
    """Write points (and optional colours and properties) as a PLY vertex cloud.

    Parameters
    ----------
    path : str or os.PathLike
        Output file (overwritten).
    points : (N, 3) or (H, W, 3) array_like [m]
        Coordinates (organized input is flattened row by row; PLY has no organization).
    colors : (N, 3) or (H, W, 3) array_like, optional
        RGB as uint8, or as floats in [0, 1] (scaled by 255 and rounded); written as
        ``uchar red green blue``.
    xyz_dtype : {numpy.float32, numpy.float64}
        Storage type of x, y, z (``float`` or ``double``).
    fields : mapping of str to (N,) array_like, optional
        Further vertex properties after x y z (and the colours), in this order; dtypes
        int8, uint8, int16, uint16, int32, uint32, float32, float64 (what PLY can store).
    encoding : {"binary_little_endian", "binary_big_endian", "ascii"}
        The PLY format (ascii floats are written with round-trip precision).

    Raises
    ------
    ValueError
        If shapes, dtypes, names or the encoding are not allowed.
    OSError
        If the file cannot be written.
    """
    xyz_type = np.dtype(xyz_dtype)
    if xyz_type not in (np.dtype(np.float32), np.dtype(np.float64)):
        raise ValueError(f"xyz_dtype must be float32 or float64, got {xyz_type}")
    if encoding not in _PLY_FORMATS:
        raise ValueError(f"encoding {encoding!r} not allowed; allowed: {', '.join(_PLY_FORMATS)}")
    xyz, _, _ = resolve_shape(points, None, None)
    n = xyz.shape[0]
    columns: list[tuple[str, np.ndarray]] = [
        (axis, xyz[:, k].astype(xyz_type)) for k, axis in enumerate("xyz")
    ]
    if colors is not None:
        rgb = _ply_colors(colors, n)
        columns += [(c, rgb[:, k]) for k, c in enumerate(("red", "green", "blue"))]
    columns += [_ply_field(k, v, n, [c for c, _ in columns]) for k, v in (fields or {}).items()]
    lines = [
        "ply",
        f"format {encoding} 1.0",
        "comment written by geomodel_ros",
        f"element vertex {n}",
        *(f"property {_PLY_NAMES[v.dtype.str[1:]]} {c}" for c, v in columns),
        "end_header",
        "",
    ]
    with open(path, "wb") as stream:
        stream.write("\n".join(lines).encode("ascii"))
        if encoding == "ascii":
            stream.write(ascii_text([v for _, v in columns]).encode("ascii"))
            return
        order = _PLY_FORMATS[encoding]
        table = np.empty(n, dtype=[(c, order + v.dtype.str[1:]) for c, v in columns])
        for c, v in columns:
            table[c] = v
        table.tofile(stream)


def _ply_field(field_name: object, raw: ArrayLike, n: int, taken: list[str]) -> tuple:
    """Check one extra property of :func:`write_ply`; return (name, (N,) values)."""
    if (
        not isinstance(field_name, str)
        or field_name.split() != [field_name]
        or not field_name.isascii()
        or field_name in taken
    ):
        raise ValueError(
            f"field name {field_name!r} not allowed: it must be one ASCII word other than "
            f"{', '.join(taken)}"
        )
    values = np.asarray(raw)
    if values.shape != (n,):
        raise ValueError(f"field {field_name!r} has shape {values.shape}; allowed: ({n},)")
    if values.dtype.str[1:] not in _PLY_NAMES:
        raise ValueError(
            f"field {field_name!r} has dtype {values.dtype}; allowed: int8, uint8, int16, "
            "uint16, int32, uint32, float32, float64"
        )
    return field_name, values


def _ply_colors(colors: ArrayLike, n: int) -> np.ndarray:
    """Check colours for :func:`write_ply`; return them as (N, 3) uint8."""
    rgb = np.asarray(colors)
    if rgb.shape[-1:] != (3,) or rgb.size != 3 * n:
        raise ValueError(
            f"colors must have one RGB triple per point ({n}, 3), got shape {rgb.shape}"
        )
    rgb = rgb.reshape(n, 3)
    if rgb.dtype.kind == "f":
        if n and not (np.isfinite(rgb).all() and rgb.min() >= 0.0 and rgb.max() <= 1.0):
            raise ValueError("float colors must be finite and within [0, 1]")
        return np.rint(rgb * 255.0).astype(np.uint8)
    if rgb.dtype != np.uint8:
        raise ValueError(f"colors must be uint8 or float in [0, 1], got dtype {rgb.dtype}")
    return rgb
