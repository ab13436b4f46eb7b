"""Modeled primitives -> ``visualization_msgs/MarkerArray`` and labelled ``PointCloud2``.

Pure functions (no ``rclpy.init``): the node calls them once per frame and publishes the
result.  Every output copies the input's ``header`` (``frame_id`` and ``stamp``), so RViz and
TF place it exactly where the sensor saw it, also when a bag is replayed.

Marker layout of one frame (``primitives_to_markers``):

* a ``DELETEALL`` marker first, so objects of the previous frame disappear;
* one shape marker per object in the namespace of its type (``"plane"``, ``"cuboid"``,
  ``"cylinder"``, ``"cone"``, ``"sphere"``, ``"frustum"``, ``"unknown"``) with the object id
  as marker id: ``CUBE`` for cuboids and (2 mm thin) planes, ``CYLINDER``, ``SPHERE``, a
  ``TRIANGLE_LIST`` mesh for cones and frustums (side and caps, vertices in metres in the
  object's frame) and a small ``SPHERE`` at the centroid of ``unknown`` objects;
* one ``TEXT_VIEW_FACING`` label per object in namespace ``"labels"`` (same id), e.g.
  ``"cylinder r=50.0 h=60.0* mm, confidence 0.93"`` (type, sizes, ``*`` after a size
  completed down to the support, the confidence when estimated), placed just above the
  object.

Units: metres and radians in, metres in the markers, millimetres only in label text.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Final

import numpy as np
from builtin_interfaces.msg import Duration, Time
from geometry_msgs.msg import Point, Pose, Quaternion, Vector3
from numpy.typing import ArrayLike, NDArray
from sensor_msgs.msg import PointCloud2
from std_msgs.msg import ColorRGBA, Header
from visualization_msgs.msg import Marker, MarkerArray

from geomodel_ros.core.colors import as_ids, id_colors
from geomodel_ros.core.primitives import DIMENSION_NAMES, Primitive

from .header import StampedFrame, header_of
from .pointcloud2 import pack_rgb, xyz_to_cloud

__all__ = [
    "tracked_markers",
    "LABEL_GAP",
    "LABEL_NAMESPACE",
    "PLANE_THICKNESS",
    "TYPE_COLOURS",
    "marker_array_frame",
    "marker_array_problem",
    "markers_to_primitives",
    "object_colours",
    "primitives_to_markers",
    "reconstruction_cloud",
    "rotation_to_quaternion",
    "segments_cloud",
]

#: Thickness [m] of the CUBE that shows a plane.
PLANE_THICKNESS: Final = 0.002
#: Namespace of the text labels.
LABEL_NAMESPACE: Final = "labels"
#: Diameter [m] of the sphere that marks the centroid of an ``unknown`` object.
UNKNOWN_MARKER_SIZE: Final = 0.01
#: Triangle-fan segments of a cone or frustum mesh.
CONE_SEGMENTS: Final = 32
#: Gap [m] between an object's top and the bottom of its label (clear of the shape).
LABEL_GAP: Final = 0.005
#: Smallest scale [m] written to a marker (RViz ignores markers with a zero scale).
_MIN_SCALE: Final = 1e-4

#: RGBA in [0, 1] per primitive type.
TYPE_COLOURS: Final[Mapping[str, tuple[float, float, float, float]]] = {
    "plane": (0.55, 0.57, 0.62, 0.45),
    "cuboid": (0.95, 0.55, 0.10, 0.85),
    "cylinder": (0.20, 0.50, 0.95, 0.85),
    "cone": (0.20, 0.80, 0.30, 0.85),
    "sphere": (0.85, 0.20, 0.60, 0.85),
    "frustum": (0.10, 0.75, 0.75, 0.85),
    "unknown": (0.75, 0.75, 0.75, 0.85),
}
_TEXT_COLOUR: Final = (1.0, 1.0, 1.0, 1.0)
#: Colour of points without an object (label < 0) in the labelled clouds.
_NOISE_RGB: Final = (128, 128, 128)


# ---------------------------------------------------------------------------------------
# Rotations
# ---------------------------------------------------------------------------------------

def rotation_to_quaternion(rotation: ArrayLike) -> NDArray[np.float64]:
    """Return the unit quaternion ``(x, y, z, w)`` of a rotation matrix.

    Parameters
    ----------
    rotation : (3, 3) real array
        Columns are the rotated frame's x, y, z axes.  It need not be exactly orthonormal:
        the nearest rotation (polar decomposition via SVD) is used.  A reflection
        (determinant < 0) is made proper by negating its x column, which leaves the shapes
        drawn here unchanged (their z axis, e.g. a cone's direction, is kept).

    Returns
    -------
    q : (4,) float64 array
        ``(x, y, z, w)`` with ``w >= 0`` and unit norm, as in ``geometry_msgs/Quaternion``.

    Raises
    ------
    ValueError
        If ``rotation`` is not a finite (3, 3) array of full rank.
    """
    r = np.asarray(rotation, dtype=np.float64)
    if r.shape != (3, 3) or not np.all(np.isfinite(r)):
        raise ValueError(f"rotation must be a finite (3, 3) array, got shape {r.shape}")
    u, s, vt = np.linalg.svd(r)
    if s[-1] <= 1e-9 * max(s[0], 1e-300):
        raise ValueError(f"rotation must have full rank, got singular values {s.tolist()}")
    r = u @ vt
    if np.linalg.det(r) < 0.0:
        r = r.copy()
        r[:, 0] = -r[:, 0]
    # Shepperd's method: divide by the largest of the four candidate terms.
    trace = r[0, 0] + r[1, 1] + r[2, 2]
    candidates = (trace, r[0, 0], r[1, 1], r[2, 2])
    k = int(np.argmax(candidates))
    if k == 0:
        s4 = 2.0 * math.sqrt(max(1.0 + trace, 0.0))
        q = np.array([(r[2, 1] - r[1, 2]) / s4, (r[0, 2] - r[2, 0]) / s4,
                      (r[1, 0] - r[0, 1]) / s4, 0.25 * s4])
    elif k == 1:
        s4 = 2.0 * math.sqrt(max(1.0 + r[0, 0] - r[1, 1] - r[2, 2], 0.0))
        q = np.array([0.25 * s4, (r[0, 1] + r[1, 0]) / s4,
                      (r[0, 2] + r[2, 0]) / s4, (r[2, 1] - r[1, 2]) / s4])
    elif k == 2:
        s4 = 2.0 * math.sqrt(max(1.0 - r[0, 0] + r[1, 1] - r[2, 2], 0.0))
        q = np.array([(r[0, 1] + r[1, 0]) / s4, 0.25 * s4,
                      (r[1, 2] + r[2, 1]) / s4, (r[0, 2] - r[2, 0]) / s4])
    else:
        s4 = 2.0 * math.sqrt(max(1.0 - r[0, 0] - r[1, 1] + r[2, 2], 0.0))
        q = np.array([(r[0, 2] + r[2, 0]) / s4, (r[1, 2] + r[2, 1]) / s4,
                      0.25 * s4, (r[1, 0] - r[0, 1]) / s4])
    if q[3] < 0.0:
        q = -q
    return q / np.linalg.norm(q)


# ---------------------------------------------------------------------------------------
# Markers
# ---------------------------------------------------------------------------------------

def _header(header: Header) -> Header:
    return Header(stamp=Time(sec=int(header.stamp.sec), nanosec=int(header.stamp.nanosec)),
                  frame_id=str(header.frame_id))


def _duration(seconds: float) -> Duration:
    whole = math.floor(seconds)
    nanosec = min(int(round((seconds - whole) * 1e9)), 999_999_999)
    return Duration(sec=int(whole), nanosec=nanosec)


def _colour(rgba: Sequence[float]) -> ColorRGBA:
    return ColorRGBA(r=float(rgba[0]), g=float(rgba[1]), b=float(rgba[2]), a=float(rgba[3]))


def _marker_id(object_id: int) -> int:
    """Wrap the object id into int32 (Marker.id); identity for ids in int32 range."""
    return (int(object_id) + 2**31) % 2**32 - 2**31


def _pose(center: NDArray[np.float64], rotation: NDArray[np.float64] | None) -> Pose:
    q = (0.0, 0.0, 0.0, 1.0) if rotation is None else rotation_to_quaternion(rotation)
    return Pose(
        position=Point(x=float(center[0]), y=float(center[1]), z=float(center[2])),
        orientation=Quaternion(x=float(q[0]), y=float(q[1]), z=float(q[2]), w=float(q[3])),
    )


def _scale(x: float, y: float, z: float) -> Vector3:
    return Vector3(x=max(float(x), _MIN_SCALE), y=max(float(y), _MIN_SCALE),
                   z=max(float(z), _MIN_SCALE))


def _valid_dimensions(p: Primitive) -> bool:
    names = DIMENSION_NAMES.get(p.type)
    if names is None:
        return False
    try:
        values = [float(p.dimensions[n]) for n in names]
    except (KeyError, TypeError, ValueError):
        return False
    return all(math.isfinite(v) and v > 0.0 for v in values)


def _confidence_text(p: Primitive) -> str:
    """``", confidence 0.93"`` when the primitive has an estimated confidence, else ``""``."""
    conf = getattr(p, "confidence", None)
    value = None if conf is None else float(conf.value)
    return "" if value is None or not math.isfinite(value) else f", confidence {value:.2f}"


def _label_text(p: Primitive, valid: bool) -> str:
    """Type, sizes in mm (``*``: completed down to the support) and confidence."""
    if p.type == "unknown":
        return "unknown" + _confidence_text(p)
    if not valid:
        return f"{p.type} (invalid size)" + _confidence_text(p)
    completed = set(getattr(p, "completed", ()))
    sizes = " ".join(f"{name[0]}={1000.0 * float(p.dimensions[name]):.1f}"
                     + ("*" if name in completed else "")
                     for name in DIMENSION_NAMES[p.type])
    return f"{p.type} {sizes} mm" + _confidence_text(p)


def _half_extent_along(p: Primitive, rotation: NDArray[np.float64], up: NDArray[np.float64],
                       valid: bool) -> float:
    """Half the object's extent [m] along the unit vector ``up``."""
    if not valid or p.type == "unknown":
        return 0.5 * UNKNOWN_MARKER_SIZE
    d = p.dimensions
    local = rotation.T @ up  # ``up`` in the object's axes
    if p.type == "plane":
        return 0.5 * (abs(local[0]) * d["length"] + abs(local[1]) * d["width"]
                      + abs(local[2]) * PLANE_THICKNESS)
    if p.type == "cuboid":
        return 0.5 * (abs(local[0]) * d["length"] + abs(local[1]) * d["width"]
                      + abs(local[2]) * d["height"])
    if p.type in ("cylinder", "cone", "frustum"):
        along = abs(float(local[2]))
        across = math.sqrt(max(0.0, 1.0 - along * along))
        return 0.5 * along * d["height"] + across * d["radius"]
    return float(d["radius"])  # sphere


def _round_mesh(radius: float, top_radius: float, height: float, segments: int) -> list[Point]:
    """Triangles (counter-clockwise seen from outside) of a cone or frustum in its local frame.

    Base circle of ``radius`` at z = -height/2, top circle of ``top_radius`` (0: a cone's
    apex) at z = +height/2 (the object's z points base -> top); the top disc is drawn
    only for a frustum.
    """
    t = np.linspace(0.0, 2.0 * math.pi, segments, endpoint=False)
    circle = np.stack([np.cos(t), np.sin(t), np.zeros(segments)], axis=1)
    ring = circle * [radius, radius, 0.0] + [0.0, 0.0, -0.5 * height]
    nxt = np.roll(ring, -1, axis=0)
    base = np.broadcast_to([0.0, 0.0, -0.5 * height], ring.shape)
    disc = np.stack([base, nxt, ring], axis=1)  # normal -z
    if top_radius <= 0.0:
        apex = np.broadcast_to([0.0, 0.0, 0.5 * height], ring.shape)
        lateral = np.stack([ring, nxt, apex], axis=1)  # outward normals
        tri = np.concatenate([lateral, disc]).reshape(-1, 3)
    else:
        top = circle * [top_radius, top_radius, 0.0] + [0.0, 0.0, 0.5 * height]
        top_nxt = np.roll(top, -1, axis=0)
        centre = np.broadcast_to([0.0, 0.0, 0.5 * height], ring.shape)
        lateral = np.concatenate([np.stack([ring, nxt, top_nxt], axis=1),
                                  np.stack([ring, top_nxt, top], axis=1)])
        lid = np.stack([centre, top, top_nxt], axis=1)  # normal +z
        tri = np.concatenate([lateral, disc, lid]).reshape(-1, 3)
    return [Point(x=float(x), y=float(y), z=float(z)) for x, y, z in tri.tolist()]


def _default_up(frame_id: str) -> NDArray[np.float64]:
    # REP 103: optical frames (suffix "_optical" / "_optical_frame") have y down, other
    # frames z up.
    name = frame_id.rstrip("/").lower()
    if name.endswith("optical") or name.endswith("optical_frame"):
        return np.array([0.0, -1.0, 0.0])
    return np.array([0.0, 0.0, 1.0])


def _up_direction(up: ArrayLike | None, header: Header) -> NDArray[np.float64]:
    """Return the unit direction in which labels are lifted (default from the frame)."""
    if up is None:
        return _default_up(str(header.frame_id))
    up_dir = np.asarray(up, dtype=np.float64).reshape(-1)
    norm = float(np.linalg.norm(up_dir)) if up_dir.shape == (3,) else 0.0
    if not math.isfinite(norm) or norm == 0.0:
        raise ValueError(f"up must be a finite non-zero (3,) vector, got {up!r}")
    return up_dir / norm


def _draw_shape(shape: Marker, p: Primitive, center: NDArray[np.float64],
                rotation: NDArray[np.float64], valid: bool) -> None:
    """Set type, namespace, pose, scale (and cone mesh) of ``shape`` for ``p``."""
    d = p.dimensions
    if not valid:
        shape.ns = p.type if p.type in TYPE_COLOURS else "unknown"
        shape.type = Marker.SPHERE
        shape.pose = _pose(center, None)
        shape.scale = _scale(UNKNOWN_MARKER_SIZE, UNKNOWN_MARKER_SIZE, UNKNOWN_MARKER_SIZE)
        return
    shape.ns = p.type
    if p.type == "plane":
        shape.type = Marker.CUBE
        shape.pose = _pose(center, rotation)
        shape.scale = _scale(d["length"], d["width"], PLANE_THICKNESS)
    elif p.type == "cuboid":
        shape.type = Marker.CUBE
        shape.pose = _pose(center, rotation)
        shape.scale = _scale(d["length"], d["width"], d["height"])
    elif p.type == "cylinder":
        shape.type = Marker.CYLINDER
        shape.pose = _pose(center, rotation)
        shape.scale = _scale(2.0 * d["radius"], 2.0 * d["radius"], d["height"])
    elif p.type == "sphere":
        shape.type = Marker.SPHERE
        shape.pose = _pose(center, None)
        shape.scale = _scale(2.0 * d["radius"], 2.0 * d["radius"], 2.0 * d["radius"])
    else:  # cone or frustum
        shape.type = Marker.TRIANGLE_LIST
        shape.pose = _pose(center, rotation)
        shape.scale = Vector3(x=1.0, y=1.0, z=1.0)
        top = float(d["top_radius"]) if p.type == "frustum" else 0.0
        shape.points = _round_mesh(float(d["radius"]), top, float(d["height"]), CONE_SEGMENTS)


def _object_markers(p: Primitive, header: Header, lifetime: Duration, text: bool,
                    text_size: float, up_dir: NDArray[np.float64]) -> list[Marker]:
    """Shape marker and (with ``text``) label of one object; none if its centre is bad."""
    center = np.asarray(p.center, dtype=np.float64).reshape(-1)
    if center.shape != (3,) or not np.all(np.isfinite(center)):
        return []
    rotation = np.asarray(p.rotation, dtype=np.float64)
    try:
        rotation_to_quaternion(rotation)
    except ValueError:
        rotation = np.eye(3)
    valid = p.type != "unknown" and _valid_dimensions(p)
    mid = _marker_id(p.id)
    shape = Marker(header=_header(header), id=mid, action=Marker.ADD, lifetime=lifetime)
    _draw_shape(shape, p, center, rotation, valid)
    shape.color = _colour(TYPE_COLOURS.get(shape.ns, TYPE_COLOURS["unknown"]))
    if not text:
        return [shape]
    lift = _half_extent_along(p, rotation, up_dir, valid) + 0.5 * text_size + LABEL_GAP
    label = Marker(header=_header(header), ns=LABEL_NAMESPACE, id=mid,
                   type=Marker.TEXT_VIEW_FACING, action=Marker.ADD, lifetime=lifetime)
    label.pose = _pose(center + lift * up_dir, None)
    label.scale = Vector3(x=text_size, y=text_size, z=text_size)
    label.color = _colour(_TEXT_COLOUR)
    label.text = _label_text(p, valid)
    return [shape, label]


def primitives_to_markers(
    primitives: Sequence[Primitive],
    header: Header,
    *,
    lifetime_s: float = 0.0,
    text: bool = True,
    text_size: float = 0.015,
    up: ArrayLike | None = None,
) -> MarkerArray:
    """RViz markers of modeled objects.

    Parameters
    ----------
    primitives : sequence of Primitive
        Objects in the frame of ``header`` (centre [m], rotation columns = object axes,
        dimensions [m]).
    header : std_msgs.msg.Header
        Copied (``frame_id`` and ``stamp``) into every marker.
    lifetime_s : float
        Marker lifetime [s]; 0 = until replaced (the leading DELETEALL of the next frame
        clears them).
    text : bool
        Add a ``TEXT_VIEW_FACING`` label per object (namespace ``"labels"``).
    text_size : float
        Height of the label text [m].
    up : (3,) array, optional
        Direction in which labels are lifted above their object, in the header's frame.
        Default: ``-y`` for optical frames (``frame_id`` ending in ``optical`` or
        ``optical_frame``, REP 103), ``+z`` otherwise.

    Returns
    -------
    visualization_msgs.msg.MarkerArray
        ``DELETEALL`` first, then per object its shape marker (namespace = type, id =
        object id wrapped into int32) and its label.  Every marker has a finite pose, a
        unit quaternion and a positive scale.  Objects whose centre is not finite are left
        out; objects of a known type with missing or non-positive dimensions are drawn
        like ``unknown`` ones (small sphere, label ``"<type> (invalid size)"``).

    Raises
    ------
    ValueError
        If ``lifetime_s`` or ``text_size`` is negative or not finite, or ``up`` is not a
        non-zero (3,) vector.
    """
    if not math.isfinite(lifetime_s) or lifetime_s < 0.0:
        raise ValueError(f"lifetime_s must be a finite number >= 0 [s], got {lifetime_s!r}")
    if not math.isfinite(text_size) or text_size <= 0.0:
        raise ValueError(f"text_size must be a finite number > 0 [m], got {text_size!r}")
    up_dir = _up_direction(up, header)
    lifetime = _duration(lifetime_s)
    out = MarkerArray()
    out.markers.append(Marker(header=_header(header), action=Marker.DELETEALL))
    for p in primitives:
        out.markers.extend(_object_markers(p, header, lifetime, text, text_size, up_dir))
    return out


def tracked_markers(
    primitives: Sequence[Primitive],
    header: Header,
    *,
    deleted_ids: Sequence[int] = (),
    previous: Mapping[int, str] | None = None,
    clear: bool = False,
    text: bool = True,
    text_size: float = 0.015,
    up: ArrayLike | None = None,
) -> tuple[MarkerArray, dict[int, str]]:
    """RViz markers of tracked objects: per-id ADD and DELETE instead of DELETEALL.

    For objects whose ids stay stable across frames
    (:class:`geomodel_ros.core.tracking.Tracker`): an ADD with the id of a marker already
    shown replaces it in RViz, so nothing flickers.

    Parameters
    ----------
    primitives : sequence of Primitive
        The frame's objects with their stable ids (drawn as by :func:`primitives_to_markers`).
    header : std_msgs.msg.Header
        Copied into every marker.
    deleted_ids : sequence of int
        Ids retired in this frame: their shape (in the namespace it was last drawn in,
        from ``previous``) and label are deleted.
    previous : dict id -> namespace, optional
        The namespace each id's shape was last drawn in (the second return value of the
        previous call).  A shape that changes namespace (its type changed) gets a DELETE
        in the old one.
    clear : bool
        Start with DELETEALL (first frame, reset).
    text, text_size, up
        As for :func:`primitives_to_markers`.

    Returns
    -------
    markers : visualization_msgs.msg.MarkerArray
        ``[DELETEALL]``, then DELETEs (retired ids, changed namespaces), then the ADDs.
    shown : dict id -> namespace
        The namespace of every id's shape after this frame (``previous`` minus the deleted
        ids, updated with the drawn ones); pass it as ``previous`` next time.

    Raises
    ------
    ValueError
        As :func:`primitives_to_markers`.
    """
    adds = primitives_to_markers(primitives, header, text=text, text_size=text_size, up=up)
    shown = {} if clear else dict(previous or {})
    out = MarkerArray()
    if clear:
        out.markers.append(adds.markers[0])
    for oid in deleted_ids:
        mid = _marker_id(oid)
        ns = shown.pop(mid, None)
        for space in ((ns,) if ns is not None else ()) + ((LABEL_NAMESPACE,) if text else ()):
            out.markers.append(Marker(header=_header(header), ns=space, id=mid,
                                      action=Marker.DELETE))
    drawn = [m for m in adds.markers[1:] if m.ns != LABEL_NAMESPACE]
    for m in drawn:
        old = shown.get(m.id)
        if old is not None and old != m.ns:
            out.markers.append(Marker(header=_header(header), ns=old, id=m.id,
                                      action=Marker.DELETE))
        shown[m.id] = m.ns
    out.markers.extend(adds.markers[1:])
    return out, shown


# ---------------------------------------------------------------------------------------
# Labelled clouds
# ---------------------------------------------------------------------------------------

def _id_colours(ids: NDArray[np.int64]) -> NDArray[np.uint8]:
    """(n, 3) colours of distinct ids: the map shared with the PLY and the pictures."""
    return id_colors(ids)


def _lookup(ids: NDArray[np.int64], per_id) -> NDArray:
    """``per_id(distinct ids)[k]`` for every element of ``ids``, vectorized.

    Dense id ranges (the usual case: 0..K and -1) are looked up by offset, in O(N); sparse
    ones go through ``np.unique``.
    """
    if ids.size == 0:
        return per_id(np.zeros(0, dtype=np.int64))
    lo, hi = int(ids.min()), int(ids.max())
    if hi - lo <= max(4 * ids.size, 1 << 16):
        return per_id(np.arange(lo, hi + 1, dtype=np.int64))[ids - lo]
    unique, inverse = np.unique(ids, return_inverse=True)
    return per_id(unique)[inverse.reshape(-1)]


def object_colours(ids: ArrayLike) -> NDArray[np.uint8]:
    """Deterministic colour per object id (same id -> same colour in every frame).

    Parameters
    ----------
    ids : (N,) integer array
        Object ids; negative = no object (grey).

    Returns
    -------
    rgb : (N, 3) uint8 array
        The shared map :func:`geomodel_ros.core.colors.id_colors`, so an object has the same
        colour in RViz, in the PLY and in the pictures.

    Raises
    ------
    ValueError
        If ``ids`` is not a 1-D integer array.
    """
    return _lookup(as_ids(ids), _id_colours)


def _labelled_cloud(points: ArrayLike, ids: ArrayLike, header: Header, what: str,
                    organized_shape: tuple[int, int] | None = None) -> PointCloud2:
    pts = np.asarray(points)
    lab = np.asarray(ids)
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise ValueError(f"points must be an (N, 3) array [m], got shape {pts.shape}")
    if lab.shape != (len(pts),) or (lab.size and lab.dtype.kind not in "ui"):
        raise ValueError(f"{what} must be an ({len(pts)},) integer array aligned with the "
                         f"points, got {lab.dtype} {lab.shape}")
    lab = lab.astype(np.int64, copy=False)
    rgb = _lookup(lab, lambda distinct: pack_rgb(_id_colours(distinct)))
    return xyz_to_cloud(pts, header, organized_shape=organized_shape,
                        fields={"object_id": lab, "rgb": rgb})


def segments_cloud(points: ArrayLike, labels: ArrayLike, header: Header, *,
                   organized_shape: tuple[int, int] | None = None) -> PointCloud2:
    """Colour the input points by the object they were assigned to.

    Parameters
    ----------
    points : (N, 3) real array [m]
        NaN rows (pixels without a return) are kept.
    labels : (N,) integer array
        Object id per point, -1 = no object; must fit in int32.
    header : std_msgs.msg.Header
        Copied into the cloud.
    organized_shape : (H, W), optional
        Keep the input's image layout (``H * W == N``), so that labels stay pixel-aligned.

    Returns
    -------
    sensor_msgs.msg.PointCloud2
        ``height = 1`` (or ``H x W``), fields ``x y z`` (FLOAT32), ``object_id`` (INT32) and
        ``rgb`` (FLOAT32 holding packed ``0x00RRGGBB``; colour from :func:`object_colours`).

    Raises
    ------
    ValueError
        If the shapes disagree, the labels are not integers or do not fit in int32.
    """
    return _labelled_cloud(points, labels, header, "labels", organized_shape)


def reconstruction_cloud(points: ArrayLike, ids: ArrayLike, header: Header) -> PointCloud2:
    """Surface samples of the modeled objects (``reconstruction.reconstruct``) as a cloud.

    Parameters
    ----------
    points : (n, 3) real array [m]
    ids : (n,) integer array
        Object id of every sample (colours match :func:`segments_cloud`).
    header : std_msgs.msg.Header
        Copied into the cloud.

    Returns
    -------
    sensor_msgs.msg.PointCloud2
        Same layout as :func:`segments_cloud`.

    Raises
    ------
    ValueError
        If the shapes disagree or the ids are not integers that fit in int32.
    """
    return _labelled_cloud(points, ids, header, "ids")


def _quaternion_to_rotation(q) -> NDArray[np.float64]:
    x, y, z, w = float(q.x), float(q.y), float(q.z), float(q.w)
    n = math.sqrt(x * x + y * y + z * z + w * w) or 1.0
    x, y, z, w = x / n, y / n, z / n, w / n
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ])


