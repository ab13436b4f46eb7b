"""Messages <-> serialized CDR bytes, as stored in rosbag2 files and sent over DDS.

Uses ``rclpy.serialization``, which needs no ``rclpy.init``.
"""

from __future__ import annotations

from typing import Any

from rclpy.serialization import deserialize_message, serialize_message
from sensor_msgs.msg import PointCloud2

__all__ = ["DeserializationError", "deserialize_cloud", "serialize"]


class DeserializationError(ValueError):
    """Bytes that are not a serialized message of the expected type.

    The message is the first line of the deserializer's own error (its exceptions have no
    public type).
    """


def serialize(msg: Any) -> bytes:
    """CDR bytes of a message (any ROS 2 message type)."""
    return serialize_message(msg)


def deserialize_cloud(raw: bytes) -> PointCloud2:
    """Read the ``sensor_msgs/PointCloud2`` serialized in ``raw``.

    Raises
    ------
    DeserializationError
        If ``raw`` is not a serialized PointCloud2 (truncated, another type, ...).
    """
    try:
        return deserialize_message(raw, PointCloud2)
    except Exception as exc:  # noqa: BLE001 - rclpy's CDR errors have no public type
        text = str(exc).strip().splitlines()
        raise DeserializationError(text[0] if text else type(exc).__name__) from exc
