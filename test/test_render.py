"""Pictures of modeled scenes: z-buffer, cameras, bitmap font, the written figures."""

from __future__ import annotations

import functools
import math

import numpy as np
import pytest

from geomodel_ros.core.errors import InputError
from geomodel_ros.core.params import ModelingParams
from geomodel_ros.core.modeling import model_scene
from geomodel_ros.core.primitives import Primitive
from geomodel_ros.core.reconstruction import reconstruct
from geomodel_ros.core.colors import id_colors
from geomodel_ros.tools.render import (
    draw_text,
    fit_camera,
    legend_label,
    orbit_camera,
    primitive_normals,
    render_figures,
    render_points,
    text_size,
)
from geomodel_ros.tools.synth import PinholeCamera, render_scene

CAM = (100.0, 100.0, 10.0, 10.0, 21, 21)  # fx, fy, cx, cy, width, height
RED, BLUE = (255, 0, 0), (0, 0, 255)


@pytest.mark.parametrize("near_first", [True, False])
def test_zbuffer_keeps_the_nearest_point(near_first: bool) -> None:
    pts = np.array([[0.0, 0.0, 1.0], [0.0, 0.0, 2.0]])  # both on pixel (10, 10)
    cols = np.array([RED, BLUE], dtype=np.uint8)
    if not near_first:
        pts, cols = pts[::-1], cols[::-1]
    img, depth = render_points(pts, cols, camera=CAM, point_size=1, shading=0.0, outline=0.0,
                               return_depth=True)
    assert tuple(img[10, 10]) == RED
    assert depth[10, 10] == 1.0
    others = np.ones((21, 21), dtype=bool)
    others[10, 10] = False
    assert (img[others] == 255).all() and np.isinf(depth[others]).all()


def test_render_points_shape_dtype_and_splat_size() -> None:
    pts = np.array([[0.0, 0.0, 1.0], [np.nan, 0.0, 1.0], [0.0, 0.0, -1.0]])
    img = render_points(pts, np.array(BLUE, dtype=np.uint8), camera=CAM, point_size=3,
                        background=(10, 20, 30), shading=0.0, outline=0.0)
    assert img.shape == (21, 21, 3) and img.dtype == np.uint8
    painted = (img != (10, 20, 30)).any(axis=2)
    assert painted.sum() == 9 and painted[9:12, 9:12].all()  # NaN / behind camera skipped


def test_render_points_rejects_bad_arguments() -> None:
    pts = np.zeros((2, 3)) + [0, 0, 1]
    with pytest.raises(ValueError, match="point_size"):
        render_points(pts, np.zeros((2, 3), np.uint8), camera=CAM, point_size=0)
    with pytest.raises(InputError, match="colors"):
        render_points(pts, np.zeros((3, 3), np.uint8), camera=CAM)
    with pytest.raises(ValueError, match="camera"):
        render_points(pts, np.zeros((2, 3), np.uint8), camera=(1, 2, 3))
    with pytest.raises(ValueError, match="fx"):
        PinholeCamera(0.0, 1.0, 0.0, 0.0, 10, 10)


def test_normal_shading_darkens_grazing_surfaces() -> None:
    pts = np.array([[-0.05, 0.0, 1.0], [0.05, 0.0, 1.0]])
    normals = np.array([[0.0, 0.0, -1.0], [1.0, 0.0, 0.0]])  # facing the camera / edge-on
    img = render_points(pts, np.array([200, 200, 200], np.uint8), camera=CAM, point_size=1,
                        normals=normals, shading=0.0, outline=0.0)
    assert int(img[10, 5, 0]) > int(img[10, 15, 0])


def test_fit_and_orbit_cameras_frame_every_point() -> None:
    rng = np.random.default_rng(3)
    pts = rng.uniform([-0.2, -0.1, 0.4], [0.2, 0.1, 0.7], size=(500, 3))
    for cam in (fit_camera(pts, width=320, height=200),
                orbit_camera(pts, yaw=math.radians(60), pitch=math.radians(20), width=320,
                             height=200)):
        q = cam.to_camera_frame(pts)
        u = cam.fx * q[:, 0] / q[:, 2] + cam.cx
        v = cam.fy * q[:, 1] / q[:, 2] + cam.cy
        assert (q[:, 2] > 0).all()
        assert u.min() >= 0 and u.max() <= 319 and v.min() >= 0 and v.max() <= 199
        assert u.max() - u.min() > 250 or v.max() - v.min() > 150  # fills the image


