"""``sensor_msgs/Image`` depth + ``sensor_msgs/CameraInfo`` -> organized cloud, as pure functions.

A depth image is the compact form of an organized cloud: 2 (``16UC1``) or 4 (``32FC1``)
bytes per pixel instead of the 12-16 of a ``PointCloud2``, so it crosses DDS between
processes far more easily.  :func:`depth_to_scene` back-projects it with the camera's
pinhole model exactly as ``depth_image_proc/point_cloud_xyz`` does::

    z = depth(v, u),  x = (u - cx) * z / fx,  y = (v - cy) * z / fy

in the image's optical frame (REP 103: x right, y down, z forward), pixel centres at
integer ``(u, v)``.  The intrinsics are those of the projection matrix ``P`` (the
rectified image's, which is what image_geometry and depth_image_proc use), or of ``K``
when ``P`` is not filled in; for the registered/rectified depth that depth drivers
publish, the two agree.  **Lens distortion is not applied**: a depth image is expected to
be rectified (``image_rect``, registered depth) or from a sensor without distortion; a raw
image from a distorting lens gives points that are off by the distortion.  Binning and a
region of interest in ``CameraInfo`` are not supported (a clear error).

Encodings (``sensor_msgs/image_encodings``): ``16UC1`` depth in millimetres, 0 = no
return; ``32FC1`` depth in metres, NaN, +-inf, 0 and negative values = no return.  Pixels
without a return give NaN points, so the cloud stays pixel-aligned (organized).  Row
padding (``step`` > ``width`` * bytes per pixel) and ``is_bigendian`` are respected; the
caller's message is never modified.

The builders :func:`depth_image` and :func:`camera_info` make the messages a depth driver
would publish (tests, benchmarks, the synthetic camera).  Nothing here needs
``rclpy.init``; messages are read duck-typed (``rosbags`` messages work too).
"""

from __future__ import annotations

import array
from typing import Final, NamedTuple

import numpy as np
from builtin_interfaces.msg import Time
from numpy.typing import ArrayLike, NDArray
from sensor_msgs.msg import CameraInfo, Image, RegionOfInterest
from std_msgs.msg import Header

from msg_adapters.pointcloud2 import ScenePoints, _byte_view

__all__ = [
    "DEPTH_ENCODINGS",
    "CameraModel",
    "DepthImageError",
    "camera_info",
    "camera_model",
    "depth_image",
    "depth_to_metres",
    "depth_to_scene",
    "depth_to_xyz",
]

#: Supported encodings -> (element dtype without byte order, units per metre).  Dividing
#: by 1000 (not multiplying by 1e-3) gives the correctly rounded metres of a millimetre value.
DEPTH_ENCODINGS: Final[dict[str, tuple[np.dtype, float]]] = {
    "16UC1": (np.dtype(np.uint16), 1000.0),  # REP 118: millimetres
    "32FC1": (np.dtype(np.float32), 1.0),  # REP 118: metres
}
#: Largest depth a 16UC1 image can hold [m] (65535 mm); deeper points are written as 0.
MAX_16UC1_DEPTH_M: Final = 65.535


class DepthImageError(ValueError):
    """A depth ``Image`` or ``CameraInfo`` that is invalid, unsupported or inconsistent.

    The message says what was wrong and what is allowed.  The node catches it, logs it
    (throttled) and drops that one frame.
    """


class CameraModel(NamedTuple):
    """Pinhole intrinsics of a depth image [px] (pixel centres at integer coordinates)."""

    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int


def camera_model(info: CameraInfo) -> CameraModel:
    """Read the pinhole intrinsics of ``info`` (``P`` if set, else ``K``).

    Parameters
    ----------
    info : sensor_msgs.msg.CameraInfo
        ``width``, ``height`` [px] and ``p`` (3 x 4, row-major) or ``k`` (3 x 3).

    Returns
    -------
    CameraModel

    Raises
    ------
    DepthImageError
        If the matrix used (``P`` when any of it is non-zero, else ``K``) has no finite
        positive focal lengths and finite principal point, the size is zero, or binning / a
        region of interest is set.
    """
    width, height = int(info.width), int(info.height)
    if width < 1 or height < 1:
        raise DepthImageError(f"CameraInfo has size {width} x {height}; width and height "
                              "must be >= 1 (is the camera calibrated?)")
    binning = (int(info.binning_x), int(info.binning_y))
    roi = info.roi
    full = (int(roi.x_offset), int(roi.y_offset), int(roi.width), int(roi.height)) in (
        (0, 0, 0, 0), (0, 0, width, height))  # both mean "the whole image"
    if max(binning) > 1 or not full:
        raise DepthImageError(
            f"CameraInfo uses binning {binning} / region of interest "
            f"({int(roi.x_offset)}, {int(roi.y_offset)}, {int(roi.width)} x {int(roi.height)})"
            "; only full-resolution images (binning 0 or 1, roi empty or the whole image) "
            "are supported")
    p = np.asarray(info.p, dtype=np.float64).reshape(3, 4)
    k = np.asarray(info.k, dtype=np.float64).reshape(3, 3)
    name, m = ("P", p) if p.any() else ("K", k)  # P not filled in: use K
    fx, fy, cx, cy = m[0, 0], m[1, 1], m[0, 2], m[1, 2]
    if not (np.isfinite([fx, fy, cx, cy]).all() and fx > 0 and fy > 0):
        raise DepthImageError(
            f"CameraInfo {name} has fx={fx}, fy={fy}, cx={cx}, cy={cy}; focal lengths must "
            "be finite and > 0 and the principal point finite (is the camera calibrated?)")
    return CameraModel(float(fx), float(fy), float(cx), float(cy), width, height)


