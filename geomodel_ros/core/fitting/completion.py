"""Support-aware sizes: an object's hidden lower part extends down to the support it rests on.

A camera looking down at a box on a desk sees its top and sides down to the desk, unless
something nearer hides the lower part (another object, the desk's edge, the edge of the
image). Then the box's points stop above the desk and its height comes out short. When a
large plane lies beyond an open end of an object along an axis perpendicular to it, the
end is *completed* down to the plane if the evidence says the part in between is hidden
and not empty. The large planes are the support planes of the segmentation (desk, shelf,
floor) and every other segment of the scene that is one large plane (:func:`end_planes`:
a floor or a wall the segmentation reported as an object, e.g. when the walls of a room
outnumber the supports it keeps); the nearest one beyond the end counts, and an end that
lies on a plane already is closed by it and not completed further. The evidence:

* the sensor cannot have seen the gap: of the rays to the sides of the hypothesised
  extension that face the sensor, at least MIN_KNOWN_SHARE are known, i.e. have a return
  or lie outside the sensor's field of view (never looked along: hidden,
  :meth:`~geomodel_ros.core.view.SceneView.beyond_image`); the object's own points in
  front of a side do not count (an object hides the space behind itself, which is no
  evidence); and at most MAX_THROUGH_SHARE of the known rays have their return behind
  the sides (a floating object shows the support or the background through the gap);
* nothing else holds the object up short of the plane: no surface of other points at the
  object's observed end under or right beside its footprint (within the contact
  tolerance: a ledge, such as the top of a box it stands on);
* the hypothesised extension is empty: no other points inside it.

Ends within the contact tolerance of a plane are closed by it as before
(:meth:`~geomodel_ros.core.fitting.cloud.ObjectCloud.support_ends`) and count as
observed. Without a :class:`~geomodel_ros.core.view.SceneView` (no scene, or the cloud is
not in the sensor's frame) nothing is completed.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Protocol

import numpy as np
from numpy.typing import NDArray

from geomodel_ros.core.fitting.cloud import SUPPORT_END_FACTOR, ObjectCloud, Plane
from geomodel_ros.core.fitting.verify import OUTLIER_FACTOR
from geomodel_ros.core.geometry import frame_with_z
from geomodel_ros.core.params import ModelingParams

__all__ = ["Section", "RectangleSection", "CircleSection", "Extension", "end_planes",
           "plane_beyond", "hidden_extension", "complete_box", "complete_axial"]

#: Angular cell of the ray look-up, in median point spacings of the object (at its
#: range): a surface facing the sensor leaves about four returns per cell, so no cell on
#: it is empty.
CELL_SPACINGS = 2.0
#: Probe rays: this many steps across the gap along the axis, this many across each flat
#: side of a box, this many round a cylinder (enough that a few stray returns cannot
#: decide; the test costs a few milliseconds per candidate object).
PROBE_STEPS = 8
PROBE_ACROSS = 8
PROBE_ANGLES = 32
#: The gap is judged hidden when at most this share of the probe rays with a return see
#: through the hypothesised sides (rays that graze a side at the silhouette may pass an
#: occluder's edge) ...
MAX_THROUGH_SHARE = 0.2
#: ... and at least this share of the probe rays have a return (holes and dropouts
#: decide nothing).
MIN_KNOWN_SHARE = 0.5
#: Fewest other returns on a ledge or inside the extension that count as a surface (a few
#: flying pixels do not).
MIN_OTHER_RETURNS = 20
#: Least turn round a section's centre [rad] over which returns at one level beside it
#: form a ledge the object may stand on (a quarter turn; :func:`_ledge_round`).
LEDGE_TURN = math.pi / 2
#: A segment of the scene is one large plane when at least this share of its points lie
#: within ``seg_plane_threshold`` of its plane (a box's segment, two faces or more, holds
#: at most about half of its points on one plane) and its points cover
#: ``seg_min_support_area`` (the area that makes a support).
PLANE_SEGMENT_SHARE = 0.9

class Section(Protocol):
    """Cross-section of an object perpendicular to its axis, in (s1, s2) coordinates [m]."""

    def outline(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Points (k, 2) on the outline and their outward unit normals (k, 2)."""

    def contains(self, s: NDArray[np.float64], margin: float | NDArray[np.float64]
                 ) -> NDArray[np.bool_]:
        """Whether the points ``s`` (m, 2) lie inside by more than ``margin`` [m] (or (m,))."""

    def outside(self, s: NDArray[np.float64]) -> NDArray[np.float64]:
        """Distance [m] (m,) of ``s`` (m, 2) [m] outside the section (0 inside)."""

    def centre(self) -> NDArray[np.float64]:
        """Centre (2,) [m] of the section."""


