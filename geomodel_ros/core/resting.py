"""Which modeled objects rest on which support plane (desk, shelf, floor).

An object rests on a support when the point of its fitted solid nearest the support's
plane lies within the contact tolerance of it, the solid lies on the plane's sensor side,
and its centre is over the support's bounded patch. The nearest point comes from the
solid's shape (box corners, the rims of a cylinder's, cone's or frustum's circles, a
sphere's radius), so an object whose lower end was completed down to the support
(:mod:`geomodel_ros.core.fitting.completion`) counts as resting on it.
"""

from __future__ import annotations

import math
from typing import Callable, Mapping, Sequence

import numpy as np
from numpy.typing import NDArray

from geomodel_ros.core.primitives import Primitive, PrimitiveType

__all__ = ["plane_offset", "resting_objects"]

#: Dimension of each box axis (the rotation's columns x, y, z).
_BOX_AXES = ("length", "width", "height")


def plane_offset(p: Primitive, normal: NDArray[np.float64], d: float) -> float | None:
    """Smallest signed distance [m] of the solid ``p`` from the plane ``normal . x + d = 0``.

    Positive on the side the unit ``normal`` (3,) points to. None for types without a solid
    (plane, unknown).
    """
    n = np.asarray(normal, dtype=np.float64)
    c = float(np.asarray(p.center, dtype=np.float64) @ n + d)
    dims, kind = p.dimensions, p.type
    rot = np.asarray(p.rotation, dtype=np.float64)
    if kind == PrimitiveType.CUBOID:
        return c - sum(abs(float(rot[:, k] @ n)) * dims[name] / 2
                       for k, name in enumerate(_BOX_AXES))
    if kind == PrimitiveType.SPHERE:
        return c - dims["radius"]
    if kind in (PrimitiveType.CYLINDER, PrimitiveType.CONE, PrimitiveType.FRUSTUM):
        # Circles at -h/2 (radius) and +h/2 along the axis z: the cylinder's second circle
        # has the same radius, the cone's is its apex, the frustum's its top.
        an = float(rot[:, 2] @ n)
        spread = math.sqrt(max(0.0, 1.0 - an * an))
        half = dims["height"] / 2
        top = {PrimitiveType.CYLINDER: dims["radius"], PrimitiveType.CONE: 0.0,
               PrimitiveType.FRUSTUM: dims.get("top_radius", 0.0)}[kind]
        return c + min(-an * half - dims["radius"] * spread, an * half - top * spread)
    return None


def _over(patch: Primitive, point: NDArray[np.float64]) -> bool:
    """Return True when ``point`` (3,) projects into the plane primitive's rectangle."""
    local = (np.asarray(point, dtype=np.float64) - patch.center) @ patch.rotation
    return bool(abs(local[0]) <= patch.dimensions.get("length", 0.0) / 2
                and abs(local[1]) <= patch.dimensions.get("width", 0.0) / 2)


def resting_objects(objects: Sequence[Primitive],
                    supports: Mapping[int, tuple[NDArray[np.float64], float]],
                    tolerance: Callable[[Primitive], float]) -> dict[int, list[int]]:
    """Ids of the objects resting on each support, by the support's id.

    Parameters
    ----------
    objects : sequence of Primitive
        The modeled objects, supports included (each support is the PLANE primitive with
        the support's id; supports without one get no entry).
    supports : dict id -> (normal (3,), d [m])
        Support planes, normal towards the sensor.
    tolerance : callable Primitive -> float
        Contact tolerance [m] for an object (its nearest point may lie this far above or
        below the plane).

    Returns
    -------
    dict[int, list[int]]
        Support id -> ids of the objects resting on it, in the order of ``objects``.
    """
    by_id = {o.id: o for o in objects}
    out: dict[int, list[int]] = {}
    for sid, (normal, d) in supports.items():
        patch = by_id.get(sid)
        if patch is None or patch.type != PrimitiveType.PLANE:
            continue
        out[sid] = []
        for o in objects:
            if o.id in supports:
                continue
            low = plane_offset(o, normal, d)
            if low is not None and abs(low) <= tolerance(o) and \
                    float(np.asarray(o.center) @ normal + d) > 0 and _over(patch, o.center):
                out[sid].append(o.id)
    return out