def depth_to_metres(msg: Image, *, dtype: np.dtype | type = np.float32) -> NDArray[np.floating]:
    """Depth of every pixel of ``msg`` in metres, NaN where there is no return.

    Parameters
    ----------
    msg : sensor_msgs.msg.Image
        ``16UC1`` [mm] or ``32FC1`` [m], either byte order, rows ``step`` bytes apart.
    dtype : floating dtype
        dtype of the result.

    Returns
    -------
    depth : (height, width) array of ``dtype`` [m]
        A new array (never a view of ``msg.data``); NaN where the image has no return
        (16UC1: 0; 32FC1: NaN, +-inf, <= 0).

    Raises
    ------
    DepthImageError
        On an unsupported encoding, ``step < width * bytes per pixel``, or a ``data``
        length other than ``step * height``.
    """
    encoding = str(msg.encoding)
    if encoding not in DEPTH_ENCODINGS:
        raise DepthImageError(
            f"depth image encoding {encoding!r} is not supported; use one of: "
            f"{', '.join(DEPTH_ENCODINGS)} (16UC1 in millimetres, 32FC1 in metres)")
    element, per_metre = DEPTH_ENCODINGS[encoding]
    element = element.newbyteorder(">" if msg.is_bigendian else "<")
    height, width, step = int(msg.height), int(msg.width), int(msg.step)
    if step < width * element.itemsize:
        raise DepthImageError(
            f"depth image step {step} is shorter than a row of {width} {encoding} pixels "
            f"({width * element.itemsize} bytes)")
    buffer = _byte_view(msg.data)
    if buffer.size != step * height:
        raise DepthImageError(
            f"depth image data has {buffer.size} bytes, expected step*height = "
            f"{step}*{height} = {step * height}")
    if height * width == 0:
        return np.empty((height, width), dtype=dtype)
    raw = np.ndarray((height, width), dtype=element, buffer=buffer,
                     strides=(step, element.itemsize))
    depth = raw.astype(dtype)  # a native-order copy
    if per_metre != 1.0:
        depth /= per_metre
    depth[~(depth > 0) | ~np.isfinite(depth)] = np.nan
    return depth


def depth_to_xyz(depth: ArrayLike, model: CameraModel) -> NDArray[np.float64]:
    """Back-project a depth image through the pinhole ``model``.

    Parameters
    ----------
    depth : (height, width) float array [m]
        Depth along the optical axis (z), NaN where there is no return.
    model : CameraModel
        Intrinsics [px] of an image of the same size.

    Returns
    -------
    points : (height, width, 3) float64 array [m]
        ``(x, y, z)`` in the optical frame, NaN rows where ``depth`` is NaN.

    Raises
    ------
    DepthImageError
        If the image size differs from the model's.
    """
    z = np.asarray(depth, dtype=np.float64)
    if z.shape != (model.height, model.width):
        raise DepthImageError(
            f"depth image is {z.shape[1] if z.ndim == 2 else '?'} x "
            f"{z.shape[0] if z.ndim else '?'} but its CameraInfo is {model.width} x "
            f"{model.height}; image and CameraInfo must have the same size")
    points = np.empty(z.shape + (3,), dtype=np.float64)
    np.multiply(z, ((np.arange(model.width) - model.cx) / model.fx)[None, :],
                out=points[..., 0])
    np.multiply(z, ((np.arange(model.height) - model.cy) / model.fy)[:, None],
                out=points[..., 1])
    points[..., 2] = z
    return points