def _round_mesh_dimensions(kind: str, pts: NDArray[np.float64]) -> dict[str, float]:
    """Sizes [m] of a cone or frustum from its mesh vertices (n, 3) in its local frame."""
    rho = np.hypot(pts[:, 0], pts[:, 1])
    dims = {"radius": float(rho.max()), "height": float(np.ptp(pts[:, 2]))}
    if kind == "frustum":
        dims["top_radius"] = float(rho[pts[:, 2] >= pts[:, 2].max()].max())
    return dims


def markers_to_primitives(markers: MarkerArray) -> list[Primitive]:
    """Read back the primitives a :func:`primitives_to_markers` array describes (its inverse).

    For subscribers of ``~/primitives`` (planners, recorders) that want typed objects back:
    type from the namespace, pose from the marker pose, sizes from the scale (cones and
    frustums from their mesh). Labels, DELETEALL and ``unknown`` placeholders give no
    primitive; point counts, rmse and faces are not carried by markers (0 / empty).
    """
    out: list[Primitive] = []
    for m in markers.markers:
        if m.action != Marker.ADD or m.ns not in TYPE_COLOURS or m.ns == "unknown":
            continue
        c = np.array([m.pose.position.x, m.pose.position.y, m.pose.position.z])
        r = _quaternion_to_rotation(m.pose.orientation)
        s = m.scale
        if m.ns == "plane" and m.type == Marker.CUBE:
            dims = {"length": s.x, "width": s.y}
        elif m.ns == "cuboid" and m.type == Marker.CUBE:
            dims = {"length": s.x, "width": s.y, "height": s.z}
        elif m.ns == "cylinder" and m.type == Marker.CYLINDER:
            dims = {"radius": 0.5 * s.x, "height": s.z}
        elif m.ns == "sphere" and m.type == Marker.SPHERE:
            dims, r = {"radius": 0.5 * s.x}, np.eye(3)
        elif m.ns in ("cone", "frustum") and m.type == Marker.TRIANGLE_LIST and m.points:
            dims = _round_mesh_dimensions(m.ns, np.array([[p.x, p.y, p.z] for p in m.points]))
        else:
            continue
        out.append(Primitive(int(m.id), m.ns, c, r, {k: float(v) for k, v in dims.items()},
                             0, 0.0))
    return out