def test_draw_text_changes_pixels_inside_its_box_only() -> None:
    img = np.full((60, 240, 3), 255, dtype=np.uint8)
    x0, y0, x1, y1 = draw_text(img, "Hi 3! gy", (5, 7), scale=2, color=(0, 0, 0))
    assert (x1 - x0, y1 - y0) == text_size("Hi 3! gy", 2)
    changed = (img != 255).any(axis=2)
    rows, cols = np.nonzero(changed)
    assert len(rows) > 50
    assert rows.min() >= y0 and rows.max() < y1 and cols.min() >= x0 and cols.max() < x1
    assert (img[changed] == 0).all()


def test_draw_text_clips_at_the_border_and_maps_unknown_characters() -> None:
    img = np.full((10, 30, 3), 255, dtype=np.uint8)
    draw_text(img, "WWWWWW", (-4, -3), scale=3)  # partly outside: clipped, no error
    assert (img != 255).any()
    a, b = np.full((20, 20, 3), 255, np.uint8), np.full((20, 20, 3), 255, np.uint8)
    draw_text(a, "\u00e9", (0, 0))
    draw_text(b, "?", (0, 0))
    assert (a == b).all()


def test_every_printable_glyph_is_drawn_and_distinct() -> None:
    masks = []
    for code in range(33, 127):
        img = np.zeros((20, 12, 3), dtype=np.uint8)
        draw_text(img, chr(code), (0, 0), scale=1, color=(255, 255, 255))
        assert img.any(), chr(code)
        masks.append(img[..., 0].tobytes())
    assert len(set(masks)) == len(masks)


def test_primitive_normals_are_exact() -> None:
    rot = np.linalg.qr(np.random.default_rng(0).normal(size=(3, 3)))[0]
    rot *= np.sign(np.linalg.det(rot))
    c = np.array([0.1, -0.2, 0.6])
    sphere = Primitive(1, "sphere", c, np.eye(3), {"radius": 0.03}, 10, 0.0)
    box = Primitive(2, "cuboid", c, rot, {"length": 0.05, "width": 0.04, "height": 0.03}, 10,
                    0.0)
    cyl = Primitive(3, "cylinder", c, rot, {"radius": 0.02, "height": 0.06}, 10, 0.0)
    for p in (sphere, box, cyl):
        pts, ids = reconstruct([p], 0.004)
        n = primitive_normals(pts, ids, [p])
        np.testing.assert_allclose(np.linalg.norm(n, axis=1), 1.0, atol=1e-9)
        if p.type == "sphere":
            np.testing.assert_allclose(n, (pts - c) / 0.03, atol=1e-9)
        else:
            local = n @ rot  # every normal is one of the local axes (or radial for the side)
            axial = np.abs(local[:, 2])
            assert ((axial > 1 - 1e-9) | (axial < 1e-9) | (p.type == "cuboid")).all()
            if p.type == "cuboid":
                assert np.allclose(np.sort(np.abs(local), axis=1)[:, :2], 0.0, atol=1e-9)


def test_legend_label_gives_id_type_and_size_in_mm() -> None:
    desk = Primitive(0, "plane", np.zeros(3), np.eye(3), {"length": 0.4, "width": 0.4}, 1, 0.0)
    assert legend_label(desk) == "0 plane 400x400 mm"
    can = Primitive(3, "cylinder", np.zeros(3), np.eye(3), {"radius": 0.05, "height": 0.0605},
                    1, 0.0)
    assert legend_label(can) == "3 cylinder r50 h60.5 mm"


@functools.lru_cache(maxsize=None)
def _tiny_model():
    scene = render_scene("tiny_shapes")
    labels, result = model_scene(scene.points, ModelingParams())
    return scene, labels, result


def test_render_figures_writes_readable_pngs(tmp_path) -> None:
    import open3d as o3d

    scene, labels, result = _tiny_model()
    paths = render_figures(scene.points, labels, result, tmp_path / "fig", size=(800, 520),
                           title_prefix="tiny: ", intrinsics=scene.intrinsics)
    assert [p.name for p in paths] == ["segments.png", "reconstruction.png", "overlay.png",
                                       "summary.png"]
    colors = {o.id: tuple(int(v) for v in id_colors(np.array([o.id]))[0])
              for o in result.objects}
    for path in paths:
        assert path.stat().st_size < 1_000_000
        img = np.asarray(o3d.io.read_image(str(path)))
        assert img.shape == (520, 800, 3) and img.dtype == np.uint8
        view = img[80:, :440].reshape(-1, 3)
        assert len(np.unique(view, axis=0)) > 50  # shaded objects, not a blank image
        present = {tuple(int(v) for v in c) for c in np.unique(img.reshape(-1, 3), axis=0)}
        for o in result.objects:  # every object's legend swatch, in its id's colour
            assert colors[o.id] in present, (path.name, o.id)
