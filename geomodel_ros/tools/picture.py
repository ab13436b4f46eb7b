"""Pictures of a modeled real scene: every object coloured, outlined and labelled.

``python -m geomodel_ros.tools.picture CLOUD --out PNG [--json RESULT]`` models a cloud
file with the default parameters (or ``--params``), and writes one PNG that shows

* the **sensor view**: the cloud seen through its own camera. For an organized cloud
  (640 x 480 Kinect frames, PCD files with ``height > 1``) that camera is recovered from
  the pixel grid itself (:func:`organized_camera`: a least-squares pinhole fit of each
  pixel's column and row to ``x / z`` and ``y / z``, exact for a depth camera's cloud), so
  the picture is exactly the sensor's image whatever frame convention the file uses (PCL's
  tutorials store some clouds looking along ``-z``);
* optionally an **oblique view**: the same scene turned about its up direction (the
  largest plane's normal) and seen a little more from above, so heights and depths show;
* in both, each point in its object's colour (:func:`geomodel_ros.core.colors.id_colors`,
  the colours of RViz and of the PLY; grey = no object, e.g. left-out fragments), a wire
  outline of each fitted primitive (box edges, cylinder and cone rims, a plane's
  rectangle; solid where visible, dotted where hidden behind the points) and an
  ``"id type"`` label at each object; a legend with every object's sizes in mm.

Everything is rasterised with numpy (:mod:`geomodel_ros.tools.render` splats the points,
its bitmap font draws the text) and written by open3d; no display is needed.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path
from typing import Final, Sequence

import numpy as np
from numpy.typing import NDArray

from geomodel_ros.core.colors import NO_OBJECT_RGB, id_colors
from geomodel_ros.core.errors import InputError, as_points
from geomodel_ros.core.faces import estimate_normals
from geomodel_ros.core.primitives import Primitive
from geomodel_ros.tools.render import (
    draw_text, fit_camera, legend_label, render_points, text_size,
)
from geomodel_ros.tools.synth.camera import PinholeCamera

__all__ = [
    "organized_camera",
    "primitive_wires",
    "draw_polylines",
    "scene_picture",
    "write_png",
    "main",
]

#: Largest RMS residual [px] of the pinhole fit of an organized cloud's pixel grid for the
#: fit to count as the sensor's camera: a depth camera's own cloud fits to ~1e-4 px (float
#: rounding); anything over half a pixel is not a pinhole image (e.g. a re-sorted cloud).
PINHOLE_FIT_TOLERANCE_PX: Final = 0.5
#: Segments of a full circle of a wire outline: smooth at picture scale (a 0.3 m rim at
#: 1 m seen by a 525 px camera has ~6 px per segment).
CIRCLE_SEGMENTS: Final = 48
#: Turn of the oblique view about the scene's up direction [rad]: enough to show the sides
#: the sensor saw edge-on, little enough that the scene is still recognisable next to the
#: sensor view.
OBLIQUE_YAW: Final = math.radians(35.0)
#: Elevation of the oblique view above the largest plane (floor, desk) [rad], whatever the
#: sensor's own: low enough that heights show, high enough to see over the objects.
OBLIQUE_ELEVATION: Final = math.radians(25.0)
#: Brightness of an outline relative to its object's colour: dark enough to stand out on
#: the object's own points, still recognisably that object's hue.
WIRE_SHADE: Final = 0.35
#: A wire sample is hidden when it lies this much farther than the visible point of its
#: pixel (relative depth): about three times a Kinect's depth noise at 1-3 m.
WIRE_HIDDEN_STEP: Final = 0.02
#: Every this many pixels along a hidden wire one pixel is drawn (dotted line).
HIDDEN_DOT_PERIOD: Final = 4

#: Splats cover this many times the projected point spacing [px] (closes the gaps of a
#: zoomed-in view), within [MIN_SPLAT, MAX_SPLAT] px.
SPLAT_COVER: Final = 1.3
MIN_SPLAT: Final = 2
MAX_SPLAT: Final = 9
#: Points on which the spacing is measured (a median needs no more).
SPACING_SAMPLE: Final = 2000

#: Direction towards the light in the camera frame: above-left of the viewer.
HEADLIGHT: Final = np.array([-0.35, -0.55, -1.0]) / np.linalg.norm([-0.35, -0.55, -1.0])
#: How much a surface turned away from the light darkens (0: flat colours) and in how
#: many brightness steps per unit: the shape reads, the picture compresses well.
SHADE_DEPTH: Final = 0.55
SHADE_LEVELS: Final = 8
#: Shading normals of an organized cloud come from the points this many pixels to either
#: side: smooth enough through a Kinect's depth noise that the shading shows surfaces,
#: not speckle (which also makes the PNG several times larger).
GRID_NORMAL_STEP: Final = 3

RGB = tuple[int, int, int]
_WHITE: RGB = (255, 255, 255)
_INK: RGB = (25, 25, 25)
_TITLE_BG: RGB = (38, 44, 56)
_TITLE_H: Final = 40
_LEGEND_LINE: Final = 22


# ------------------------------------------------------------------------------ cameras
def organized_camera(points) -> tuple[PinholeCamera, NDArray[np.float64]] | None:
    """Recover the pinhole camera of an organized cloud from its pixel grid.

    Parameters
    ----------
    points : (H, W, 3) float array [m]
        Organized cloud; non-finite entries are missing pixels.

    Returns
    -------
    (camera, rotation) or None
        ``camera``: intrinsics (``fx, fy > 0``, ``cx, cy`` [px], ``W x H``) with identity
        pose in the optical frame; ``rotation`` (3, 3): a signed axis permutation
        ``diag(+-1, +-1, +-1)`` that maps the cloud's frame to that optical frame (x right,
        y down, z forward). None when fewer than 10 pixels are valid or the grid is not a
        pinhole image (RMS residual over :data:`PINHOLE_FIT_TOLERANCE_PX`).
    """
    arr = np.asarray(points, dtype=np.float64)
    if arr.ndim != 3 or arr.shape[2] != 3:
        raise InputError(f"an organized cloud is (H, W, 3), got shape {arr.shape}")
    h, w = arr.shape[:2]
    ok = np.isfinite(arr).all(axis=2) & (np.abs(arr[..., 2]) > 1e-9)
    if ok.sum() < 10:
        return None
    rows, cols = np.nonzero(ok)
    p = arr[ok]
    coef = []
    for ratio, pix in ((p[:, 0] / p[:, 2], cols), (p[:, 1] / p[:, 2], rows)):
        a = np.column_stack([ratio, np.ones_like(ratio)])
        sol, *_ = np.linalg.lstsq(a, pix.astype(np.float64), rcond=None)
        if np.sqrt(np.mean((a @ sol - pix) ** 2)) > PINHOLE_FIT_TOLERANCE_PX or \
                abs(sol[0]) < 1e-9:
            return None
        coef.append(sol)
    s = 1.0 if np.median(p[:, 2]) > 0 else -1.0
    rotation = np.diag([s * np.sign(coef[0][0]), s * np.sign(coef[1][0]), s])
    cam = PinholeCamera(abs(coef[0][0]), abs(coef[1][0]), coef[0][1], coef[1][1], w, h)
    return cam, rotation


def _sensor_frame(points) -> tuple[NDArray[np.float64], PinholeCamera | None,
                                   NDArray[np.float64]]:
    """Flat points (N, 3) [m], the organized cloud's camera (or None) and its rotation."""
    arr = np.asarray(points)
    if arr.ndim == 3 and arr.shape[2] == 3:
        found = organized_camera(arr)
        if found is not None:
            return as_points(arr, allow_organized=True), found[0], found[1]
    pts = as_points(points, allow_organized=True)
    z = pts[np.isfinite(pts).all(axis=1), 2]
    flip = len(z) and np.median(z) < 0  # looks along -z: turn about x
    return pts, None, np.diag([1.0, -1.0, -1.0]) if flip else np.eye(3)


