"""Core primitives <-> ``geomodel_msgs/PrimitiveArray`` (the planner-facing ``~/objects``).

The conventions are those documented in ``geomodel_msgs/msg/Primitive.msg`` (MoveIt's
``SolidPrimitive`` + pose):

* cuboid -> BOX ``[length, width, height]``: the core's rotation columns are the box axes
  and its centre the box centre, so the pose is the core's centre and rotation unchanged;
* plane -> BOX ``[length, width, 0]`` with pose z = the plane normal, plus ``plane``
  ``(a, b, c, d)``; the core's plane normal (rotation z) points towards the sensor, so
  ``d = -n . centre`` gives the sensor side ``n . x + d > 0``;
* cylinder -> CYLINDER ``[height, radius]`` and cone -> CONE ``[height, radius]`` centred on
  the midpoint of the axis segment, axis = pose z.  The core already uses these
  conventions: its cylinder/cone centre is the axis midpoint and a cone's rotation z points
  from the base to the apex (``fitting/cone.py``: ``centre = apex + axis * height / 2``,
  ``z = -axis`` with ``axis`` from the apex towards the base), so the pose is again the
  core's centre and rotation;
* frustum -> its enclosing CYLINDER ``[height, radius]`` (``SolidPrimitive`` has no
  frustum; ``radius`` is the base's, the larger circle), centred on the midpoint of the axis
  segment with pose z from the base towards the smaller top circle, as the core's; the true
  shape is in ``dimensions`` (``radius, top_radius, height``);
* sphere -> SPHERE ``[radius]``; unknown -> type 0, no dimensions (pose = points' centroid).

Orientation: the unit quaternion of the core's rotation (nearest proper rotation, ``w >= 0``,
:func:`msg_adapters.markers.rotation_to_quaternion`).

``confidence`` is the core's per-object confidence in [0, 1]
(:mod:`geomodel_ros.core.confidence`; 0 for UNKNOWN), NaN for a primitive whose confidence
was not estimated (built outside the modeling). ``dimension_completed`` says, in the order
of ``dimension_names``, which sizes were completed down to a support plane because the
object's lower part was hidden (the others were observed).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

import numpy as np
from geometry_msgs.msg import Point, Pose, Quaternion
from numpy.typing import ArrayLike, NDArray
from shape_msgs.msg import Plane, SolidPrimitive
from std_msgs.msg import Header

from geomodel_msgs.msg import Primitive as PrimitiveMsg
from geomodel_msgs.msg import PrimitiveArray, SupportSurface

from geomodel_ros.core.primitives import DIMENSION_NAMES, Primitive, PrimitiveType

from .markers import _quaternion_to_rotation, rotation_to_quaternion

__all__ = ["PrimitiveArray", "PrimitiveMsg", "primitives_to_objects", "objects_to_primitives",
           "TYPE_CODES", "CONFIDENCE_NOT_ESTIMATED"]

#: ``Primitive.msg`` type constant per core type name.
TYPE_CODES: dict[str, int] = {
    "plane": PrimitiveMsg.PLANE, "cuboid": PrimitiveMsg.CUBOID,
    "cylinder": PrimitiveMsg.CYLINDER, "cone": PrimitiveMsg.CONE,
    "sphere": PrimitiveMsg.SPHERE, "frustum": PrimitiveMsg.FRUSTUM,
    "unknown": PrimitiveMsg.UNKNOWN,
}
_TYPE_NAMES: dict[int, str] = {v: k for k, v in TYPE_CODES.items()}

#: Published ``confidence`` of a primitive without one (NaN = "not estimated").
CONFIDENCE_NOT_ESTIMATED: float = math.nan

#: ``uint32`` fields (``id``, ``point_count``) hold values modulo 2**32.
_UINT32 = 1 << 32


def _shape(type_name: str, d: Mapping[str, float]) -> SolidPrimitive:
    """SolidPrimitive of a core type with dimensions ``d`` [m] (MoveIt's order)."""
    if type_name == "cuboid":
        return SolidPrimitive(type=SolidPrimitive.BOX,
                              dimensions=[d["length"], d["width"], d["height"]])
    if type_name == "plane":
        return SolidPrimitive(type=SolidPrimitive.BOX, dimensions=[d["length"], d["width"], 0.0])
    if type_name in ("cylinder", "frustum"):  # a frustum's enclosing cylinder
        return SolidPrimitive(type=SolidPrimitive.CYLINDER, dimensions=[d["height"], d["radius"]])
    if type_name == "cone":
        return SolidPrimitive(type=SolidPrimitive.CONE, dimensions=[d["height"], d["radius"]])
    if type_name == "sphere":
        return SolidPrimitive(type=SolidPrimitive.SPHERE, dimensions=[d["radius"]])
    return SolidPrimitive()


def _pose(center: NDArray[np.float64], rotation: NDArray[np.float64]) -> Pose:
    try:
        x, y, z, w = rotation_to_quaternion(rotation)
    except ValueError:  # degenerate rotation (e.g. unknown objects): identity
        x, y, z, w = 0.0, 0.0, 0.0, 1.0
    return Pose(position=Point(x=float(center[0]), y=float(center[1]), z=float(center[2])),
                orientation=Quaternion(x=float(x), y=float(y), z=float(z), w=float(w)))


def _plane_of(normal: ArrayLike, point_or_d: ArrayLike | float, is_d: bool) -> Plane:
    n = np.asarray(normal, dtype=np.float64)
    n = n / np.linalg.norm(n)
    d = float(point_or_d) if is_d else -float(n @ np.asarray(point_or_d, dtype=np.float64))
    return Plane(coef=[float(n[0]), float(n[1]), float(n[2]), d])


def _has_sizes(p: Primitive, type_name: str) -> bool:
    names = DIMENSION_NAMES.get(PrimitiveType(type_name), ()) if type_name in TYPE_CODES else ()
    return bool(names) and all(
        k in p.dimensions and math.isfinite(p.dimensions[k]) and p.dimensions[k] >= 0
        for k in names)


def _primitive_msg(p: Primitive) -> PrimitiveMsg:
    type_name = str(getattr(p.type, "value", p.type))
    center = np.asarray(p.center, dtype=np.float64).reshape(3)
    rotation = np.asarray(p.rotation, dtype=np.float64).reshape(3, 3)
    conf = getattr(p, "confidence", None)
    msg = PrimitiveMsg(id=int(p.id) % _UINT32, point_count=int(p.point_count) % _UINT32,
                       rmse=float(p.rmse),
                       confidence=CONFIDENCE_NOT_ESTIMATED if conf is None else float(conf.value),
                       reason=str(p.reason), pose=_pose(center, rotation))
    if type_name not in TYPE_CODES or not _has_sizes(p, type_name):
        msg.type = PrimitiveMsg.UNKNOWN
        return msg
    msg.type = TYPE_CODES[type_name]
    names = DIMENSION_NAMES[PrimitiveType(type_name)]
    msg.shape = _shape(type_name, p.dimensions)
    msg.dimensions = [float(p.dimensions[k]) for k in names]
    msg.dimension_names = list(names)
    completed = set(getattr(p, "completed", ()))
    msg.dimension_completed = [k in completed for k in names]
    if type_name == "plane":
        msg.plane = _plane_of(rotation[:, 2], center, is_d=False)
    return msg


def primitives_to_objects(primitives: Sequence[Primitive], header: Header, *,
                          supports: Mapping[int, tuple[ArrayLike, float]] | None = None,
                          supported: Mapping[int, Sequence[int]] | None = None
                          ) -> PrimitiveArray:
    """Typed objects message of one frame's primitives.

    Parameters
    ----------
    primitives : sequence of Primitive
        Objects in the frame of ``header`` (centre [m], rotation columns = object axes,
        dimensions [m]); their ``id`` is published (modulo 2**32).
    header : std_msgs.msg.Header
        The input's header, copied.
    supports : dict id -> (normal (3,), d [m]), optional
        Support planes ``n . x + d = 0`` of the segmentation, keyed by the id of the PLANE
        primitive that is the surface; ids without such a primitive are left out.
    supported : dict id -> ids, optional
        Ids of the objects resting on each support (empty when not given).

    Returns
    -------
    geomodel_msgs.msg.PrimitiveArray
        One ``Primitive`` per input object, in input order.  Objects whose type is not
        known or whose dimensions are missing or not finite are published as UNKNOWN
        without shape or dimensions; an object with a non-finite centre is left out.
    """
    out = PrimitiveArray(header=Header(frame_id=header.frame_id, stamp=header.stamp))
    plane_ids = set()
    for p in primitives:
        if not np.all(np.isfinite(np.asarray(p.center, dtype=np.float64))):
            continue
        msg = _primitive_msg(p)
        out.primitives.append(msg)
        if msg.type == PrimitiveMsg.PLANE:
            plane_ids.add(int(p.id))
    for sid, (normal, d) in sorted((supports or {}).items()):
        if int(sid) in plane_ids:
            ids = [int(i) % _UINT32 for i in (supported or {}).get(sid, ())]
            out.support_surfaces.append(SupportSurface(
                id=int(sid) % _UINT32, plane=_plane_of(normal, d, is_d=True),
                supported_ids=ids))
    return out


def _dimensions_of(m: PrimitiveMsg) -> dict[str, float]:
    return {str(k): float(v) for k, v in zip(m.dimension_names, m.dimensions)}


def objects_to_primitives(msg: PrimitiveArray) -> list[Primitive]:
    """Read the core primitives back from a ``PrimitiveArray`` (the inverse, for tools).

    Centre, rotation (from the quaternion), dimensions (by ``dimension_names``), the
    completed dimensions, id, point count, rmse and reason are restored; faces and the
    confidence's terms are not carried (empty, None).  Spheres and UNKNOWN objects get the
    identity rotation of the core.
    """
    out = []
    for m in msg.primitives:
        type_name = _TYPE_NAMES.get(int(m.type), "unknown")
        p = m.pose.position
        center = np.array([p.x, p.y, p.z], dtype=np.float64)
        rotation = _quaternion_to_rotation(m.pose.orientation)
        if type_name in ("sphere", "unknown"):
            rotation = np.eye(3)
        completed = tuple(str(k) for k, done in zip(m.dimension_names, m.dimension_completed)
                          if done)
        out.append(Primitive(int(m.id), type_name, center, rotation, _dimensions_of(m),
                             int(m.point_count), float(m.rmse), reason=str(m.reason),
                             completed=completed))
    return out
