"""Reading and writing point cloud files: PCD, PLY and NPY.

Everything here is plain numpy (and liblzf for compressed PCD); no ROS, no PCL.

* PCD v0.6 / v0.7 with ``DATA ascii``, ``binary`` and ``binary_compressed`` (LZF), read by
  :func:`read_pcd` (keeps every field, e.g. ``label``) and written by :func:`write_pcd`
  (all three, laid out as PCL writes them): module :mod:`geomodel_ros.tools.pcd_file`.
* PLY ``ascii`` / ``binary_little_endian`` / ``binary_big_endian`` vertex clouds, read by
  :func:`read_ply` and written by :func:`write_ply`: module
  :mod:`geomodel_ros.tools.ply_file`.
* NPY arrays of shape (N, 3) or (H, W, 3), read by :func:`read_npy`, written by
  :func:`write_npy` (here).

:func:`read_cloud` and :func:`write_cloud` dispatch on the file suffix. Every problem with
a file being read (missing, unreadable, empty, corrupt, truncated, wrong shape, unknown
suffix) raises :class:`CloudFileError`, whose message names the file and says what was wrong
and what is allowed. Invalid arguments to the writers raise :class:`ValueError`; operating
system errors while writing propagate as :class:`OSError`.

What a writer stores, its reader gives back bit for bit (x y z widened to float64; ascii
files store every NaN as ``nan``). Reading holds the result plus at most one copy of the
file's data (for ``binary_compressed``: the decompressed data), never the whole file on
top of a copy of it; ``python -m geomodel_ros.tools.bench_io`` measures it.

:func:`load_osd` loads a scene of the Object Segmentation Database (``osd_learn``) with the
raw per-point labels mapped to object ids.
"""

from __future__ import annotations

import os
import warnings
from io import BytesIO
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike, NDArray

from geomodel_ros.tools.cloud_file import Cloud, CloudFileError, PathLike, read_bytes
from geomodel_ros.tools.pcd_file import lzf_decompress, read_pcd, write_pcd
from geomodel_ros.tools.ply_file import read_ply, write_ply

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

#: File suffixes understood by :func:`read_cloud` and :func:`write_cloud`.
CLOUD_SUFFIXES = (".npy", ".pcd", ".ply")

#: Bytes of an NPY file that can hold its header: numpy refuses headers over 10 kB (its
#: ``max_header_size``), so parsing never needs a copy of more than this.
_NPY_HEAD_BYTES = 1 << 16
#: Object id :func:`load_osd` gives the table (raw labels 1-9).
OSD_TABLE_ID = 0
#: Object id :func:`load_osd` gives invalid points (raw label 0).
OSD_INVALID_ID = -1


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
    buf = read_bytes(path)
    shape, fortran_order, dtype, offset = _npy_header(buf, name)
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


def _npy_header(buf: bytearray, name: str) -> tuple[tuple, bool, np.dtype, int]:
    """Parse the header of an NPY file: shape, Fortran order, dtype and the data offset."""
    stream = BytesIO(buf[:_NPY_HEAD_BYTES])  # the header only: BytesIO copies what it gets
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
    return shape, fortran_order, dtype, stream.tell()


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
    with np.errstate(invalid="ignore"):  # signalling-NaN payloads stay NaN, silently
        array = array.astype(np.float64, copy=False)
    with open(path, "wb") as stream:
        np.save(stream, array, allow_pickle=False)


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