# ------------------------------------------------------------------------------ outlines
def _circle(center, u, v, radius: float) -> NDArray[np.float64]:
    t = np.linspace(0.0, 2.0 * math.pi, CIRCLE_SEGMENTS + 1)
    return center + radius * (np.outer(np.cos(t), u) + np.outer(np.sin(t), v))


def _box_edges(center, axes, half) -> list[NDArray[np.float64]]:
    """Return the 12 edges of a box (axes: (3, 3) columns, half: (3,) half sizes [m])."""
    signs = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)])
    corners = center + (signs * half) @ axes.T
    edges = []
    for i in range(8):
        for j in range(i + 1, 8):
            if np.count_nonzero(signs[i] != signs[j]) == 1:
                edges.append(corners[[i, j]])
    return edges


def _axial_wires(p: Primitive, radius: float, top: float) -> list[NDArray[np.float64]]:
    """Rims (base, top) and four side lines of a cylinder, cone or frustum."""
    u, v, axis = p.rotation[:, 0], p.rotation[:, 1], p.rotation[:, 2]
    half = 0.5 * p.dimensions["height"]
    base, cap = p.center - half * axis, p.center + half * axis
    wires = [_circle(base, u, v, radius)]
    if top > 0:
        wires.append(_circle(cap, u, v, top))
    for ang in np.arange(4) * (math.pi / 2):
        d = math.cos(ang) * u + math.sin(ang) * v
        wires.append(np.array([base + radius * d, cap + top * d]))
    return wires


