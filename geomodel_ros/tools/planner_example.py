"""A planner's view of the modeler: ``~/objects`` -> MoveIt-style collision objects.

Run it beside the node::

    python -m geomodel_ros.tools.planner_example            # listens on /modeler/objects
    python -m geomodel_ros.tools.planner_example /cam2/modeler/objects

:func:`to_collision_objects` is the documented mapping from a
``geomodel_msgs/PrimitiveArray`` onto ``moveit_msgs/CollisionObject`` fields.  moveit_msgs
is not a dependency of this package, so each collision object is a plain dict with the
message's field names; a MoveIt planner fills the message from it one to one:

============================  ==================================================
dict key                      moveit_msgs/CollisionObject field
============================  ==================================================
``id``                        ``id`` (``"geomodel_<Primitive.id>"``; the id is
                              stable across frames, so ADD with the same id
                              replaces the object in the planning scene)
``header``                    ``header`` (the input cloud's frame and stamp)
``primitives``                ``primitives``: one ``shape_msgs/SolidPrimitive``
                              (``type`` name -> ``SolidPrimitive.BOX`` ...,
                              ``dimensions`` unchanged)
``primitive_poses``           ``primitive_poses``: one ``geometry_msgs/Pose``
``operation``                 ``operation``: ``"add"`` -> ``ADD``,
                              ``"remove"`` -> ``REMOVE``
============================  ==================================================

Per ``Primitive.type``, with MoveIt's conventions already in ``Primitive.shape``:

* CUBOID -> box ``[x, y, z]``; CYLINDER and FRUSTUM (its enclosing cylinder) -> cylinder
  ``[height, radius]``; CONE -> cone ``[height, radius]`` (tip along the pose's +z);
  SPHERE -> sphere ``[radius]``; every shape centred on its pose.
* PLANE -> a box ``[length, width, PLANE_THICKNESS]`` whose face towards the sensor is the
  observed plane: the message's zero-thickness patch is thickened away from the sensor
  (the pose's z axis is the plane normal, pointing towards the sensor), so objects standing
  on a desk do not intersect it.
* UNKNOWN (no fitted shape) -> skipped: the planner should treat those points as unknown
  space (e.g. an octomap), not as a solid of guessed shape.

An object of the previous message that is missing from this one (gone, or now UNKNOWN) gets
a ``"remove"`` entry with its id.
"""

from __future__ import annotations

import sys
from typing import Any, Callable, Collection

import rclpy
from geomodel_msgs.msg import PrimitiveArray
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from rclpy.utilities import remove_ros_args

__all__ = ["PLANE_THICKNESS", "collision_id", "to_collision_objects", "PlannerExample",
           "main"]

#: Thickness given to planes (desk tops, walls, floors) as collision boxes [m]: thick enough
#: for a planner's discrete collision checks not to step through it, thin enough not to
#: swallow a desk's legs or a shelf below it.
PLANE_THICKNESS = 0.02
#: Topic of the modeler's typed objects (``~/objects`` of the node named ``modeler``).
DEFAULT_TOPIC = "/modeler/objects"


def collision_id(primitive_id: int) -> str:
    """Return the collision object id of a ``Primitive.id`` (``"geomodel_<id>"``)."""
    return f"geomodel_{primitive_id}"


def _shape_name(shape: Any) -> str | None:
    """Return MoveIt's name of a ``shape_msgs/SolidPrimitive`` type, None for no shape."""
    return {shape.BOX: "box", shape.CYLINDER: "cylinder", shape.CONE: "cone",
            shape.SPHERE: "sphere"}.get(shape.type)


def _plane_normal(orientation: Any) -> tuple[float, float, float]:
    """Return the z axis of a unit quaternion's rotation (a plane pose's normal)."""
    x, y, z, w = orientation.x, orientation.y, orientation.z, orientation.w
    return (2.0 * (x * z + w * y), 2.0 * (y * z - w * x), 1.0 - 2.0 * (x * x + y * y))


def _pose(primitive: Any, offset: float = 0.0) -> dict[str, dict[str, float]]:
    """Return the primitive's pose as a dict, moved by ``offset`` [m] along its z axis."""
    p, q = primitive.pose.position, primitive.pose.orientation
    n = _plane_normal(q)
    return {"position": {"x": p.x + offset * n[0], "y": p.y + offset * n[1],
                         "z": p.z + offset * n[2]},
            "orientation": {"x": q.x, "y": q.y, "z": q.z, "w": q.w}}


