"""Parameter definitions -> ``rcl_interfaces`` descriptors and set-parameter results.

:func:`spec_descriptor` turns an entry of the one parameter definition
(:data:`geomodel_ros.core.params.PARAMETERS`) into the ``ParameterDescriptor`` a node
declares (type, description with unit and range, numeric range); :func:`option_descriptor`
does the same for a node's own options.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from rcl_interfaces.msg import (FloatingPointRange, IntegerRange, ParameterDescriptor,
                                ParameterType, SetParametersResult)

from geomodel_ros.core.params import ParamSpec

__all__ = ["option_descriptor", "set_parameters_result", "spec_descriptor"]

#: Bounds written for an open end of an integer range (int64, what rcl stores).
_INT_MIN, _INT_MAX = -(2**63), 2**63 - 1


def spec_descriptor(spec: ParamSpec) -> ParameterDescriptor:
    """Descriptor of a modeling parameter: type, ``description [unit] Range [lo, hi].``."""
    unit = f" [{spec.unit}]" if spec.unit else ""
    rng = "" if spec.low is None and spec.high is None else f" Range [{spec.low}, {spec.high}]."
    d = ParameterDescriptor(name=spec.name, description=f"{spec.description}{unit}{rng}")
    bounded = spec.low is not None or spec.high is not None
    if spec.type is str:
        d.type = ParameterType.PARAMETER_STRING
        d.additional_constraints = f"one of: {', '.join(spec.choices or ())}"
    elif spec.type is bool:
        d.type = ParameterType.PARAMETER_BOOL
    elif spec.type is int:
        d.type = ParameterType.PARAMETER_INTEGER
        if bounded:
            lo = _INT_MIN if spec.low is None else int(spec.low)
            hi = _INT_MAX if spec.high is None else int(spec.high)
            d.integer_range = [IntegerRange(from_value=lo, to_value=hi, step=1)]
    else:
        d.type = ParameterType.PARAMETER_DOUBLE
        if bounded:
            big = np.finfo(np.float64).max
            lo = -big if spec.low is None else float(spec.low)
            hi = big if spec.high is None else float(spec.high)
            d.floating_point_range = [FloatingPointRange(from_value=lo, to_value=hi, step=0.0)]
    return d


def option_descriptor(name: str, default: Any, description: str, *, read_only: bool = False,
                      constraints: str = "", low: int | None = None,
                      high: int | None = None) -> ParameterDescriptor:
    """Descriptor of a node option; its type follows ``default`` (bool, int or string).

    An integer range is declared when both ``low`` and ``high`` are given.
    """
    d = ParameterDescriptor(name=name, description=description, read_only=read_only,
                            additional_constraints=constraints)
    if isinstance(default, bool):
        d.type = ParameterType.PARAMETER_BOOL
    elif isinstance(default, int):
        d.type = ParameterType.PARAMETER_INTEGER
        if low is not None and high is not None:
            d.integer_range = [IntegerRange(from_value=low, to_value=high, step=1)]
    else:
        d.type = ParameterType.PARAMETER_STRING
    return d


def set_parameters_result(reason: str | None = None) -> SetParametersResult:
    """Accept a set of parameters (``reason`` None) or reject it with ``reason``."""
    if reason is None:
        return SetParametersResult(successful=True)
    return SetParametersResult(successful=False, reason=reason)
