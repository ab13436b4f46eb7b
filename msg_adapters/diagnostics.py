"""Status reports <-> ``diagnostic_msgs/DiagnosticArray``.

A report is a name, a hardware id, a level (``"ok"``, ``"warn"`` or ``"error"``), a
one-line message and string key/values, as ``/diagnostics`` carries them.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Final

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue

from .header import time_from_ns

__all__ = ["LEVELS", "diagnostics_message", "read_status_values"]

#: Level names -> ``DiagnosticStatus`` level bytes.
LEVELS: Final[Mapping[str, bytes]] = {"ok": DiagnosticStatus.OK,
                                      "warn": DiagnosticStatus.WARN,
                                      "error": DiagnosticStatus.ERROR}


def diagnostics_message(name: str, hardware_id: str, level: str, message: str,
                        values: Mapping[str, str], stamp_ns: int) -> DiagnosticArray:
    """Build a ``DiagnosticArray`` with one status.

    Parameters
    ----------
    name, hardware_id : str
        The status' name and hardware id.
    level : {"ok", "warn", "error"}
    message : str
        One line saying what the level means.
    values : mapping of str to str
        Key/values, in order.
    stamp_ns : int
        Stamp of the report [ns] (the time it was made).

    Raises
    ------
    ValueError
        If ``level`` is not one of :data:`LEVELS`.
    """
    if level not in LEVELS:
        raise ValueError(f"level {level!r} is not allowed; use one of: {', '.join(LEVELS)}")
    status = DiagnosticStatus(level=LEVELS[level], name=name, message=message,
                              hardware_id=hardware_id)
    status.values = [KeyValue(key=k, value=v) for k, v in values.items()]
    msg = DiagnosticArray(status=[status])
    msg.header.stamp = time_from_ns(stamp_ns)
    return msg


def read_status_values(msg: DiagnosticArray, hardware_suffix: str) -> dict[str, str] | None:
    """Key/values of the last status whose hardware id ends with ``hardware_suffix``.

    Returns None when no status of the array matches.
    """
    found = None
    for status in msg.status:
        if status.hardware_id.endswith(hardware_suffix):
            found = {kv.key: kv.value for kv in status.values}
    return found
