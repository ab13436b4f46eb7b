"""A flat face seen alone above a support: the top of a solid standing on it.

A box or a can seen from straight above, or with its sides hidden by the objects in front
of it, shows the sensor its top face only, and the modeling fits a plane: a planner gets
a patch floating above the desk. The support-aware sizes (:mod:`.completion`) extend an
object's hidden lower part down to the support it rests on; a lone top face is the case
where all of it is hidden. Where the face is parallel to a support plane below it (its
normal within ``angle_tolerance`` of the plane's, farther above it than the contact
tolerance) and the evidence of :func:`~.completion.hidden_extension` says the space
between them is a hidden part of the object (the rays to its sides facing the sensor are
blocked, not seen through to the support; no ledge of other returns holds the face up;
nothing else inside), the face is the top of a solid down to the support: a cylinder
when its outline follows a circle (the circle through its convex hull's vertices nearer
than the least-area rectangle round them, as a can's lid, whole or partly hidden), else
the box of its rectangle. The height is ``completed``, the face's sizes ``observed``. A
plate or a shelf board held above the support shows the support or the background
through the gap and stays a plane. The lower end is nowhere seen, so a part none of whose
sides faces the sensor (a can's lid seen from within its circle) is judged by the ledge
and occupancy tests alone, and a ledge at any level between the face and the support
counts (``behind_itself`` of :func:`~.completion.hidden_extension`: the top of a larger
box the object stands on, seen round its footprint); the plane is then kept.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from geomodel_ros.core.confidence import surface_distance
from geomodel_ros.core.fitting.cloud import ObjectCloud
from geomodel_ros.core.fitting.completion import (Extension, RectangleSection, complete_axial,
                                                  hidden_extension, plane_beyond)
from geomodel_ros.core.fitting.strategies import outline_circle
from geomodel_ros.core.geometry import frame_with_z
from geomodel_ros.core.primitives import Primitive, PrimitiveType

__all__ = ["solid_below_top"]


def solid_below_top(cloud: ObjectCloud, plane: Primitive, reasons: list[str]
                    ) -> Primitive | None:
    """Return the solid whose top is the ``plane`` fitted to ``cloud``, or None.

    See the module docstring. Only with ``noise_model = auto``, a scene view and support
    planes; the solid's rmse is that of the object's points about its surface. The
    completion is added to ``reasons``.
    """
    params = cloud.params
    if plane.type is not PrimitiveType.PLANE or params.noise_model != "auto" or \
            cloud.view is None or not cloud.supports:
        return None
    rot = plane.rotation
    normal = rot[:, 2]
    top = float(plane.center @ normal)
    beyond = plane_beyond(cloud, normal, np.zeros(3), plane.center, top, top,
                          list(cloud.supports))
    if beyond is None or beyond[0] != 0:
        return None
    t_plane = beyond[1]
    circle = _top_circle(cloud, plane)
    if circle is not None:
        origin, radius = circle
        lo, hi, end = complete_axial(cloud, origin, normal, radius, 0.0, 0.0,
                                     behind_itself=True)
        if end is None:
            return None
        solid = Primitive(cloud.oid, PrimitiveType.CYLINDER, origin + normal * (lo + hi) / 2,
                          frame_with_z(normal), {"radius": radius, "height": hi - lo},
                          len(cloud.points), 0.0, completed=("height",))
    else:
        c = rot.T @ plane.center
        half = np.array([plane.dimensions["length"], plane.dimensions["width"]]) / 2
        ext = Extension(rot, np.zeros(3), RectangleSection(c[:2] - half, c[:2] + half), top,
                        t_plane)
        if not hidden_extension(cloud, ext, behind_itself=True):
            return None
        solid = Primitive(cloud.oid, PrimitiveType.CUBOID,
                          rot @ np.array([c[0], c[1], (top + t_plane) / 2]), rot,
                          {"length": plane.dimensions["length"],
                           "width": plane.dimensions["width"], "height": top - t_plane},
                          len(cloud.points), 0.0, completed=("height",))
    d = surface_distance(solid, cloud.points)
    height = solid.dimensions["height"]
    reasons.append(f"a top face alone {height * 1000:.1f} mm above its support, the space "
                   f"below hidden: the {solid.type.value} down to the support")
    return dataclasses.replace(solid, rmse=float(np.sqrt(np.mean(d * d))))


def _top_circle(cloud: ObjectCloud, plane: Primitive) -> tuple[np.ndarray, float] | None:
    """Return the centre (3,) [m] on the plane and radius of the face's round outline, or None.

    The object's points in the plane's frame (:func:`~.strategies.outline_circle`).
    """
    rot = plane.rotation
    circle = outline_circle((cloud.points - plane.center) @ rot[:, :2])
    if circle is None:
        return None
    centre2, radius = circle
    return plane.center + rot[:, :2] @ centre2, float(radius)
