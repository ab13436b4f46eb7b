"""Messages <-> serialized CDR bytes, as stored in rosbag2 files and sent over DDS.

Uses ``rclpy.serialization`` (no ``rclpy.init`` needed) for the standard messages, and
``rosbags``' own CDR serializer for ``geomodel_msgs``: rmw_fastrtps'
``serialize_message`` reports its size estimate as the length, with alignment padding after
an empty ``float64[]`` (an UNKNOWN primitive's ``dimensions``), and ``rosbags`` then rejects
the record ("CDR message size mismatch").  :func:`serialize_objects` writes the exact CDR
length, which both ``rosbags`` and ``rclpy.serialization.deserialize_message`` read.
"""

from __future__ import annotations

import functools
import re
import sysconfig
from pathlib import Path
from typing import Any

import numpy as np
from rclpy.serialization import deserialize_message, serialize_message
from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from sensor_msgs.msg import PointCloud2

__all__ = ["DeserializationError", "GEOMODEL_MESSAGES", "OBJECTS_TYPE", "deserialize_cloud",
           "geomodel_typestore", "serialize", "serialize_objects", "to_rosbags"]

#: The message types of the ``geomodel_msgs`` package (registered with rosbags).
GEOMODEL_MESSAGES = ("SupportSurface", "Primitive", "PrimitiveArray")
#: rosbag2 type name of the typed objects (``~/objects``).
OBJECTS_TYPE = "geomodel_msgs/msg/PrimitiveArray"

#: NumPy dtype of each rosidl primitive type that rosbags stores in numpy arrays.
_DTYPES = {"double": np.float64, "float": np.float32, "int8": np.int8, "uint8": np.uint8,
           "octet": np.uint8, "int16": np.int16, "uint16": np.uint16, "int32": np.int32,
           "uint32": np.uint32, "int64": np.int64, "uint64": np.uint64, "boolean": np.bool_}
#: ``sequence<T>``, ``sequence<T, N>`` (bounded) or ``T[N]`` (array) -> ``T``.
_ELEMENT = re.compile(r"^sequence<([^,>]+)(?:, *\d+)?>$|^([^\[]+)\[\d+\]$")


class DeserializationError(ValueError):
    """Bytes that are not a serialized message of the expected type.

    The message is the first line of the deserializer's own error (its exceptions have no
    public type).
    """


def serialize(msg: Any) -> bytes:
    """CDR bytes of a message (any ROS 2 message type; see :func:`serialize_objects`)."""
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


def _msg_dir() -> Path:
    """Directory of the ``geomodel_msgs`` ``.msg`` files the Python classes were built from.

    The installed copy (``<prefix>/share/geomodel_msgs/msg``), else the sources of the
    repository.
    """
    installed = Path(sysconfig.get_paths()["data"]) / "share" / "geomodel_msgs" / "msg"
    if (installed / "PrimitiveArray.msg").is_file():
        return installed
    return Path(__file__).resolve().parent.parent / "geomodel_msgs" / "msg"


@functools.lru_cache(maxsize=1)
def geomodel_typestore():
    """Return rosbags' Jazzy typestore with the ``geomodel_msgs`` types registered.

    The types are read from the ``.msg`` definitions (``get_types_from_msg``), so bags
    written with it carry the definitions and are readable without this package.
    """
    store = get_typestore(Stores.ROS2_JAZZY)
    types: dict = {}
    for name in GEOMODEL_MESSAGES:
        text = (_msg_dir() / f"{name}.msg").read_text()
        types.update(get_types_from_msg(text, f"geomodel_msgs/msg/{name}"))
    store.register(types)
    return store


def _type_name(msg: Any) -> str:
    """``pkg/msg/Name`` of an rclpy message instance."""
    return f"{type(msg).__module__.split('.')[0]}/msg/{type(msg).__name__}"


def _field_to_rosbags(value: Any, rosidl_type: str, store) -> Any:
    """One rclpy field value as rosbags stores it (numpy arrays for numeric sequences)."""
    if hasattr(value, "get_fields_and_field_types"):
        return to_rosbags(value, store)
    match = _ELEMENT.match(rosidl_type)
    if match is None:
        return value
    element = match.group(1) or match.group(2)
    if element in _DTYPES:
        return np.asarray(value, dtype=_DTYPES[element])
    return [_field_to_rosbags(v, element, store) for v in value]


def to_rosbags(msg: Any, store=None) -> Any:
    """Return the rosbags message object with the fields of an rclpy message.

    Parameters
    ----------
    msg : rclpy message
        Any message whose type (and nested types) ``store`` knows.
    store : rosbags Typestore, optional
        Default: :func:`geomodel_typestore`.
    """
    store = store if store is not None else geomodel_typestore()
    cls = store.types[_type_name(msg)]
    fields = msg.get_fields_and_field_types()
    return cls(**{name: _field_to_rosbags(getattr(msg, name), kind, store)
                  for name, kind in fields.items()})


def serialize_objects(msg: Any) -> bytes:
    """CDR bytes of a ``geomodel_msgs/PrimitiveArray``, serialized by rosbags.

    Parameters
    ----------
    msg : geomodel_msgs.msg.PrimitiveArray
        The rclpy message (e.g. :attr:`geomodel_ros.ros.processing.FrameResult.objects`).

    Returns
    -------
    bytes
        Little-endian CDR of exactly the message's length: readable by rosbags'
        ``deserialize_cdr`` and by ``rclpy.serialization.deserialize_message``.
    """
    store = geomodel_typestore()
    return bytes(store.serialize_cdr(to_rosbags(msg, store), OBJECTS_TYPE))