def _collision_object(primitive: Any, header: dict[str, Any]) -> dict[str, Any] | None:
    """Return the "add" collision object of one ``Primitive``; None if it has no shape."""
    name = _shape_name(primitive.shape)
    if primitive.type == primitive.UNKNOWN or name is None:
        return None
    dimensions = [float(d) for d in primitive.shape.dimensions]
    offset = 0.0
    if primitive.type == primitive.PLANE:
        # [length, width, 0] -> [length, width, PLANE_THICKNESS], moved away from the sensor
        dimensions = dimensions[:2] + [PLANE_THICKNESS]
        offset = -0.5 * PLANE_THICKNESS
    return {"id": collision_id(primitive.id), "header": header,
            "primitives": [{"type": name, "dimensions": dimensions}],
            "primitive_poses": [_pose(primitive, offset)], "operation": "add"}


def to_collision_objects(msg: Any, previous_ids: Collection[str] = ()) -> list[dict[str, Any]]:
    """Convert a ``geomodel_msgs/PrimitiveArray`` into MoveIt-style collision objects.

    Parameters
    ----------
    msg : geomodel_msgs.msg.PrimitiveArray
        The modeler's objects of one frame (poses and sizes in metres, ``msg.header``'s
        frame).
    previous_ids : collection of str
        Collision object ids added for the previous message; those not added again get a
        ``"remove"`` entry.

    Returns
    -------
    list of dict
        First one ``"add"`` entry per object with a shape (module docstring: keys and
        mapping), in the message's order, then one ``{"id", "header", "operation":
        "remove"}`` per vanished id, sorted by id.
    """
    header = {"frame_id": msg.header.frame_id,
              "stamp": {"sec": msg.header.stamp.sec, "nanosec": msg.header.stamp.nanosec}}
    added = [o for o in (_collision_object(p, header) for p in msg.primitives) if o]
    current = {o["id"] for o in added}
    removed = [{"id": i, "header": header, "operation": "remove"}
               for i in sorted(set(previous_ids) - current)]
    return added + removed


class PlannerExample(Node):
    """Subscribe to the modeler's objects and hand collision objects to a callback.

    Parameters
    ----------
    topic : str
        The ``geomodel_msgs/PrimitiveArray`` topic (default ``/modeler/objects``).
    on_objects : callable, optional
        Called with the list of :func:`to_collision_objects` of every message; by default
        the counts are logged.  A MoveIt planner would build ``moveit_msgs/CollisionObject``
        messages here and apply them as a planning scene diff.
    **kwargs
        Passed to :class:`rclpy.node.Node` (``context``, ...).
    """

    def __init__(self, topic: str = DEFAULT_TOPIC,
                 on_objects: Callable[[list[dict[str, Any]]], None] | None = None,
                 **kwargs: Any) -> None:
        super().__init__("planner_example", **kwargs)
        self._ids: set[str] = set()
        self._on_objects = on_objects or self._log
        # the modeler publishes ~/objects reliable
        qos = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
        self.create_subscription(PrimitiveArray, topic, self._on_message, qos)

    def _on_message(self, msg: PrimitiveArray) -> None:
        objects = to_collision_objects(msg, self._ids)
        self._ids = {o["id"] for o in objects if o["operation"] == "add"}
        self._on_objects(objects)

    def _log(self, objects: list[dict[str, Any]]) -> None:
        added = [f"{o['id']} {o['primitives'][0]['type']}" for o in objects
                 if o["operation"] == "add"]
        removed = [o["id"] for o in objects if o["operation"] == "remove"]
        self.get_logger().info(f"add {', '.join(added) or '-'}; remove "
                               f"{', '.join(removed) or '-'}")


def main(args: list[str] | None = None) -> int:
    """Run the example node on the topic given after the program name; return the status."""
    argv = sys.argv if args is None else args
    topics = remove_ros_args(argv)[1:]
    rclpy.init(args=argv)
    node: PlannerExample | None = None
    try:
        node = PlannerExample(topics[0] if topics else DEFAULT_TOPIC)
        rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