def primitive_wires(p: Primitive) -> list[NDArray[np.float64]]:
    """Wire outline of a fitted primitive as polylines in its frame [m].

    Parameters
    ----------
    p : Primitive

    Returns
    -------
    list of (K, 3) float64 arrays
        Cuboid: its 12 edges; plane: its rectangle; cylinder, frustum: both rims and four
        side lines; cone: the base rim and four lines to the apex; sphere: three great
        circles; ``unknown`` (or a type without sizes): none.
    """
    d, r = p.dimensions, p.rotation
    if p.type == "cuboid":
        return _box_edges(p.center, r, 0.5 * np.array([d["length"], d["width"], d["height"]]))
    if p.type == "plane":
        half = 0.5 * np.array([d["length"], d["width"]])
        signs = np.array([[-1, -1], [1, -1], [1, 1], [-1, 1], [-1, -1]])
        return [p.center + (signs * half) @ r[:, :2].T]
    if p.type == "cylinder":
        return _axial_wires(p, d["radius"], d["radius"])
    if p.type == "cone":
        return _axial_wires(p, d["radius"], 0.0)
    if p.type == "frustum":
        return _axial_wires(p, d["radius"], d["top_radius"])
    if p.type == "sphere":
        e = np.eye(3)
        return [_circle(p.center, e[i], e[(i + 1) % 3], d["radius"]) for i in range(3)]
    return []