def marker_array_frame(markers: MarkerArray) -> StampedFrame | None:
    """``frame_id`` and stamp [ns] of a frame's markers (all share the input's header).

    Returns None for an empty array.
    """
    if not markers.markers:
        return None
    return header_of(markers.markers[0])


def _marker_problem(m: Marker) -> str | None:
    p, q = m.pose.position, m.pose.orientation
    if not all(math.isfinite(v) for v in (p.x, p.y, p.z, q.x, q.y, q.z, q.w)):
        return f"marker {m.ns}/{m.id} has a non-finite pose"
    if not all(math.isfinite(v) and v > 0 for v in (m.scale.x, m.scale.y, m.scale.z)):
        return f"marker {m.ns}/{m.id} has a non-positive or non-finite scale"
    if any(not all(math.isfinite(v) for v in (pt.x, pt.y, pt.z)) for pt in m.points):
        return f"marker {m.ns}/{m.id} has non-finite points"
    return None


def marker_array_problem(markers: MarkerArray, frame: StampedFrame) -> str | None:
    """Why a frame's MarkerArray is not what :func:`primitives_to_markers` promises, or None.

    Also accepts the per-id form of :func:`tracked_markers`.  Checked: not empty; a
    DELETEALL only as the first marker; every marker carries ``frame`` (the input's
    ``frame_id`` and stamp [ns]); every ADD has a finite pose, a positive finite scale and
    finite points.
    """
    if not markers.markers:
        return "is empty"
    if any(m.action == Marker.DELETEALL for m in markers.markers[1:]):
        return "has a DELETEALL after the first marker"
    for m in markers.markers:
        if header_of(m) != frame:
            return f"marker {m.ns}/{m.id} has another header than its input"
        if m.action == Marker.ADD and (why := _marker_problem(m)) is not None:
            return why
    return None