@dataclass(frozen=True)
class RectangleSection:
    """A box's cross-section: [lo1, hi1] x [lo2, hi2] [m]."""

    lo: NDArray[np.float64]
    hi: NDArray[np.float64]

    def outline(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Sample each of the four sides at PROBE_ACROSS points; normals outwards."""
        f = (np.arange(PROBE_ACROSS) + 0.5) / PROBE_ACROSS
        pts, normals = [], []
        for k in range(2):
            j = 1 - k
            along = self.lo[j] + f * (self.hi[j] - self.lo[j])
            for side, sign in ((self.lo[k], -1.0), (self.hi[k], 1.0)):
                p = np.empty((PROBE_ACROSS, 2))
                p[:, k], p[:, j] = side, along
                n = np.zeros((PROBE_ACROSS, 2))
                n[:, k] = sign
                pts.append(p)
                normals.append(n)
        return np.concatenate(pts), np.concatenate(normals)

    def contains(self, s: NDArray[np.float64], margin: float | NDArray[np.float64]
                 ) -> NDArray[np.bool_]:
        """Inside the rectangle shrunk by ``margin`` (scalar or one per point) on every side."""
        m = np.asarray(margin, dtype=np.float64)[..., None]
        return np.all((s > self.lo + m) & (s < self.hi - m), axis=1)

    def outside(self, s: NDArray[np.float64]) -> NDArray[np.float64]:
        """Distance outside the rectangle."""
        return np.linalg.norm(np.maximum(np.maximum(self.lo - s, s - self.hi), 0.0), axis=1)

    def centre(self) -> NDArray[np.float64]:
        """Centre of the rectangle."""
        return (self.lo + self.hi) / 2


@dataclass(frozen=True)
class CircleSection:
    """A cylinder's cross-section: a circle of ``radius`` [m] round (0, 0)."""

    radius: float

    def outline(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Sample the circle at PROBE_ANGLES points."""
        a = np.arange(PROBE_ANGLES) * (2.0 * math.pi / PROBE_ANGLES)
        n = np.column_stack([np.cos(a), np.sin(a)])
        return self.radius * n, n

    def contains(self, s: NDArray[np.float64], margin: float | NDArray[np.float64]
                 ) -> NDArray[np.bool_]:
        """Inside the circle shrunk by ``margin`` (scalar or one per point)."""
        return np.linalg.norm(s, axis=1) < self.radius - margin

    def outside(self, s: NDArray[np.float64]) -> NDArray[np.float64]:
        """Distance outside the circle."""
        return np.maximum(np.linalg.norm(s, axis=1) - self.radius, 0.0)

    def centre(self) -> NDArray[np.float64]:
        """Return the axis: (0, 0)."""
        return np.zeros(2)


@dataclass(frozen=True)
class Extension:
    """The part an object would gain between its observed end and a support plane.

    Attributes
    ----------
    frame : (3, 3) float64
        Columns s1, s2 (the section's axes) and the object's axis.
    origin : (3,) float64 [m]
        Point at which local coordinates are zero.
    section : Section
    t_end, t_plane : float [m]
        Axial coordinates of the observed end and of the support plane on the axis.
    slope : float
        Outward growth of the section per metre along the axis (a cone's or frustum's
        taper, tan of its half-angle; 0 for a prism): ``section`` is the section at
        ``t_end``, and at ``t`` its outline lies ``slope * (t - t_end)`` [m] farther out.
    """

    frame: NDArray[np.float64]
    origin: NDArray[np.float64]
    section: Section
    t_end: float
    t_plane: float
    slope: float = 0.0

    def grow(self, t: NDArray[np.float64] | float) -> NDArray[np.float64]:
        """Outward offset [m] of the section's outline at axial coordinates ``t`` [m]."""
        return self.slope * (np.asarray(t, dtype=np.float64) - self.t_end)

    def local(self, x: NDArray[np.float64]) -> NDArray[np.float64]:
        """Local coordinates (m, 3) (s1, s2, t) of the points ``x`` (m, 3) [m]."""
        return (x - self.origin) @ self.frame

    def diameter(self) -> float:
        """Largest width [m] of the section (its outline's extent) over the extension."""
        s, _ = self.section.outline()
        wider = 2.0 * max(float(self.grow(self.t_plane)), 0.0)
        return float(np.linalg.norm(s.max(axis=0) - s.min(axis=0))) + wider

    def end_centre(self) -> NDArray[np.float64]:
        """Centre (3,) [m] of the section at the observed end."""
        c = self.section.centre()
        return self.origin + c[0] * self.frame[:, 0] + c[1] * self.frame[:, 1] + \
            self.t_end * self.frame[:, 2]

    def probes(self) -> NDArray[np.float64]:
        """Points (k, 3) [m] on the extension's sides that face the sensor (at the origin)."""
        s, n = self.section.outline()
        f = (np.arange(PROBE_STEPS) + 0.5) / PROBE_STEPS
        t = self.t_end + f * (self.t_plane - self.t_end)
        u, v, w = self.frame[:, 0], self.frame[:, 1], self.frame[:, 2]
        on_side = self.origin + s[:, :1] * u + s[:, 1:] * v
        normals = n[:, :1] * u + n[:, 1:] * v
        pts = on_side[:, None, :] + t[None, :, None] * w + \
            self.grow(t)[None, :, None] * normals[:, None, :]
        facing = np.einsum("kj,kij->ki", normals, pts) < 0.0
        return pts[facing]


def end_planes(cloud: ObjectCloud) -> list[Plane]:
    """Planes (normal towards the sensor, d) an end of ``cloud`` may be completed to.

    The support planes, then every other segment of the scene view that is one large
    plane: PLANE_SEGMENT_SHARE of its sampled points within ``seg_plane_threshold`` of
    its plane (:meth:`~geomodel_ros.core.view.SceneView.plane_segments`), the convex hull
    of its points in the plane covering ``seg_min_support_area``, and not a support
    itself. Without a scene view only the supports.
    """
    planes = list(cloud.supports)
    if cloud.view is None:
        return planes
    params = cloud.params
    for seg in cloud.view.plane_segments(params.seg_min_support_area):
        if seg.label == cloud.oid or seg.area < params.seg_min_support_area or \
                seg.share(params.seg_plane_threshold) < PLANE_SEGMENT_SHARE:
            continue
        if not any(_same_plane((seg.normal, seg.d), p, params) for p in cloud.supports):
            planes.append((seg.normal, seg.d))
    return planes


def _same_plane(a: Plane, b: Plane, params: ModelingParams) -> bool:
    """Whether two planes (normals towards the sensor) are one.

    One: normals within ``angle_tolerance``, offsets within the contact tolerance (the
    segment of a support plane is that support).
    """
    tol = SUPPORT_END_FACTOR * params.seg_plane_threshold
    return float(a[0] @ b[0]) >= math.cos(params.angle_tolerance) and abs(a[1] - b[1]) <= tol


def plane_beyond(cloud: ObjectCloud, axis: NDArray[np.float64], origin: NDArray[np.float64],
                 ref: NDArray[np.float64], lo: float, hi: float,
                 planes: list[Plane] | None = None) -> tuple[int, float] | None:
    """Find the nearest plane beyond an open end of [lo, hi] along ``axis`` (3,).

    Coordinates are ``(x - origin) . axis`` [m]; the plane is crossed on the axis line
    through ``ref`` (3,). Of ``planes`` (default: :func:`end_planes`) only those
    perpendicular to the axis (within ``angle_tolerance``) with ``ref`` on their sensor
    side count. An end within the contact tolerance (SUPPORT_END_FACTOR
    ``seg_plane_threshold``) of one of them is closed by it; beyond an open end the
    nearest is taken. Returns (0 for the low end or 1 for the high end, the plane's
    coordinate), or None.
    """
    params = cloud.params
    tol = SUPPORT_END_FACTOR * params.seg_plane_threshold
    best: tuple[float, int, float] | None = None
    closed = [False, False]
    for n, d in end_planes(cloud) if planes is None else planes:
        c, above = float(n @ axis), float(n @ ref) + d
        if abs(c) < math.cos(params.angle_tolerance) or above <= 0.0:
            continue
        t = float((ref - origin) @ axis) - above / c
        end = 0 if t < (lo + hi) / 2 else 1
        gap = lo - t if end == 0 else t - hi
        closed[end] |= abs(gap) <= tol
        if gap > tol and (best is None or gap < best[0]):
            best = (gap, end, t)
    return None if best is None or closed[best[1]] else best[1:]


def hidden_extension(cloud: ObjectCloud, ext: Extension, behind_itself: bool = False) -> bool:
    """Return True when the evidence says ``ext`` is a hidden part of the object.

    See the module docstring: rays to its sensor-facing sides blocked (not seen
    through), no ledge of other returns at the observed end, nothing else inside it.
    With ``behind_itself`` (an object seen by its top face alone, its lower end nowhere
    seen): an extension none of whose sides faces the sensor lies behind the object's own
    end (a can's lid seen from within the circle of its side), no ray can tell, and it is
    judged by the ledge and occupancy tests alone; and a ledge at any level between the
    ends holds the object up (the top of a box it stands on, seen round its footprint).
    Without it such an extension is not hidden.
    """
    view = cloud.view
    probes = ext.probes()
    if view is None or (len(probes) == 0 and not behind_itself):
        return False
    rng = float(np.linalg.norm(cloud.center))
    cell = CELL_SPACINGS * cloud.spacing / max(rng, np.finfo(float).tiny)
    if not cell > 0.0:  # no point spacing known (every point a duplicate): no evidence
        return False
    contact = SUPPORT_END_FACTOR * cloud.params.seg_plane_threshold
    # The look-up also covers the outline at the observed end, grown by the contact
    # tolerance (where a ledge would be), and returns the points in the range band of
    # the extension (for the ledge and occupancy tests).
    ring = ext.end_centre() + _outline_world(ext, contact)
    r_probes = np.linalg.norm(probes if len(probes) else ring, axis=1)
    band = (float(r_probes.min()) - contact, float(r_probes.max()) + ext.diameter() + contact)
    got = view.returns(np.concatenate([probes, ring]), cell, band)
    if len(probes) == 0:
        return not _held_or_filled(cloud, ext, got.points[got.labels != cloud.oid], True)
    nearest, r_t = got.nearest[:len(probes)], got.ranges[:len(probes)]
    # A return counts as on a side within the sizing's outlier band, plus the depth
    # spread of one cell on a surface seen at an angle.
    tol = OUTLIER_FACTOR * cloud.params.ransac_threshold + cell * r_t
    # The object's own points in front of a probe hide it from itself, which says nothing
    # about what lies there (the gap behind a box towards a wall).
    own = (got.nearest_label[:len(probes)] == cloud.oid) & (nearest < r_t - tol)
    seen = np.isfinite(nearest) & ~own
    through = int(np.count_nonzero(nearest[seen] > (r_t + tol)[seen]))
    # A ray outside the field of view was never looked along: hidden, as by an occluder.
    unseen = ~np.isfinite(nearest)
    unseen[unseen] = view.beyond_image(probes[unseen])
    n_known = int(np.count_nonzero(seen | unseen))
    if n_known < MIN_KNOWN_SHARE * len(probes) or through > MAX_THROUGH_SHARE * n_known:
        return False
    return not _held_or_filled(cloud, ext, got.points[got.labels != cloud.oid], behind_itself)


def _outline_world(ext: Extension, grow: float) -> NDArray[np.float64]:
    """Return the section's outline (k, 3) [m] grown by ``grow`` [m], from its centre."""
    s, n = ext.section.outline()
    s = s - ext.section.centre() + grow * n
    return s[:, :1] * ext.frame[:, 0] + s[:, 1:] * ext.frame[:, 1]


def _held_or_filled(cloud: ObjectCloud, ext: Extension, others: NDArray[np.float64],
                    any_level: bool = False) -> bool:
    """Whether other returns (k, 3) form a ledge at the observed end or fill the extension.

    With ``any_level`` a ledge at one level anywhere between the observed end and the
    plane counts too (returns under or right beside the section there, the plane's own
    band left out, round it: :func:`_ledge_round`).
    """
    tol = SUPPORT_END_FACTOR * cloud.params.seg_plane_threshold
    q = ext.local(others)
    t = q[:, 2]
    lo, hi = sorted((ext.t_end, ext.t_plane))
    outside = ext.section.outside(q[:, :2])
    ledge = (np.abs(t - ext.t_end) <= tol) & (outside <= tol)  # under or right beside it
    if any_level and int(np.count_nonzero(ledge)) < MIN_OTHER_RETURNS:
        beside = outside <= tol + np.maximum(ext.grow(t), 0.0)
        on = beside & (np.abs(t - ext.t_plane) > tol) & (t >= lo - tol) & (t <= hi + tol)
        if _ledge_round(ext, q[on], float(2.0 * tol)):
            return True
    between = (t > lo + tol) & (t < hi - tol)
    inside = between & ext.section.contains(q[:, :2], tol - ext.grow(t))
    return int(np.count_nonzero(ledge)) >= MIN_OTHER_RETURNS or \
        int(np.count_nonzero(inside)) >= MIN_OTHER_RETURNS


def _ledge_round(ext: Extension, q: NDArray[np.float64], step: float) -> bool:
    """Whether returns beside the section (local coordinates (k, 3)) form a ledge round it.

    Levels ``step`` [m] deep from the observed end towards the plane; a level holds a
    ledge when MIN_OTHER_RETURNS of the returns lie in it and they reach round the
    section's centre over at least LEDGE_TURN: a surface the object stands on reaches
    under it and shows round it wherever the sensor sees past the object, while a
    neighbour standing beside it touches one side (its points within a narrow turn).
    """
    if len(q) < MIN_OTHER_RETURNS:
        return False
    level = np.floor(np.abs(q[:, 2] - ext.t_end) / step).astype(np.int64)
    c = ext.section.centre()
    turn = np.arctan2(q[:, 1] - c[1], q[:, 0] - c[0])
    for k in np.flatnonzero(np.bincount(level) >= MIN_OTHER_RETURNS):
        a = np.sort(turn[level == k])
        gaps = np.diff(np.append(a, a[0] + 2.0 * math.pi))
        if 2.0 * math.pi - float(gaps.max()) >= LEDGE_TURN:
            return True
    return False


def complete_box(cloud: ObjectCloud, rot: NDArray[np.float64], lo: NDArray[np.float64],
                 hi: NDArray[np.float64]
                 ) -> tuple[NDArray[np.float64], NDArray[np.float64], tuple[int, ...]]:
    """Extend a box's hidden ends down to the support planes beyond them.

    Parameters
    ----------
    rot : (3, 3) float64
        Box axes (columns); box coordinates are ``x @ rot``.
    lo, hi : (3,) float64 [m]
        The box's ends along its axes.

    Returns
    -------
    lo, hi : (3,) float64 [m]
        The ends, completed where the evidence says so.
    completed : tuple of int
        The axes whose extent was completed.
    """
    lo, hi = lo.copy(), hi.copy()
    done = []
    planes = end_planes(cloud)
    for a in range(3):
        b, c = (a + 1) % 3, (a + 2) % 3
        centre = rot @ ((lo + hi) / 2)
        beyond = plane_beyond(cloud, rot[:, a], np.zeros(3), centre, lo[a], hi[a], planes)
        if beyond is None:
            continue
        end, t_plane = beyond
        frame = np.column_stack([rot[:, b], rot[:, c], rot[:, a]])
        section = RectangleSection(np.array([lo[b], lo[c]]), np.array([hi[b], hi[c]]))
        ends = lo if end == 0 else hi
        if hidden_extension(cloud, Extension(frame, np.zeros(3), section, float(ends[a]),
                                             t_plane)):
            ends[a] = t_plane
            done.append(a)
    return lo, hi, tuple(done)


def complete_axial(cloud: ObjectCloud, origin: NDArray[np.float64], axis: NDArray[np.float64],
                   radius: float, lo: float, hi: float, slope: float = 0.0,
                   ends: tuple[int, ...] = (0, 1), behind_itself: bool = False
                   ) -> tuple[float, float, int | None]:
    """Extend a standing round solid's hidden end down to the support plane beyond it.

    The side ``origin + t * axis``, ``lo <= t <= hi`` [m], of radius ``radius + slope *
    t`` [m] at ``t``: a cylinder (``slope`` 0), or a cone or frustum with its apex at
    ``origin`` (``radius`` 0, ``slope`` the tangent of its half-angle), whose hidden part
    keeps its taper down to the plane. Only the ``ends`` listed (0 the low end, 1 the high
    end) may be completed (a cone's apex is no end to complete); ``behind_itself``: as
    :func:`hidden_extension`'s. A lying cylinder (axis
    parallel to the support) has no plane beyond its ends and is returned unchanged.
    Returns the ends and the end completed (None when neither was).
    """
    beyond = plane_beyond(cloud, axis, origin, origin + axis * (lo + hi) / 2, lo, hi)
    if beyond is None or beyond[0] not in ends:
        return lo, hi, None
    end, t_plane = beyond
    t_end = (lo, hi)[end]
    ext = Extension(frame_with_z(axis), origin, CircleSection(radius + slope * t_end), t_end,
                    t_plane, slope)
    if not hidden_extension(cloud, ext, behind_itself):
        return lo, hi, None
    return (t_plane, hi, end) if end == 0 else (lo, t_plane, end)