# ------------------------------------------------------------------------------ drawing
def _sample_polyline(q: NDArray[np.float64], camera: PinholeCamera
                     ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Points about one pixel apart along a camera-frame polyline: (u, v) [px] and depth [m].

    Segments with an end behind the camera are skipped.
    """
    a, b = q[:-1], q[1:]
    keep = (a[:, 2] > 1e-6) & (b[:, 2] > 1e-6)
    a, b = a[keep], b[keep]
    if not len(a):
        return np.zeros((0, 2)), np.zeros(0)
    ua, ub = camera.project_camera_frame(a), camera.project_camera_frame(b)
    steps = np.clip(np.ceil(np.linalg.norm(ub - ua, axis=1)), 1, 4 * (camera.width
                                                                     + camera.height))
    n = steps.astype(np.int64) + 1
    seg = np.repeat(np.arange(len(a)), n)
    t = (np.arange(n.sum()) - np.repeat(np.cumsum(n) - n, n)) / np.repeat(steps, n)
    pts = a[seg] + t[:, None] * (b[seg] - a[seg])  # straight in 3-D, straight in the image
    return camera.project_camera_frame(pts), pts[:, 2]


def draw_polylines(img: NDArray[np.uint8], polylines: Sequence[NDArray[np.float64]],
                   camera: PinholeCamera, color, depth: NDArray[np.float64] | None = None,
                   thickness: int = 2) -> None:
    """Draw 3-D polylines into ``img`` in place, solid where visible, dotted where hidden.

    Parameters
    ----------
    img : (H, W, 3) uint8 array
        The camera's image.
    polylines : sequence of (K, 3) float arrays [m]
        Scene-frame polylines (the camera's pose maps them to its optical frame).
    camera : PinholeCamera
    color : 3 ints in [0, 255]
    depth : (H, W) float array [m], optional
        Depth of the visible surface per pixel (``inf`` where none): samples farther than
        it by :data:`WIRE_HIDDEN_STEP` (relative) are drawn dotted. Without it every
        sample is drawn solid.
    thickness : int
        Line width [px], 1-5.
    """
    if not 1 <= int(thickness) <= 5:
        raise ValueError(f"thickness must be in [1, 5] px, got {thickness!r}")
    h, w = img.shape[:2]
    for line in polylines:
        uv, z = _sample_polyline(camera.to_camera_frame(line), camera)
        if not len(z):
            continue
        u, v = np.rint(uv[:, 0]).astype(np.int64), np.rint(uv[:, 1]).astype(np.int64)
        show = (u >= 0) & (u < w) & (v >= 0) & (v < h)
        if depth is not None:
            hidden = np.zeros(len(z), dtype=bool)
            hidden[show] = z[show] > depth[v[show], u[show]] * (1.0 + WIRE_HIDDEN_STEP)
            show &= ~hidden | (np.arange(len(z)) % HIDDEN_DOT_PERIOD == 0)
            wide = ~hidden
        else:
            wide = np.ones(len(z), dtype=bool)
        for dy in range(int(thickness)):
            for dx in range(int(thickness)):
                m = show & (wide | ((dx == 0) & (dy == 0)))
                uu, vv = u[m] + dx - thickness // 2, v[m] + dy - thickness // 2
                ok = (uu >= 0) & (uu < w) & (vv >= 0) & (vv < h)
                img[vv[ok], uu[ok]] = color


def _place_label(img: NDArray[np.uint8], text: str, anchor: tuple[float, float], color,
                 taken: list[tuple[int, int, int, int]], scale: int) -> None:
    """Draw ``text`` in a white box with a coloured border near ``anchor`` (u, v) [px].

    The box moves down (then up) past boxes already ``taken`` and stays inside the image.
    """
    h, w = img.shape[:2]
    tw, th = text_size(text, scale)
    bw, bh = tw + 6, th + 2
    x = int(np.clip(anchor[0] - bw / 2, 0, max(w - bw, 0)))
    y0 = int(np.clip(anchor[1] - bh / 2, 0, max(h - bh, 0)))
    y = y0
    for k in range(1, 40):
        box = (x, y, x + bw, y + bh)
        if not any(b[0] < box[2] and box[0] < b[2] and b[1] < box[3] and box[1] < b[3]
                   for b in taken):
            break
        step = (k + 1) // 2 * (bh + 2) * (1 if k % 2 else -1)
        y = int(np.clip(y0 + step, 0, max(h - bh, 0)))
    taken.append((x, y, x + bw, y + bh))
    img[y:y + bh, x:x + bw] = color
    img[y + 2:y + bh - 2, x + 2:x + bw - 2] = _WHITE
    draw_text(img, text, (x + 3, y + 2), scale, _INK)


def _grid_normals(points: NDArray[np.float64], shape: tuple[int, int] | None
                  ) -> NDArray[np.float64]:
    """Return shading normals (N, 3) of the points (either orientation).

    Pixel-grid differences (:data:`GRID_NORMAL_STEP` pixels to either side) for an
    organized cloud of ``shape`` (H, W), else PCA over 12 neighbours.
    """
    if shape is None:
        normals = np.zeros_like(points)
        fin = np.isfinite(points).all(axis=1)
        if fin.sum() >= 3:
            normals[fin] = estimate_normals(points[fin], 12)[0]
        return normals
    g = points.reshape(*shape, 3)
    du = np.zeros_like(g)
    dv = np.zeros_like(g)
    k = GRID_NORMAL_STEP
    du[:, k:-k] = g[:, 2 * k:] - g[:, :-2 * k]
    dv[k:-k] = g[2 * k:] - g[:-2 * k]
    n = np.cross(du, dv).reshape(-1, 3)
    n[~np.isfinite(n).all(axis=1)] = 0.0
    return n


# ------------------------------------------------------------------------------ views
def _splat(points: NDArray[np.float64], camera: PinholeCamera) -> int:
    """Splat size [px] that closes the gaps between neighbouring ``points`` in ``camera``."""
    from scipy.spatial import cKDTree

    if len(points) < 2:
        return MIN_SPLAT
    step = max(1, len(points) // SPACING_SAMPLE)
    sample = points[::step]
    spacing = float(np.median(cKDTree(points).query(sample, k=2)[0][:, 1]))
    z = camera.to_camera_frame(sample)[:, 2]
    z = z[z > 0]
    if not len(z):
        return MIN_SPLAT
    px = SPLAT_COVER * spacing * camera.fx / float(np.median(z))
    return int(np.clip(math.ceil(px), MIN_SPLAT, MAX_SPLAT))


def _shaded(labels: NDArray[np.int64], normals: NDArray[np.float64], camera: PinholeCamera
            ) -> NDArray[np.uint8]:
    """Object colours (N, 3) darkened by a headlight on the ``normals`` (N, 3), in steps.

    Brightness ``1 - SHADE_DEPTH * (1 - |n . light|)`` rounded to :data:`SHADE_LEVELS`
    levels: surfaces show their orientation, and flat colour areas keep the PNG small.
    """
    n = normals @ np.ascontiguousarray(camera.rotation.T)
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
    f = 1.0 - SHADE_DEPTH * (1.0 - np.abs(n @ HEADLIGHT))
    f = np.round(f * SHADE_LEVELS) / SHADE_LEVELS
    return np.clip(id_colors(labels) * f[:, None], 0, 255).astype(np.uint8)


def _view(points, normals, labels, primitives, camera: PinholeCamera, scale: int
          ) -> NDArray[np.uint8]:
    """One view: coloured points, outlines (dotted where hidden) and labels."""
    img, depth = render_points(points, _shaded(labels, normals, camera), camera=camera,
                               point_size=_splat(points, camera), shading=0.0, outline=0.0,
                               return_depth=True)
    colors = id_colors(np.array([p.id for p in primitives], dtype=np.int64))
    for p, c in zip(primitives, colors):
        draw_polylines(img, primitive_wires(p), camera,
                       tuple(int(v * WIRE_SHADE) for v in c), depth)
    taken: list[tuple[int, int, int, int]] = []
    for p, c in sorted(zip(primitives, colors), key=lambda pc: -pc[0].point_count):
        mine = points[labels == p.id]
        anchor = np.nanmedian(mine, axis=0) if len(mine) else p.center
        uv = camera.project(anchor[None])[0]
        if np.isfinite(uv).all():
            _place_label(img, f"{p.id} {p.type}", (uv[0], uv[1]),
                         tuple(int(v) for v in c), taken, scale)
    return img


def _ground(primitives: Sequence[Primitive]) -> tuple[NDArray[np.float64], int | None]:
    """Scene up and the id of the largest plane (its normal towards the sensor).

    Without a plane: the sensor's -y and None.
    """
    planes = [p for p in primitives if p.type == "plane"]
    if not planes:
        return np.array([0.0, -1.0, 0.0]), None
    p = max(planes, key=lambda q: q.point_count)
    n = p.rotation[:, 2]
    return (n if float(n @ p.center) < 0 else -n), p.id


def _oblique_camera(points: NDArray[np.float64], labels: NDArray[np.int64],
                    primitives: Sequence[Primitive], width: int, height: int
                    ) -> PinholeCamera:
    """Camera looking at the objects from :data:`OBLIQUE_ELEVATION` above the ground plane.

    Its line of sight is the sensor's, turned :data:`OBLIQUE_YAW` about the up direction;
    it frames the points of every object but the ground plane (all points if none).
    """
    up, ground = _ground(primitives)
    up = up / np.linalg.norm(up)
    focus = points[(labels >= 0) & (labels != (-2 if ground is None else ground))]
    focus = focus if len(focus) >= 10 else points
    pivot = np.median(focus, axis=0)
    level = pivot - (pivot @ up) * up  # sensor -> pivot, in the ground's directions
    level = level / max(np.linalg.norm(level), 1e-9)
    c, s = math.cos(OBLIQUE_YAW), math.sin(OBLIQUE_YAW)
    level = c * level + s * np.cross(up, level)
    fwd = math.cos(OBLIQUE_ELEVATION) * level - math.sin(OBLIQUE_ELEVATION) * up
    down = -(up - (up @ fwd) * fwd)
    down /= np.linalg.norm(down)
    rot = np.array([np.cross(down, fwd), down, fwd])
    eye = pivot - float(np.linalg.norm(pivot)) * fwd
    return fit_camera(focus, rot, -rot @ eye, width=width, height=height, margin=0.08)


def _in_frame(p: Primitive, rotation: NDArray[np.float64]) -> Primitive:
    """``p`` with its pose turned by ``rotation`` (cloud frame -> optical frame)."""
    from dataclasses import replace

    return replace(p, center=rotation @ p.center, rotation=rotation @ p.rotation)


def _legend(entries: Sequence[tuple[RGB, str]], width: int, scale: int) -> NDArray[np.uint8]:
    """Columns of colour swatches and texts, ``width`` [px] wide."""
    line = _LEGEND_LINE * scale // 2
    col_w = max([text_size(t, scale)[0] for _, t in entries] + [100]) + 12 * scale + 20
    cols = max(1, width // col_w)
    rows = max(1, math.ceil(len(entries) / cols))
    img = np.full((rows * line + 12, width, 3), 255, dtype=np.uint8)
    sw = 7 * scale
    for k, (color, text) in enumerate(entries):
        x, y = 10 + (k // rows) * col_w, 6 + (k % rows) * line
        img[y:y + sw, x:x + sw] = _INK
        img[y + 1:y + sw - 1, x + 1:x + sw - 1] = color
        draw_text(img, text, (x + sw + 6, y), scale, _INK)
    return img


def scene_picture(points, labels, primitives, *, title: str = "", oblique: bool = True,
                  scale: int = 1) -> NDArray[np.uint8]:
    """Picture of a modeled scene: sensor view [+ oblique view], title and legend.

    Parameters
    ----------
    points : (H, W, 3) or (N, 3) float array [m]
        The input cloud; an organized cloud is shown through its own camera
        (:func:`organized_camera`), an unorganized one from the origin, framed.
    labels : (H * W,) or (N,) int array
        Object id per point, -1 = none.
    primitives : sequence of Primitive or ModelingResult
        The reported objects (their ids are the labels').
    title : str
        Line on the title bar.
    oblique : bool
        Add the oblique view (:func:`_oblique_camera`: the sensor's line of sight turned
        :data:`OBLIQUE_YAW` about the largest plane's normal, :data:`OBLIQUE_ELEVATION`
        above that plane, framing the objects) beside the sensor view.
    scale : int
        Text scale, 1-4 (1: 5 x 7 px letters).

    Returns
    -------
    (H', W', 3) uint8 array
        RGB image.

    Raises
    ------
    InputError
        If ``points`` is not (N, 3) / (H, W, 3) or ``labels`` does not match it.
    """
    if not 1 <= int(scale) <= 4:
        raise ValueError(f"scale must be an integer in [1, 4], got {scale!r}")
    prims = list(getattr(primitives, "objects", primitives))
    pts, camera, rot = _sensor_frame(points)
    lab = np.asarray(labels).reshape(-1)
    if len(lab) != len(pts) or (lab.size and lab.dtype.kind not in "iu"):
        raise InputError(f"labels must be {len(pts)} integers like the points, got "
                         f"{lab.dtype} {lab.shape}")
    arr = np.asarray(points)
    normals = _grid_normals(pts, arr.shape[:2] if camera is not None else None)
    fin = np.isfinite(pts).all(axis=1)
    pts, lab, normals = pts[fin] @ rot.T, lab[fin].astype(np.int64), normals[fin] @ rot.T
    prims = [_in_frame(p, rot) for p in prims]
    if camera is None:
        camera = fit_camera(pts, width=640, height=480)
    views = [_view(pts, normals, lab, prims, camera, scale)]
    if oblique and len(pts):
        cam = _oblique_camera(pts, lab, prims, camera.width, camera.height)
        views.append(_view(pts, normals, lab, prims, cam, scale))
    body = np.concatenate([np.pad(v, ((0, 0), (0, 4), (0, 0)), constant_values=255)
                           for v in views], axis=1)[:, :-4]
    ids = np.array([p.id for p in prims], dtype=np.int64)
    entries = [(tuple(int(v) for v in c), legend_label(p))
               for c, p in zip(id_colors(ids), prims)]
    if (lab < 0).any():
        entries.append((NO_OBJECT_RGB, "grey: no object (left out)"))
    bar = np.empty((_TITLE_H, body.shape[1], 3), dtype=np.uint8)
    bar[:] = _TITLE_BG
    big = 2 if text_size(title, 2)[0] <= body.shape[1] - 20 else 1
    draw_text(bar, title, (10, (_TITLE_H - text_size(title, big)[1]) // 2), big, _WHITE)
    return np.concatenate([bar, body, _legend(entries, body.shape[1], scale)], axis=0)


def write_png(path, img: NDArray[np.uint8], downscale: int = 1) -> Path:
    """Write an (H, W, 3) uint8 RGB image as PNG, shrunk by an integer ``downscale``.

    Downscaling averages ``downscale`` x ``downscale`` pixel blocks.
    """
    import open3d as o3d

    out = Path(path)
    if out.suffix.lower() != ".png":
        raise ValueError(f"picture must be written as .png, got {out.name!r}")
    arr = np.asarray(img)
    if arr.ndim != 3 or arr.shape[2] != 3 or arr.dtype != np.uint8:
        raise InputError(f"image must be (H, W, 3) uint8, got {arr.dtype} {arr.shape}")
    k = int(downscale)
    if k > 1:
        h, w = arr.shape[0] // k * k, arr.shape[1] // k * k
        arr = arr[:h, :w].reshape(h // k, k, w // k, k, 3).mean(axis=(1, 3))
        arr = np.round(arr).astype(np.uint8)
    if not o3d.io.write_image(str(out), o3d.geometry.Image(np.ascontiguousarray(arr))):
        raise OSError(f"could not write {out}")
    return out


# ------------------------------------------------------------------------------ command
def _model(path: str, params_file: str | None):
    """Read a cloud file and model it: (points as read, labels (N,), ModelingResult)."""
    from geomodel_ros.core.modeling import model_scene
    from geomodel_ros.core.params import ModelingParams, load_params_file
    from geomodel_ros.tools.io import read_cloud

    cloud = read_cloud(path)
    params = load_params_file(params_file) if params_file else ModelingParams()
    labels, result = model_scene(cloud.points, params)
    points = cloud.organized_points() if cloud.is_organized else cloud.points
    return points, labels, result


def _summary(result) -> str:
    counts: dict[str, int] = {}
    for o in result.objects:
        counts[str(o.type)] = counts.get(str(o.type), 0) + 1
    text = ", ".join(f"{v} {k}" for k, v in sorted(counts.items())) or "no objects"
    return f"{len(result.objects)} objects ({text}), {result.fragments} fragments left out"


def main(argv: Sequence[str] | None = None) -> int:
    """Model a cloud file and write its picture; 0 on success, 2 on a user error."""
    from geomodel_ros.core.params import ParameterError
    from geomodel_ros.tools.io import CloudFileError

    ap = argparse.ArgumentParser(prog="python -m geomodel_ros.tools.picture",
                                 description=__doc__.split("\n\n")[0])
    ap.add_argument("cloud", help="cloud file (.pcd, .ply, .npy)")
    ap.add_argument("--out", required=True, help="picture to write (.png)")
    ap.add_argument("--json", help="also write the modeling result (as `geomodel model`)")
    ap.add_argument("--params", help="parameter YAML (default: the defaults)")
    ap.add_argument("--no-oblique", action="store_true", help="sensor view only")
    ap.add_argument("--downscale", type=int, default=1, choices=(1, 2, 3, 4),
                    help="shrink the picture by this factor (block mean)")
    ap.add_argument("--title", help="title line (default: file name and object counts)")
    args = ap.parse_args(argv)
    try:
        if Path(args.out).suffix.lower() != ".png":
            raise ValueError(f"--out must end in .png, got {args.out!r}")
        points, labels, result = _model(args.cloud, args.params)
        title = args.title or f"{Path(args.cloud).name}: {_summary(result)}"
        img = scene_picture(points, labels, result, title=title, oblique=not args.no_oblique,
                            scale=1 if args.downscale == 1 else 2)
        write_png(args.out, img, args.downscale)
        if args.json:
            Path(args.json).write_text(json.dumps(result.to_dict(), indent=2))
    except (CloudFileError, ParameterError, InputError, ValueError, OSError) as exc:
        print(f"picture: error: {exc}", file=sys.stderr)
        return 2
    print(f"{_summary(result)} -> {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
