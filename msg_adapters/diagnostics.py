"""Status reports <-> ``diagnostic_msgs/DiagnosticArray``.

A report is a name, a hardware id, a level (``"ok"``, ``"warn"`` or ``"error"``), a
one-line message and string key/values, as ``/diagnostics`` carries them.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, Final

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue

from .header import time_from_ns

__all__ = ["LEVELS", "diagnostics_message", "noise_values", "sensor_values",
           "read_status_values"]

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


def noise_values(noise: Any, fragments: int) -> dict[str, str]:
    """Key/values of a frame's noise estimate and fragment count for a status report.

    Parameters
    ----------
    noise : geomodel_ros.core.noise.NoiseEstimate or None
        The frame's estimate (None with ``noise_model = fixed``: only the fragments).
    fragments : int
        Segments left out of the objects as too small.

    Returns
    -------
    dict of str to str
        ``noise_sigma_a_m``, ``noise_sigma_b_per_m`` (sigma(z) = a + b z^2 [m]),
        ``noise_sigma_at_1m_m``, ``noise_spacing_per_m``, ``noise_samples`` and
        ``fragments``, in that order.
    """
    values: dict[str, str] = {}
    if noise is not None:
        values = {"noise_sigma_a_m": f"{noise.a:.6f}", "noise_sigma_b_per_m": f"{noise.b:.6f}",
                  "noise_sigma_at_1m_m": f"{noise.sigma(1.0):.6f}",
                  "noise_spacing_per_m": f"{noise.spacing_per_m:.6f}",
                  "noise_samples": str(int(noise.samples))}
    values["fragments"] = str(int(fragments))
    return values


def sensor_values(sensor: Any) -> dict[str, str]:
    """Key/value of the camera recovered from an organized cloud's grid, for a status report.

    ``sensor_origin_m``: the camera's centre "x y z" [m] in the cloud's frame, when the
    cloud was not in the camera's optical frame
    (:class:`geomodel_ros.core.viewpoint.SensorPose`); no key when ``sensor`` is None.
    """
    if sensor is None:
        return {}
    return {"sensor_origin_m": " ".join(f"{v:.4f}" for v in sensor.center)}


def read_status_values(msg: DiagnosticArray, hardware_suffix: str) -> dict[str, str] | None:
    """Key/values of the last status whose hardware id ends with ``hardware_suffix``.

    Returns None when no status of the array matches.
    """
    found = None
    for status in msg.status:
        if status.hardware_id.endswith(hardware_suffix):
            found = {kv.key: kv.value for kv in status.values}
    return found
