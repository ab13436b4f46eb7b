"""Pictures of a modeled scene like the paper's Figures 6-8, with numpy only.

A z-buffered point splatting renderer (:func:`render_points`), virtual cameras that look
at a scene from the sensor's own view or from a rotated one (:func:`sensor_camera`,
:func:`orbit_camera`), a built-in 5 x 7 bitmap font (:func:`draw_text`) and
:func:`render_figures`, which writes the three pictures of a modeled scene:

* ``segments.png`` -- the input coloured by segment (paper Figure 6),
* ``reconstruction.png`` -- every modeled surface sampled in full, hidden parts
  included, seen from a rotated viewpoint (Figure 7),
* ``overlay.png`` -- input (grey) and reconstruction (coloured) together (Figure 8),
* ``summary.png`` -- the three side by side with one legend.

Cameras are :class:`geomodel_ros.tools.synth.camera.PinholeCamera` (the one camera model of
the tools, also the synthetic depth camera): optical frame of REP 103 (x right, y down, z
forward), a pose mapping a scene point ``p`` [m] to ``rotation @ p + translation``. Objects
take the shared colour of their id (:func:`geomodel_ros.core.colors.id_colors`, the same as
in RViz and in the PLY). Images are (H, W, 3) uint8 RGB arrays; PNGs are written through
open3d.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Iterable, Mapping, Sequence

import numpy as np
from numpy.typing import NDArray

from geomodel_ros.core.colors import NO_OBJECT_RGB, id_colors
from geomodel_ros.core.errors import InputError, as_points
from geomodel_ros.core.faces import estimate_normals
from geomodel_ros.core.primitives import Primitive
from geomodel_ros.tools.synth.camera import PinholeCamera

__all__ = [
    "sensor_camera",
    "fit_camera",
    "orbit_camera",
    "render_points",
    "primitive_normals",
    "text_size",
    "draw_text",
    "legend_label",
    "render_figures",
    "INPUT_GREY",
]

RGB = tuple[int, int, int]

#: Input points in the overlay picture.
INPUT_GREY: RGB = (185, 185, 185)

_TITLE_BG: RGB = (38, 44, 56)
_WHITE: RGB = (255, 255, 255)
_INK: RGB = (25, 25, 25)
_MUTED_INK: RGB = (110, 110, 110)


# --------------------------------------------------------------------------- cameras
def _rotate(points: NDArray[np.float64], rotation: NDArray[np.float64]) -> NDArray[np.float64]:
    """``points @ rotation.T`` (a contiguous right operand is much faster in numpy)."""
    return points @ np.ascontiguousarray(rotation.T)


def _as_camera(camera) -> PinholeCamera:
    if isinstance(camera, PinholeCamera):
        return camera
    if isinstance(camera, Mapping):
        return PinholeCamera(*(camera[k] for k in ("fx", "fy", "cx", "cy", "width", "height")))
    try:
        values = tuple(camera)
    except TypeError:
        values = ()
    if len(values) != 6:
        raise ValueError("camera must be a PinholeCamera, an intrinsics dict or a tuple "
                         f"(fx, fy, cx, cy, width, height), got {camera!r}")
    return PinholeCamera(*values)


def sensor_camera(intrinsics, width: int, height: int) -> PinholeCamera:
    """Return the sensor's own view scaled to fit in ``width`` x ``height`` [px].

    Parameters
    ----------
    intrinsics : dict, PinholeCamera or tuple
        ``fx, fy, cx, cy`` [px] and ``width, height`` [px] of the sensor.
    width, height : int
        Largest image size [px]; the aspect ratio of the sensor is kept.
    """
    cam = _as_camera(intrinsics)
    return cam.scaled(min(width / cam.width, height / cam.height))


def fit_camera(points, rotation=None, translation=None, *, width: int, height: int,
               margin: float = 0.03) -> PinholeCamera:
    """Camera with the given pose whose intrinsics frame all ``points``.

    Parameters
    ----------
    points : (N, 3) float array [m]
        Points to frame (non-finite rows and points behind the camera are ignored).
    rotation : (3, 3) array, optional
        Scene -> optical frame (identity: the sensor's orientation).
    translation : (3,) array [m], optional
    width, height : int
        Image size [px].
    margin : float
        Free border as a fraction of the image size, in [0, 0.45].

    Returns
    -------
    PinholeCamera
        Square pixels (``fx == fy``), the points' projection centred in the image.
    """
    if not 0.0 <= margin <= 0.45:
        raise ValueError(f"margin must be in [0, 0.45], got {margin!r}")
    r = np.eye(3) if rotation is None else np.asarray(rotation, dtype=np.float64)
    t = np.zeros(3) if translation is None else np.asarray(translation, dtype=np.float64)
    q = _rotate(as_points(points), r) + t
    q = q[np.isfinite(q).all(axis=1) & (q[:, 2] > 1e-6)]
    if len(q) == 0:
        return PinholeCamera(width, width, (width - 1) / 2, (height - 1) / 2, width, height, r, t)
    a, b = q[:, 0] / q[:, 2], q[:, 1] / q[:, 2]
    a0, a1, b0, b1 = a.min(), a.max(), b.min(), b.max()
    f = min(width * (1 - 2 * margin) / max(a1 - a0, 1e-9),
            height * (1 - 2 * margin) / max(b1 - b0, 1e-9))
    f = min(f, 1e6)
    cx = (width - 1) / 2 - f * (a0 + a1) / 2
    cy = (height - 1) / 2 - f * (b0 + b1) / 2
    return PinholeCamera(f, f, cx, cy, width, height, r, t)


def _axis_angle(axis: NDArray[np.float64], angle: float) -> NDArray[np.float64]:
    k = axis / np.linalg.norm(axis)
    kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + math.sin(angle) * kx + (1 - math.cos(angle)) * kx @ kx


def orbit_camera(points, *, yaw: float = math.radians(40), pitch: float = math.radians(15),
                 up=None, pivot=None, width: int, height: int, margin: float = 0.03
                 ) -> PinholeCamera:
    """Make a camera that sees the scene turned about its centre, framing all ``points``.

    The scene is turned by ``yaw`` about ``up`` and then by ``pitch`` about the sensor's
    x axis (positive: look more from above), both through ``pivot``, and seen from the
    sensor's position, so the sides and backs the sensor missed come into view.

    Parameters
    ----------
    points : (N, 3) float array [m]
        Scene points in the sensor frame (also the points to frame).
    yaw, pitch : float [rad]
    up : (3,) array, optional
        Scene up direction in the sensor frame, e.g. the support plane's normal
        (default: the sensor's -y).
    pivot : (3,) array [m], optional
        Centre of rotation (default: the middle of the points' bounding box).
    width, height : int
        Image size [px].
    margin : float
        Free border as a fraction of the image size.
    """
    pts = as_points(points)
    pts = pts[np.isfinite(pts).all(axis=1)]
    if pivot is None:
        pivot = (0.5 * (pts.min(axis=0) + pts.max(axis=0)) if len(pts)
                 else np.array([0.0, 0.0, 1.0]))
    pivot = np.asarray(pivot, dtype=np.float64)
    up = np.array([0.0, -1.0, 0.0]) if up is None else np.asarray(up, dtype=np.float64)
    if up.shape != (3,) or not np.linalg.norm(up) > 0:
        raise ValueError(f"up must be a non-zero (3,) vector, got {up!r}")
    rot = _axis_angle(np.array([1.0, 0.0, 0.0]), -pitch) @ _axis_angle(up, yaw)
    t = pivot - rot @ pivot
    if len(pts):  # keep everything well in front of the camera
        near = (_rotate(pts, rot) + t)[:, 2].min()
        floor = 0.25 * max(float(np.linalg.norm(pivot)), 1e-3)
        if near < floor:
            t = t + np.array([0.0, 0.0, floor - near])
    return fit_camera(pts, rot, t, width=width, height=height, margin=margin)


# --------------------------------------------------------------------------- renderer
def _splat_offsets(point_size: int) -> NDArray[np.int64]:
    lo = -((point_size - 1) // 2)
    d = np.arange(lo, lo + point_size)
    dx, dy = np.meshgrid(d, d)
    off = np.stack([dx.ravel(), dy.ravel()], axis=1)
    if point_size >= 4:  # round splats
        c = (point_size - 1) / 2 + lo
        off = off[((off - c) ** 2).sum(axis=1) <= (point_size / 2) ** 2 + 0.25]
    return off


def _rasterize(q: NDArray[np.float64], camera: PinholeCamera, point_size: int
               ) -> tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.float64]]:
    """Z-buffer of camera-frame points: (pixel index, point index) of the winners, depth."""
    w, h = camera.width, camera.height
    depth = np.full(w * h, np.inf)
    z = q[:, 2]
    ok = np.isfinite(q).all(axis=1) & (z > 1e-6)
    idx = np.flatnonzero(ok)
    u, v = camera.project_camera_frame(q[idx]).T
    near = (np.abs(u) < 4 * (w + h)) & (np.abs(v) < 4 * (w + h))
    idx, u, v = idx[near], u[near], v[near]
    off = _splat_offsets(point_size)
    col = (np.rint(u).astype(np.int64)[:, None] + off[:, 0]).ravel()
    row = (np.rint(v).astype(np.int64)[:, None] + off[:, 1]).ravel()
    src = np.repeat(idx, len(off))
    inside = (col >= 0) & (col < w) & (row >= 0) & (row < h)
    lin, src = row[inside] * w + col[inside], src[inside]
    zz = z[src]
    np.minimum.at(depth, lin, zz)
    win = zz == depth[lin]
    return lin[win], src[win], depth


#: Relative depth step below which no outline is drawn (smooth, slanted surfaces).
_EDGE_STEP = 0.006


def _outline(img: NDArray[np.uint8], depth: NDArray[np.float64], strength: float) -> None:
    """Darken pixels just behind a nearer neighbour (eye-dome lighting), in place.

    Steps in log depth below :data:`_EDGE_STEP` are ignored, so only depth edges get a rim.
    """
    if strength <= 0:
        return
    valid = np.isfinite(depth)
    logd = np.log(np.where(valid, depth, 1.0))
    pad = np.pad(np.where(valid, logd, np.inf), 2, constant_values=np.inf)
    h_img, w_img = depth.shape
    acc = np.zeros_like(depth)
    for dy, dx in ((0, 2), (0, -2), (2, 0), (-2, 0), (0, 1), (0, -1), (1, 0), (-1, 0)):
        nb = pad[2 + dy:2 + dy + h_img, 2 + dx:2 + dx + w_img]
        acc += np.clip(logd - nb - _EDGE_STEP, 0.0, 0.05)
    shade = np.where(valid, np.maximum(np.exp(-strength * 60.0 * acc), 0.3), 1.0)
    img[:] = np.clip(img * shade[..., None], 0, 255).astype(np.uint8)


def _shade_factor(q: NDArray[np.float64], normals_cam: NDArray[np.float64] | None,
                  shading: float) -> NDArray[np.float64]:
    """Brightness in (0, 1] of camera-frame points: headlight on normals, then depth."""
    f = np.ones(len(q))
    if normals_cam is not None:
        light = np.array([-0.35, -0.55, -1.0])
        light /= np.linalg.norm(light)
        n = normals_cam / np.maximum(np.linalg.norm(normals_cam, axis=1, keepdims=True), 1e-12)
        f = 0.42 + 0.58 * np.abs(n @ light)
    if shading > 0 and len(q):
        z = q[:, 2]
        z0, z1 = np.percentile(z, (1, 99))
        f = f * (1.0 - shading * np.clip((z - z0) / max(z1 - z0, 1e-9), 0.0, 1.0))
    return f


def _fill_holes(col: NDArray[np.float64], depth: NDArray[np.float64]) -> None:
    """Close small holes (up to 2 x 2 px) of a splatted surface in place.

    A pixel (empty or farther) with at least 5 of its 8 neighbours nearer by more than
    :data:`_EDGE_STEP` shows something through a gap between splats: it takes the mean
    colour and depth of those neighbours. Two passes.
    """
    for _ in range(2):
        _fill_pass(col, depth)


def _fill_pass(col: NDArray[np.float64], depth: NDArray[np.float64]) -> None:
    h, w = depth.shape
    pd = np.pad(depth, 1, constant_values=np.inf)
    offsets = [(dy, dx) for dy in (-1, 0, 1) for dx in (-1, 0, 1) if dy or dx]
    nearest = np.full((h, w), np.inf)
    for dy, dx in offsets:
        np.minimum(nearest, pd[1 + dy:1 + dy + h, 1 + dx:1 + dx + w], out=nearest)
    limit = depth * (1.0 - _EDGE_STEP)  # inf for empty pixels
    cand = np.flatnonzero(nearest < limit)  # pixels with at least one nearer neighbour
    if len(cand) == 0:
        return
    r, c = np.divmod(cand, w)
    dy, dx = np.array(offsets).T
    rr, cc = r[:, None] + 1 + dy, c[:, None] + 1 + dx  # (m, 8) in padded coordinates
    nd = pd[rr, cc]
    nearer = nd < limit.ravel()[cand][:, None]
    count = nearer.sum(axis=1)
    hole = count >= 5
    if not hole.any():
        return
    nearer, nd, rr, cc, count = nearer[hole], nd[hole], rr[hole] - 1, cc[hole] - 1, count[hole]
    inside = nearer & (rr >= 0) & (rr < h) & (cc >= 0) & (cc < w)  # nearer implies inside
    nc = col[np.clip(rr, 0, h - 1), np.clip(cc, 0, w - 1)]  # (k, 8, 3)
    flat_d, flat_c = depth.reshape(-1), col.reshape(-1, 3)
    flat_d[cand[hole]] = np.where(inside, nd, 0.0).sum(axis=1) / count
    flat_c[cand[hole]] = (nc * inside[..., None]).sum(axis=1) / count[:, None]


def _render_layer(points, colors, camera: PinholeCamera, point_size: int, normals, shading: float
                  ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Shaded colour (H, W, 3) float64 and depth (H, W) [m] images of one cloud.

    Pixels without a point have depth ``inf`` (and colour 0).
    """
    pts = as_points(points)
    cols = np.asarray(colors)
    if cols.shape == (3,):
        cols = np.broadcast_to(cols, pts.shape)
    if cols.shape != pts.shape:
        raise InputError(f"colors must be (3,) or ({len(pts)}, 3) like points, got {cols.shape}")
    if not (isinstance(point_size, (int, np.integer)) and 1 <= point_size <= 9):
        raise ValueError(f"point_size must be an integer in [1, 9] [px], got {point_size!r}")
    if not 0.0 <= shading <= 1.0:
        raise ValueError(f"shading must be in [0, 1], got {shading!r}")
    q = camera.to_camera_frame(pts)
    lin, src, depth = _rasterize(q, camera, int(point_size))
    n_cam = None
    if normals is not None:
        nrm = as_points(normals)
        if nrm.shape != pts.shape:
            raise InputError(f"normals must be ({len(pts)}, 3) like points, got {nrm.shape}")
        n_cam = _rotate(nrm[src], camera.rotation)
    f = _shade_factor(q[src], n_cam, shading)
    col = np.zeros((camera.height * camera.width, 3))
    col[lin] = cols[src] * f[:, None]
    col = col.reshape(camera.height, camera.width, 3)
    depth = depth.reshape(camera.height, camera.width)
    _fill_holes(col, depth)
    return col, depth


def _check_background(background) -> NDArray[np.uint8]:
    bg = np.asarray(background)
    if bg.shape != (3,) or not np.all((bg >= 0) & (bg <= 255)):
        raise ValueError(f"background must be 3 values in [0, 255], got {background!r}")
    return bg.astype(np.uint8)


def render_points(points, colors, *, camera, point_size: int = 2,
                  background=(255, 255, 255), normals=None, shading: float = 0.35,
                  outline: float = 1.0, return_depth: bool = False):
    """Splat a coloured point cloud into an image with a z-buffer.

    Every point covers ``point_size`` x ``point_size`` pixels; per pixel the point nearest
    the camera wins.

    Parameters
    ----------
    points : (N, 3) float array [m]
        Non-finite rows and points behind the camera are skipped.
    colors : (N, 3) or (3,) uint8 array
        RGB per point (or one for all).
    camera : PinholeCamera, intrinsics dict or (fx, fy, cx, cy, width, height)
        A plain intrinsics tuple means the sensor's pose (identity).
    point_size : int
        Splat size [px], 1-9.
    background : 3 ints in [0, 255]
    normals : (N, 3) float array, optional
        Surface normals (either orientation): light from above-left of the viewer.
    shading : float
        Darkening from the nearest to the farthest points, in [0, 1].
    outline : float
        Strength of the dark rim drawn behind depth edges (0 = none).
    return_depth : bool
        Also return the depth image.

    Returns
    -------
    image : (H, W, 3) uint8 array
    depth : (H, W) float64 array [m], only with ``return_depth``
        Optical-frame z of the visible point per pixel, ``inf`` where none.
    """
    cam = _as_camera(camera)
    bg = _check_background(background)
    col, depth = _render_layer(points, colors, cam, point_size, normals, shading)
    img = np.where(np.isfinite(depth)[..., None], col, bg.astype(np.float64))
    img = np.clip(img, 0, 255).astype(np.uint8)
    _outline(img, depth, outline)
    return (img, depth) if return_depth else img


def _render_overlay(under, under_color, over, over_colors, camera: PinholeCamera, under_size: int,
                    over_size: int, under_normals, over_normals, background
                    ) -> NDArray[np.uint8]:
    """Two clouds in one picture; where both show the same surface their colours mix."""
    bg = _check_background(background)
    col_a, dep_a = _render_layer(under, under_color, camera, under_size, under_normals, 0.2)
    col_b, dep_b = _render_layer(over, over_colors, camera, over_size, over_normals, 0.2)
    img = np.empty(col_a.shape)
    img[:] = bg
    has_a, has_b = np.isfinite(dep_a), np.isfinite(dep_b)
    same = has_a & has_b
    same[same] = np.abs(dep_a[same] - dep_b[same]) <= 0.008 * dep_a[same]
    a_front = has_a & ~same & (dep_a < dep_b)
    b_front = has_b & ~same & ~a_front
    img[a_front] = col_a[a_front]
    img[b_front] = col_b[b_front]
    img[same] = 0.7 * col_a[same] + 0.3 * col_b[same]
    out = np.clip(img, 0, 255).astype(np.uint8)
    _outline(out, np.minimum(dep_a, dep_b), 1.0)
    return out


def primitive_normals(points, ids, primitives: Iterable[Primitive]) -> NDArray[np.float64]:
    """Exact surface normals of reconstruction samples.

    Parameters
    ----------
    points : (N, 3) float array [m]
        Samples of :func:`geomodel_ros.core.reconstruction.reconstruct`.
    ids : (N,) int array
        Object id of every sample.
    primitives : iterable of Primitive

    Returns
    -------
    (N, 3) float64 array
        Unit normals (outward for closed shapes); zero for ids without a primitive.
    """
    pts = as_points(points)
    ids = np.asarray(ids).reshape(-1)
    if len(ids) != len(pts):
        raise InputError(f"ids must have {len(pts)} entries like points, got {len(ids)}")
    out = np.zeros_like(pts)
    for p in primitives:
        m = ids == p.id
        if not m.any() or p.type == "unknown":
            continue
        q = (pts[m] - p.center) @ np.ascontiguousarray(p.rotation)  # local coordinates
        d = p.dimensions
        if p.type == "plane":
            nl = np.tile([0.0, 0.0, 1.0], (len(q), 1))
        elif p.type == "sphere":
            nl = q
        elif p.type == "cuboid":
            half = np.array([d["length"], d["width"], d["height"]]) / 2
            k = np.argmax(np.abs(q) / np.maximum(half, 1e-12), axis=1)
            nl = np.zeros_like(q)
            nl[np.arange(len(q)), k] = np.sign(q[np.arange(len(q)), k])
        else:  # cylinder, cone, frustum
            r, hgt = d["radius"], d["height"]
            rr = np.hypot(q[:, 0], q[:, 1])
            radial = q[:, :2] / np.maximum(rr, 1e-12)[:, None]
            eps = 1e-9 + 1e-6 * max(r, hgt)
            if p.type == "cylinder":
                nl = np.c_[radial, np.zeros(len(q))]
                cap = (np.abs(np.abs(q[:, 2]) - hgt / 2) < eps) & (rr < r - eps)
                nl[cap] = np.c_[np.zeros((cap.sum(), 2)), np.sign(q[cap, 2])]
            else:
                top = d.get("top_radius", 0.0)  # a frustum's top circle; a cone's apex
                nl = np.c_[hgt * radial, np.full(len(q), r - top)]
                base = (q[:, 2] + hgt / 2 < eps) & (rr < r - eps)
                nl[base] = [0.0, 0.0, -1.0]
                lid = (hgt / 2 - q[:, 2] < eps) & (rr < top - eps)
                nl[lid] = [0.0, 0.0, 1.0]
        nl = nl / np.maximum(np.linalg.norm(nl, axis=1, keepdims=True), 1e-12)
        out[m] = _rotate(nl, p.rotation)
    return out


# --------------------------------------------------------------------------- font
#: 5 x 7 glyphs of ASCII 32-126, one string per character: 7 rows of 5 pixels, plus two
#: rows below the baseline for descenders (g j p q y ,).
_GLYPH_ROWS = (
    "..... ..... ..... ..... ..... ..... .....",  # space
    "..#.. ..#.. ..#.. ..#.. ..#.. ..... ..#..",  # !
    ".#.#. .#.#. ..... ..... ..... ..... .....",  # "
    ".#.#. .#.#. ##### .#.#. ##### .#.#. .#.#.",  # #
    "..#.. .#### #.#.. .###. ..#.# ####. ..#..",  # $
    "##... ##..# ...#. ..#.. .#... #..## ...##",  # %
    ".##.. #..#. #.#.. .#... #.#.# #..#. .##.#",  # &
    "..#.. ..#.. ..... ..... ..... ..... .....",  # '
    "...#. ..#.. .#... .#... .#... ..#.. ...#.",  # (
    ".#... ..#.. ...#. ...#. ...#. ..#.. .#...",  # )
    "..... ..#.. #.#.# .###. #.#.# ..#.. .....",  # *
    "..... ..#.. ..#.. ##### ..#.. ..#.. .....",  # +
    "..... ..... ..... ..... ..... .##.. .##.. ..#.. .#...",  # ,
    "..... ..... ..... ##### ..... ..... .....",  # -
    "..... ..... ..... ..... ..... .##.. .##..",  # .
    "..... ....# ...#. ..#.. .#... #.... .....",  # /
    ".###. #...# #..## #.#.# ##..# #...# .###.",  # 0
    "..#.. .##.. ..#.. ..#.. ..#.. ..#.. .###.",  # 1
    ".###. #...# ....# ...#. ..#.. .#... #####",  # 2
    "##### ...#. ..#.. ...#. ....# #...# .###.",  # 3
    "...#. ..##. .#.#. #..#. ##### ...#. ...#.",  # 4
    "##### #.... ####. ....# ....# #...# .###.",  # 5
    "..##. .#... #.... ####. #...# #...# .###.",  # 6
    "##### ....# ...#. ..#.. .#... .#... .#...",  # 7
    ".###. #...# #...# .###. #...# #...# .###.",  # 8
    ".###. #...# #...# .#### ....# ...#. .##..",  # 9
    "..... .##.. .##.. ..... .##.. .##.. .....",  # :
    "..... .##.. .##.. ..... .##.. ..#.. .#...",  # ;
    "...#. ..#.. .#... #.... .#... ..#.. ...#.",  # <
    "..... ..... ##### ..... ##### ..... .....",  # =
    ".#... ..#.. ...#. ....# ...#. ..#.. .#...",  # >
    ".###. #...# ....# ...#. ..#.. ..... ..#..",  # ?
    ".###. #...# ....# .##.# #.#.# #.#.# .###.",  # @
    ".###. #...# #...# ##### #...# #...# #...#",  # A
    "####. #...# #...# ####. #...# #...# ####.",  # B
    ".###. #...# #.... #.... #.... #...# .###.",  # C
    "###.. #..#. #...# #...# #...# #..#. ###..",  # D
    "##### #.... #.... ####. #.... #.... #####",  # E
    "##### #.... #.... ####. #.... #.... #....",  # F
    ".###. #...# #.... #.### #...# #...# .####",  # G
    "#...# #...# #...# ##### #...# #...# #...#",  # H
    ".###. ..#.. ..#.. ..#.. ..#.. ..#.. .###.",  # I
    "..### ...#. ...#. ...#. ...#. #..#. .##..",  # J
    "#...# #..#. #.#.. ##... #.#.. #..#. #...#",  # K
    "#.... #.... #.... #.... #.... #.... #####",  # L
    "#...# ##.## #.#.# #.#.# #...# #...# #...#",  # M
    "#...# #...# ##..# #.#.# #..## #...# #...#",  # N
    ".###. #...# #...# #...# #...# #...# .###.",  # O
    "####. #...# #...# ####. #.... #.... #....",  # P
    ".###. #...# #...# #...# #.#.# #..#. .##.#",  # Q
    "####. #...# #...# ####. #.#.. #..#. #...#",  # R
    ".#### #.... #.... .###. ....# ....# ####.",  # S
    "##### ..#.. ..#.. ..#.. ..#.. ..#.. ..#..",  # T
    "#...# #...# #...# #...# #...# #...# .###.",  # U
    "#...# #...# #...# #...# #...# .#.#. ..#..",  # V
    "#...# #...# #...# #.#.# #.#.# #.#.# .#.#.",  # W
    "#...# #...# .#.#. ..#.. .#.#. #...# #...#",  # X
    "#...# #...# .#.#. ..#.. ..#.. ..#.. ..#..",  # Y
    "##### ....# ...#. ..#.. .#... #.... #####",  # Z
    ".###. .#... .#... .#... .#... .#... .###.",  # [
    "..... #.... .#... ..#.. ...#. ....# .....",  # backslash
    ".###. ...#. ...#. ...#. ...#. ...#. .###.",  # ]
    "..#.. .#.#. #...# ..... ..... ..... .....",  # ^
    "..... ..... ..... ..... ..... ..... #####",  # _
    ".#... ..#.. ..... ..... ..... ..... .....",  # `
    "..... ..... .###. ....# .#### #...# .####",  # a
    "#.... #.... #.##. ##..# #...# #...# ####.",  # b
    "..... ..... .###. #.... #.... #...# .###.",  # c
    "....# ....# .##.# #..## #...# #...# .####",  # d
    "..... ..... .###. #...# ##### #.... .###.",  # e
    "..##. .#..# .#... ###.. .#... .#... .#...",  # f
    "..... ..... .#### #...# #...# #...# .#### ....# .###.",  # g
    "#.... #.... #.##. ##..# #...# #...# #...#",  # h
    "..#.. ..... .##.. ..#.. ..#.. ..#.. .###.",  # i
    "...#. ..... ..##. ...#. ...#. ...#. ...#. #..#. .##..",  # j
    "#.... #.... #..#. #.#.. ##... #.#.. #..#.",  # k
    ".##.. ..#.. ..#.. ..#.. ..#.. ..#.. .###.",  # l
    "..... ..... ##.#. #.#.# #.#.# #...# #...#",  # m
    "..... ..... #.##. ##..# #...# #...# #...#",  # n
    "..... ..... .###. #...# #...# #...# .###.",  # o
    "..... ..... ####. #...# #...# #...# ####. #.... #....",  # p
    "..... ..... .#### #...# #...# #...# .#### ....# ....#",  # q
    "..... ..... #.##. ##..# #.... #.... #....",  # r
    "..... ..... .###. #.... .###. ....# ####.",  # s
    ".#... .#... ###.. .#... .#... .#..# ..##.",  # t
    "..... ..... #...# #...# #...# #..## .##.#",  # u
    "..... ..... #...# #...# #...# .#.#. ..#..",  # v
    "..... ..... #...# #...# #.#.# #.#.# .#.#.",  # w
    "..... ..... #...# .#.#. ..#.. .#.#. #...#",  # x
    "..... ..... #...# #...# #...# #...# .#### ....# .###.",  # y
    "..... ..... ##### ...#. ..#.. .#... #####",  # z
    "...#. ..#.. ..#.. .#... ..#.. ..#.. ...#.",  # {
    "..#.. ..#.. ..#.. ..#.. ..#.. ..#.. ..#..",  # |
    ".#... ..#.. ..#.. ...#. ..#.. ..#.. .#...",  # }
    "..... ..... .#... #.#.# ...#. ..... .....",  # ~
)
#: Font cell [font px]: glyph columns + 1 of spacing, rows + descenders + 1 of spacing.
_CELL_W, _CELL_H = 6, 10
#: (95, 10, 6) bool glyph masks.
_GLYPHS = np.zeros((len(_GLYPH_ROWS), _CELL_H, _CELL_W), dtype=bool)
for _i, _g in enumerate(_GLYPH_ROWS):
    _rows = np.array([[c == "#" for c in row] for row in _g.split()])
    _GLYPHS[_i, :len(_rows), :5] = _rows
del _rows
del _i, _g
assert _GLYPHS.shape[0] == 95  # ASCII 32-126


def _glyph_index(text: str) -> NDArray[np.int64]:
    codes = np.frombuffer(text.encode("ascii", "replace"), dtype=np.uint8).astype(np.int64)
    codes[(codes < 32) | (codes > 126)] = ord("?")
    return codes - 32


def text_size(text: str, scale: int = 2) -> tuple[int, int]:
    """(width, height) [px] of one line of ``text`` drawn by :func:`draw_text`."""
    return _CELL_W * scale * len(text), _CELL_H * scale


def draw_text(img: NDArray[np.uint8], text: str, xy: tuple[int, int], scale: int = 2,
              color=(0, 0, 0)) -> tuple[int, int, int, int]:
    """Draw one line of ``text`` into ``img`` in place with the built-in 5 x 7 font.

    Parameters
    ----------
    img : (H, W, 3) uint8 array
    text : str
        Characters outside ASCII 32-126 are drawn as ``?``.
    xy : (int, int)
        Top-left corner (column, row) [px]; text outside the image is clipped.
    scale : int
        Pixels per font pixel, 1-16; a character cell is 6 x 10 font pixels.
    color : 3 ints in [0, 255]

    Returns
    -------
    (x0, y0, x1, y1)
        The text box in image coordinates (end exclusive, before clipping).
    """
    if not (isinstance(scale, (int, np.integer)) and 1 <= scale <= 16):
        raise ValueError(f"scale must be an integer in [1, 16], got {scale!r}")
    if img.ndim != 3 or img.shape[2] != 3 or img.dtype != np.uint8:
        raise InputError(f"img must be an (H, W, 3) uint8 array, got {img.shape} {img.dtype}")
    x, y = int(xy[0]), int(xy[1])
    w, h = text_size(text, scale)
    if not text:
        return x, y, x, y
    mask = _GLYPHS[_glyph_index(text)]  # (n, 10, 6)
    mask = mask.transpose(1, 0, 2).reshape(_CELL_H, -1)
    mask = np.repeat(np.repeat(mask, scale, axis=0), scale, axis=1)
    x0, y0 = max(x, 0), max(y, 0)
    x1, y1 = min(x + w, img.shape[1]), min(y + h, img.shape[0])
    if x1 > x0 and y1 > y0:
        sub = mask[y0 - y:y1 - y, x0 - x:x1 - x]
        img[y0:y1, x0:x1][sub] = np.asarray(color, dtype=np.uint8)
    return x, y, x + w, y + h


# --------------------------------------------------------------------------- figures
def _mm(v: float) -> str:
    s = f"{v * 1000:.1f}"
    return s[:-2] if s.endswith(".0") else s


def legend_label(p: Primitive) -> str:
    """``"id type size"`` with the main sizes in mm, e.g. ``"3 cylinder r50 h60 mm"``.

    Planes and cuboids give length x width (x height), cylinders and cones radius and
    height, frustums radius, top radius and height, spheres the radius.
    """
    d = p.dimensions
    if p.type in ("plane", "cuboid"):
        size = "x".join(_mm(d[k]) for k in ("length", "width", "height") if k in d) + " mm"
    elif p.type in ("cylinder", "cone"):
        size = f"r{_mm(d['radius'])} h{_mm(d['height'])} mm"
    elif p.type == "frustum":
        size = f"r{_mm(d['radius'])} t{_mm(d['top_radius'])} h{_mm(d['height'])} mm"
    elif p.type == "sphere":
        size = f"r{_mm(d['radius'])} mm"
    else:
        size = "(not modeled)"
    return f"{p.id} {p.type} {size}"


def _blank(width: int, height: int, color: RGB = _WHITE) -> NDArray[np.uint8]:
    img = np.empty((height, width, 3), dtype=np.uint8)
    img[:] = color
    return img


def _fit(text: str, width: int, scale: int) -> str:
    """``text`` cut to at most ``width`` [px] at ``scale`` (ending in ``..`` when cut)."""
    n = max(0, width // (_CELL_W * scale))
    return text if len(text) <= n else text[:max(n - 2, 0)] + ".."


def _title_bar(img: NDArray[np.uint8], title: str, subtitle: str, height: int,
               scale: int) -> None:
    """Dark bar of ``height`` [px] on top: title at ``scale + 1``, subtitle at ``scale``."""
    img[:height] = _TITLE_BG
    w = img.shape[1] - 28
    draw_text(img, _fit(title, w, scale + 1), (14, 10), scale + 1, _WHITE)
    if subtitle:
        draw_text(img, _fit(subtitle, w, scale), (14, 10 + 7 * (scale + 1) + 9), scale,
                  (205, 210, 220))


def _legend(img: NDArray[np.uint8], entries: Sequence[tuple[RGB, str]],
            box: tuple[int, int, int, int], header: str, scale: int = 2) -> None:
    """Colour swatch + text per entry, in ``box = (x0, y0, x1, y1)`` [px]."""
    x0, y0, x1, y1 = box
    line = _CELL_H * scale + 6
    draw_text(img, header, (x0, y0), scale, _MUTED_INK)
    img[y0 + 9 * scale:y0 + 9 * scale + 2, x0:x1] = _MUTED_INK
    y = y0 + line + 6
    room = max(0, (y1 - y) // line)
    shown = entries if len(entries) <= room else entries[:max(room - 1, 0)]
    sw = 7 * scale  # swatch as high as a capital letter
    for color, text in shown:
        img[y - 1:y + sw + 1, x0 - 1:x0 + sw + 1] = _MUTED_INK
        img[y:y + sw, x0:x0 + sw] = color
        draw_text(img, _fit(text, x1 - x0 - sw - 8, scale), (x0 + sw + 8, y), scale, _INK)
        y += line
    if len(shown) < len(entries):
        draw_text(img, f"... {len(entries) - len(shown)} more", (x0, y), scale, _MUTED_INK)


def _paste(canvas: NDArray[np.uint8], img: NDArray[np.uint8], box: tuple[int, int, int, int]
           ) -> None:
    """Centre ``img`` in ``box = (x0, y0, x1, y1)`` of ``canvas``."""
    x0, y0, x1, y1 = box
    h, w = img.shape[:2]
    ox, oy = x0 + max(0, (x1 - x0 - w) // 2), y0 + max(0, (y1 - y0 - h) // 2)
    h, w = min(h, y1 - oy), min(w, x1 - ox)
    canvas[oy:oy + h, ox:ox + w] = img[:h, :w]


def _write_png(path: Path, img: NDArray[np.uint8]) -> Path:
    import open3d as o3d

    if not o3d.io.write_image(str(path), o3d.geometry.Image(np.ascontiguousarray(img))):
        raise OSError(f"could not write {path}")
    return path


#: Shading normals are estimated on at most this many points (a fixed subsample); the
#: others take the normal of their nearest subsample point. Bounds the time on large clouds
#: (a full 1104 x 624 synthetic frame has ~370k valid points and is estimated whole).
_MAX_NORMAL_POINTS = 500_000
#: Neighbours per shading normal: a stable plane through sensor noise, still local enough
#: to keep the edges of small objects.
_NORMAL_NEIGHBORS = 12


def _shading_normals(points: NDArray[np.float64]) -> NDArray[np.float64]:
    """(N, 3) unit normals of ``points`` (N, 3) [m] for shading (either orientation).

    The core's estimator (:func:`geomodel_ros.core.faces.estimate_normals`) on at most
    :data:`_MAX_NORMAL_POINTS` points.
    """
    from scipy.spatial import cKDTree

    sub = points
    if len(points) > _MAX_NORMAL_POINTS:
        sub = points[np.random.default_rng(0).choice(len(points), _MAX_NORMAL_POINTS,
                                                     replace=False)]
    normals = estimate_normals(sub, _NORMAL_NEIGHBORS)[0]
    if sub is points:
        return normals
    return normals[cKDTree(sub).query(points, workers=-1)[1]]


def _splat_size(points: NDArray[np.float64], camera: PinholeCamera, minimum: int) -> int:
    """Splat size [px] that closes the gaps between neighbouring ``points`` in ``camera``.

    The points' spacing is the median nearest-neighbour distance of a fixed sample.
    """
    from scipy.spatial import cKDTree

    if len(points) < 2:
        return minimum
    sample = points[np.random.default_rng(0).choice(len(points), min(len(points), 2000),
                                                    replace=False)]
    spacing = float(np.median(cKDTree(points).query(sample, k=2)[0][:, 1]))
    z = camera.to_camera_frame(sample)[:, 2]
    z = z[z > 0]
    if not len(z) or spacing <= 0:
        return minimum
    px = 1.3 * spacing * camera.fx / float(np.median(z))
    return int(np.clip(math.ceil(px), minimum, 9))


def _up_vector(primitives: Sequence[Primitive]) -> NDArray[np.float64]:
    """Return the largest plane's normal pointing to the sensor's up (-y), else -y."""
    planes = [p for p in primitives if p.type == "plane"]
    if not planes:
        return np.array([0.0, -1.0, 0.0])
    p = max(planes, key=lambda p: p.point_count)
    n = p.rotation[:, 2]
    return -n if n[1] > 0 else n


@dataclass(frozen=True)
class _Figure:
    """What the pictures of one scene show, in the sensor frame.

    Attributes
    ----------
    points, labels, rgb, normals : (N, 3), (N,), (N, 3) uint8, (N, 3) or None
        Finite input points [m], their object ids, id colours and shading normals.
    rec, rec_rgb, rec_normals : (n, 3), (n, 3) uint8, (n, 3)
        Reconstruction samples [m] at about one pixel, their colours and exact normals.
    framing : (N + m, 3)
        Input and coarse reconstruction: what the turned views frame.
    pivot, up : (3,) or None, (3,)
        Centre and up direction of the turned views.
    primitives : list of Primitive
    """

    points: NDArray[np.float64]
    labels: NDArray[np.int64]
    rgb: NDArray[np.uint8]
    normals: NDArray[np.float64] | None
    rec: NDArray[np.float64]
    rec_rgb: NDArray[np.uint8]
    rec_normals: NDArray[np.float64]
    framing: NDArray[np.float64]
    pivot: NDArray[np.float64] | None
    up: NDArray[np.float64]
    primitives: list[Primitive]


#: Height of the title bar and width of the legend column of a picture [px].
_TITLE_H, _LEGEND_W = 70, 360
#: Height of a cell's caption bar in the summary picture [px].
_CAPTION_H = 30
#: Colour of the thin lines between the parts of a picture.
_RULE: RGB = (215, 215, 215)


def _prepare(points, labels, primitives, view: tuple[int, int], point_size: int, yaw: float,
             pitch: float) -> _Figure:
    """Check the inputs and build what every picture shows (:class:`_Figure`).

    The reconstruction is sampled at about one pixel of a ``view`` (width, height) [px]
    picture turned by ``yaw`` and ``pitch`` [rad]: coarse samples frame it first.
    """
    from geomodel_ros.core.reconstruction import reconstruct

    prims = list(getattr(primitives, "objects", primitives))
    pts = as_points(points, allow_organized=True)
    lab = np.asarray(labels).reshape(-1)
    if len(lab) != len(pts):
        raise InputError(f"labels must have {len(pts)} entries like points, got {len(lab)}")
    finite = np.isfinite(pts).all(axis=1)
    pts, lab = pts[finite], lab[finite].astype(np.int64)
    up = _up_vector(prims)
    coarse, _ = reconstruct(prims, 0.01, max_points_per_object=50_000)
    framing = np.vstack([pts, coarse])
    pivot = (0.5 * (pts.min(axis=0) + pts.max(axis=0)) if len(pts) else None)
    orbit = orbit_camera(framing, yaw=yaw, pitch=pitch, up=up, pivot=pivot,
                         width=view[0], height=view[1])
    depth = orbit.to_camera_frame(framing)[:, 2]
    footprint = float(np.median(depth)) / orbit.fx if len(depth) else 0.001
    rec, rec_ids = reconstruct(prims, max(0.6 * point_size * footprint, 1e-4),
                               max_points_per_object=600_000)
    return _Figure(pts, lab, id_colors(lab), _shading_normals(pts) if len(pts) >= 3 else None,
                   rec, id_colors(rec_ids), primitive_normals(rec, rec_ids, prims), framing,
                   pivot, up, prims)


def _views(fig: _Figure, width: int, height: int, intrinsics, point_size: int, yaw: float,
           pitch: float) -> list[NDArray[np.uint8]]:
    """Render the segments (sensor view), reconstruction and overlay (turned view) images."""
    if intrinsics is not None:
        sensor = sensor_camera(intrinsics, width, height)
    else:
        sensor = fit_camera(fig.points, width=width, height=height)
    cam = orbit_camera(fig.framing, yaw=yaw, pitch=pitch, up=fig.up, pivot=fig.pivot,
                       width=width, height=height)
    seg = render_points(fig.points, fig.rgb, camera=sensor, normals=fig.normals,
                        point_size=_splat_size(fig.points, sensor, point_size))
    recon = render_points(fig.rec, fig.rec_rgb, camera=cam, point_size=point_size,
                          normals=fig.rec_normals)
    overlay = _render_overlay(fig.points, np.array(INPUT_GREY, dtype=np.uint8), fig.rec,
                              fig.rec_rgb, cam,
                              min(_splat_size(fig.points, cam, point_size) + 1, 9), point_size,
                              fig.normals, fig.rec_normals, _WHITE)
    return [seg, recon, overlay]


def _captions(fig: _Figure, yaw: float) -> list[tuple[str, str]]:
    """(title, subtitle) of the segments, reconstruction and overlay pictures."""
    n_obj = sum(p.type != "unknown" for p in fig.primitives)
    turned = f"view turned {math.degrees(yaw):.0f} deg"
    return [
        ("Segmentation of the input",
         f"{len(fig.points)} sensor points coloured by object (sensor view); grey = no object"),
        ("Reconstruction",
         f"{n_obj} modeled surfaces in full, hidden parts included; {turned}"),
        ("Input + reconstruction",
         f"grey = sensor points; colour = modeled surface, bright where unseen; {turned}"),
    ]


def _legend_entries(fig: _Figure) -> tuple[list[tuple[RGB, str]], list[list[tuple[RGB, str]]]]:
    """Legend lines of every object, and the extra lines of each of the three pictures."""
    prims = sorted(fig.primitives, key=lambda p: p.id)
    swatches = id_colors(np.array([p.id for p in prims], dtype=np.int64))
    entries = [(tuple(int(v) for v in c), legend_label(p)) for c, p in zip(swatches, prims)]
    noise = [(NO_OBJECT_RGB, "-1 no object")] if (fig.labels < 0).any() else []
    return entries, [noise, [], [(INPUT_GREY, "sensor points")]]


def _picture(img: NDArray[np.uint8], title: str, subtitle: str,
             entries: Sequence[tuple[RGB, str]], size: tuple[int, int]) -> NDArray[np.uint8]:
    """One full picture: title bar, the view on the left, the legend on the right."""
    width, height = size
    view_w = width - _LEGEND_W
    canvas = _blank(width, height)
    _title_bar(canvas, title, subtitle, _TITLE_H, 2)
    _paste(canvas, img, (0, _TITLE_H, view_w, height))
    canvas[_TITLE_H:, view_w:view_w + 1] = _RULE
    _legend(canvas, entries, (view_w + 16, _TITLE_H + 16, width - 8, height - 8),
            "id type size")
    return canvas


def _summary(imgs: Sequence[NDArray[np.uint8]], titles: Sequence[str], legend_title: str,
             entries: Sequence[tuple[RGB, str]], size: tuple[int, int]) -> NDArray[np.uint8]:
    """Put the three views and one legend in a 2 x 2 grid of ``size`` (width, height) [px]."""
    width, height = size
    cw, ch, cap = width // 2, height // 2, _CAPTION_H
    canvas = _blank(width, height)
    for img, title, (x, y) in zip(imgs, titles, [(0, 0), (cw, 0), (0, ch)]):
        canvas[y:y + cap, x:x + cw] = _TITLE_BG
        draw_text(canvas, title, (x + 10, y + 7), 2, _WHITE)
        _paste(canvas, img, (x, y + cap, x + cw, y + ch))
    canvas[ch, :] = canvas[:, cw] = _RULE
    canvas[ch:ch + cap, cw:] = _TITLE_BG
    draw_text(canvas, legend_title, (cw + 10, ch + 7), 2, _WHITE)
    _legend(canvas, entries, (cw + 16, ch + cap + 12, width - 8, height - 8), "id type size")
    return canvas


def render_figures(points, labels, primitives, out_dir, *, title_prefix: str = "",
                   intrinsics=None, size: tuple[int, int] = (1200, 800), point_size: int = 2,
                   yaw: float = math.radians(40), pitch: float = math.radians(12),
                   summary: bool = True) -> list[Path]:
    """Write pictures of a modeled scene like the paper's Figures 6-8.

    Parameters
    ----------
    points : (N, 3) or (H, W, 3) float array [m]
        Input cloud in the sensor frame (non-finite rows are skipped).
    labels : (N,) int array
        Object id per point, -1 = no object (e.g. from ``model_scene``).
    primitives : list of Primitive or ModelingResult
        The modeled objects.
    out_dir : str or Path
        Created if missing.
    title_prefix : str
        Put in front of each title, e.g. ``"scene3: "``.
    intrinsics : dict, optional
        ``fx, fy, cx, cy, width, height`` [px] of the sensor: ``segments.png`` then shows
        exactly the sensor's image; without it the input is framed from the sensor's pose.
    size : (width, height) [px]
        Size of each picture, each at least (640, 400).
    point_size : int
        Splat size [px], 1-9.
    yaw, pitch : float [rad]
        Turn of the scene about its up direction (the largest plane's normal) and about
        the horizontal for the reconstruction and overlay views.
    summary : bool
        Also write ``summary.png`` (the three views and one legend, 2 x 2).

    Returns
    -------
    list of Path
        ``segments.png``, ``reconstruction.png``, ``overlay.png`` [, ``summary.png``].
        Every object has the colour :func:`geomodel_ros.core.colors.id_colors` gives its id.
    """
    width, height = int(size[0]), int(size[1])
    if width < 640 or height < 400:
        raise ValueError(f"size must be at least (640, 400) [px], got {size!r}")
    view_w, view_h = width - _LEGEND_W, height - _TITLE_H
    fig = _prepare(points, labels, primitives, (view_w, view_h), point_size, yaw, pitch)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    captions = _captions(fig, yaw)
    entries, extra = _legend_entries(fig)
    names = ["segments.png", "reconstruction.png", "overlay.png"]
    paths = []
    views = _views(fig, view_w, view_h, intrinsics, point_size, yaw, pitch)
    for img, (title, sub), name, more in zip(views, captions, names, extra):
        canvas = _picture(img, title_prefix + title, sub, entries + more, (width, height))
        paths.append(_write_png(out / name, canvas))
    if summary:
        cw, ch = width // 2, height // 2
        views = _views(fig, cw, ch - _CAPTION_H, intrinsics, point_size, yaw, pitch)
        canvas = _summary(views, [title_prefix + t for t, _ in captions],
                          title_prefix + "Objects", entries + extra[0] + extra[2],
                          (width, height))
        paths.append(_write_png(out / "summary.png", canvas))
    return paths
