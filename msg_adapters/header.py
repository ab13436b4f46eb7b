"""``std_msgs/Header`` and ``builtin_interfaces/Time`` <-> frame id and integer stamps.

Stamps are handled outside the adapters as one integer of nanoseconds since the epoch
(``sec * 10**9 + nanosec``), which is exact and orders correctly; these functions are the
only place where the two message fields are read or written.  Messages are read
duck-typed (``rclpy`` messages and those deserialized by ``rosbags`` alike).
"""

from __future__ import annotations

from typing import Any, NamedTuple

from builtin_interfaces.msg import Time
from std_msgs.msg import Header

__all__ = [
    "NS_PER_S",
    "StampedFrame",
    "header_of",
    "make_header",
    "set_stamp",
    "stamp_ns",
    "stamp_text",
    "time_from_ns",
]

#: Nanoseconds per second (the resolution of ``builtin_interfaces/Time``).
NS_PER_S = 10**9


class StampedFrame(NamedTuple):
    """Where and when a message was taken: its header's ``frame_id`` and stamp [ns]."""

    frame_id: str
    stamp_ns: int


def time_from_ns(stamp_ns: int) -> Time:
    """``builtin_interfaces/Time`` of an integer stamp [ns] (``nanosec`` in [0, 1e9))."""
    sec, nanosec = divmod(int(stamp_ns), NS_PER_S)
    return Time(sec=sec, nanosec=nanosec)


def make_header(frame_id: str, stamp_ns: int = 0) -> Header:
    """Build a ``std_msgs/Header`` with ``frame_id`` and the stamp ``stamp_ns`` [ns]."""
    return Header(stamp=time_from_ns(stamp_ns), frame_id=str(frame_id))


def stamp_ns(stamped: Any) -> int:
    """Stamp [ns] of a header, or of a message that has one (``msg.header``)."""
    header = getattr(stamped, "header", stamped)
    return int(header.stamp.sec) * NS_PER_S + int(header.stamp.nanosec)


def header_of(msg: Any) -> StampedFrame:
    """``frame_id`` and stamp [ns] of a message with a header (or of a header)."""
    header = getattr(msg, "header", msg)
    return StampedFrame(str(header.frame_id), stamp_ns(header))


def set_stamp(msg: Any, stamp_ns: int) -> None:
    """Set the stamp of ``msg.header`` to ``stamp_ns`` [ns], in place (frame id kept)."""
    msg.header.stamp = time_from_ns(stamp_ns)


def stamp_text(stamp_ns: int) -> str:
    """``"<sec>.<nanosec>"`` with nine digits of nanoseconds, as ``ros2 topic echo`` shows."""
    sec, nanosec = divmod(int(stamp_ns), NS_PER_S)
    return f"{sec}.{nanosec:09d}"