def depth_to_scene(msg: Image, info: CameraInfo) -> ScenePoints:
    """Every pixel of a depth image as a point (NaN without return) and the image grid.

    Parameters
    ----------
    msg : sensor_msgs.msg.Image
        ``16UC1`` [mm] or ``32FC1`` [m] (see :func:`depth_to_metres`).  Not modified.
    info : sensor_msgs.msg.CameraInfo
        The camera's calibration (see :func:`camera_model`); its header is not used.

    Returns
    -------
    ScenePoints
        ``points`` (height * width, 3) float64 [m] in the image's optical frame, row-major;
        ``organized_shape`` (height, width) when height > 1; the image's header (frame_id
        and stamp of the outputs).

    Raises
    ------
    DepthImageError
        On an unsupported encoding, an inconsistent image, unusable intrinsics, or an
        image whose size differs from the CameraInfo's.
    """
    model = camera_model(info)
    if (int(msg.width), int(msg.height)) != (model.width, model.height):
        raise DepthImageError(
            f"depth image is {int(msg.width)} x {int(msg.height)} but its CameraInfo is "
            f"{model.width} x {model.height}; image and CameraInfo must have the same size")
    grid = depth_to_xyz(depth_to_metres(msg, dtype=np.float64), model)
    organized = grid.shape[:2] if grid.shape[0] > 1 else None
    return ScenePoints(grid.reshape(-1, 3), organized, msg.header)


def _copy_header(header: Header) -> Header:
    return Header(stamp=Time(sec=int(header.stamp.sec), nanosec=int(header.stamp.nanosec)),
                  frame_id=str(header.frame_id))


def depth_image(depth: ArrayLike, header: Header, *, encoding: str = "16UC1") -> Image:
    """Build a depth ``Image`` as a driver publishes it.

    Parameters
    ----------
    depth : (height, width) float array [m]
        Depth along the optical axis; NaN, inf and values <= 0 mean no return.
    header : std_msgs.msg.Header
        ``frame_id`` (the optical frame) and ``stamp``, copied.
    encoding : {'16UC1', '32FC1'}
        ``16UC1``: rounded to whole millimetres (no return and depths beyond
        :data:`MAX_16UC1_DEPTH_M` -> 0); ``32FC1``: float32 metres, no return -> NaN.

    Returns
    -------
    sensor_msgs.msg.Image
        Little-endian, rows without padding (``step = width * bytes per pixel``).

    Raises
    ------
    ValueError
        If ``depth`` is not 2-D or ``encoding`` is not supported.
    """
    d = np.asarray(depth, dtype=np.float64)
    if d.ndim != 2:
        raise ValueError(f"depth must be a (height, width) array, got shape {d.shape}")
    if encoding not in DEPTH_ENCODINGS:
        raise ValueError(f"encoding must be one of {', '.join(DEPTH_ENCODINGS)}, got "
                         f"{encoding!r}")
    element, per_metre = DEPTH_ENCODINGS[encoding]
    valid = np.isfinite(d) & (d > 0)
    if encoding == "16UC1":
        valid &= d <= MAX_16UC1_DEPTH_M
        values = np.where(valid, np.rint(np.where(valid, d, 0.0) * per_metre), 0)
    else:
        values = np.where(valid, d, np.nan)
    data = array.array("B", np.ascontiguousarray(values, dtype=element.newbyteorder("<"))
                       .tobytes())
    return Image(header=_copy_header(header), height=d.shape[0], width=d.shape[1],
                 encoding=encoding, is_bigendian=0, step=d.shape[1] * element.itemsize,
                 data=data)


def camera_info(model: CameraModel, header: Header) -> CameraInfo:
    """Build the ``CameraInfo`` of an ideal (distortion-free, rectified) pinhole camera.

    Parameters
    ----------
    model : CameraModel
        Intrinsics [px] and image size.
    header : std_msgs.msg.Header
        Copied (the optical frame of the images).

    Returns
    -------
    sensor_msgs.msg.CameraInfo
        ``plumb_bob`` with zero distortion, ``K``, identity ``R``, ``P = [K | 0]``.
    """
    k = [model.fx, 0.0, model.cx, 0.0, model.fy, model.cy, 0.0, 0.0, 1.0]
    p = [model.fx, 0.0, model.cx, 0.0, 0.0, model.fy, model.cy, 0.0, 0.0, 0.0, 1.0, 0.0]
    return CameraInfo(header=_copy_header(header), width=int(model.width),
                      height=int(model.height), distortion_model="plumb_bob", d=[0.0] * 5,
                      k=[float(v) for v in k], r=[1.0, 0, 0, 0, 1.0, 0, 0, 0, 1.0],
                      p=[float(v) for v in p], binning_x=0, binning_y=0,
                      roi=RegionOfInterest())
