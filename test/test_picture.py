"""Pictures of modeled scenes (tools/picture.py): sensor camera, colours, outlines, labels."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.signal import fftconvolve

from geomodel_ros.core.colors import id_colors
from geomodel_ros.core.errors import InputError
from geomodel_ros.core.primitives import Primitive
from geomodel_ros.tools import picture
from geomodel_ros.tools.render import draw_text
from geomodel_ros.tools.synth import PinholeCamera
from geomodel_ros.tools.synth.shapes import Box, Rectangle

#: An odd camera (non-square pixels, off-centre principal point) that the fit must recover.
CAM = PinholeCamera(fx=300.0, fy=310.0, cx=100.5, cy=70.25, width=200, height=150)
INK = (25, 25, 25)
#: Desk 0.7 m ahead, tilted 132 deg about x (seen from above, its normal towards the camera);
#: a box of 100 x 80 x 60 mm rests on it, turned 30 deg about that normal.
TILT = np.array([[1.0, 0.0, 0.0],
                 [0.0, np.cos(2.3), -np.sin(2.3)],
                 [0.0, np.sin(2.3), np.cos(2.3)]])  # desk normal towards the camera


def _yaw(a: float) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _scene():
    """Organized cloud (H, W, 3), labels (H*W,), desk and box as their true primitives."""
    desk_c = np.array([0.0, 0.0, 0.7])
    box_rot = TILT @ _yaw(np.radians(30.0))
    box_c = desk_c + TILT[:, 2] * 0.03  # resting on the desk: half its 60 mm height
    desk = Rectangle(0.8, 0.6, center=desk_c, rotation=TILT)
    box = Box(0.10, 0.08, 0.06, center=box_c, rotation=box_rot)
    pts, lab = CAM.render([desk, box], [0, 1])
    prims = [Primitive(0, "plane", desk_c, TILT, {"length": 0.8, "width": 0.6}, 1, 0.0),
             Primitive(1, "cuboid", box_c, box_rot,
                       {"length": 0.10, "width": 0.08, "height": 0.06}, 1, 0.0)]
    return pts, lab.reshape(-1).astype(np.int64), prims


def _contains_text(img: np.ndarray, text: str) -> bool:
    """Whether ``text`` appears in ``img`` drawn in INK at scale 1 (exact glyph match)."""
    w = 6 * len(text)
    probe = np.full((10, w, 3), 255, dtype=np.uint8)
    draw_text(probe, text, (0, 0), 1, INK)
    glyph = (probe == INK).all(axis=2).astype(float)
    ink = (img == INK).all(axis=2).astype(float)
    # every glyph pixel inked (match == glyph count) and no ink where the glyph is blank
    hits = fftconvolve(ink, glyph[::-1, ::-1], mode="valid")
    blank = fftconvolve(ink, (1.0 - glyph)[::-1, ::-1], mode="valid")
    return bool(np.any((np.rint(hits) == glyph.sum()) & (np.rint(blank) == 0)))


def test_organized_camera_recovers_the_intrinsics() -> None:
    pts, _, _ = _scene()
    cam, rot = picture.organized_camera(pts)
    assert np.allclose([cam.fx, cam.fy, cam.cx, cam.cy], [300.0, 310.0, 100.5, 70.25],
                       atol=1e-6)
    assert (cam.width, cam.height) == (200, 150)
    assert np.array_equal(rot, np.eye(3))


def test_organized_camera_of_a_cloud_looking_along_minus_z() -> None:
    # PCL's tutorials store some clouds as (x, -y, -z) of the optical frame.
    pts, _, _ = _scene()
    flipped = pts * np.array([1.0, -1.0, -1.0])
    cam, rot = picture.organized_camera(flipped)
    assert np.allclose([cam.fx, cam.fy, cam.cx, cam.cy], [300.0, 310.0, 100.5, 70.25],
                       atol=1e-6)
    assert np.array_equal(rot, np.diag([1.0, -1.0, -1.0]))


def test_a_shuffled_grid_is_no_pinhole_image() -> None:
    pts, _, _ = _scene()
    flat = pts.reshape(-1, 3).copy()
    np.random.default_rng(0).shuffle(flat)
    assert picture.organized_camera(flat.reshape(pts.shape)) is None


def test_box_wire_has_twelve_edges_of_the_box_lengths() -> None:
    _, _, prims = _scene()
    edges = picture.primitive_wires(prims[1])
    lengths = sorted(round(float(np.linalg.norm(e[1] - e[0])), 9) for e in edges)
    assert lengths == [0.06] * 4 + [0.08] * 4 + [0.10] * 4
    assert picture.primitive_wires(Primitive(2, "unknown", np.zeros(3), np.eye(3), {}, 1,
                                             0.0)) == []


@pytest.fixture(scope="module")
def written(tmp_path_factory):
    """Write the scene's picture as PNG and read it back (uint8 H x W x 3)."""
    import open3d as o3d

    pts, lab, prims = _scene()
    img = picture.scene_picture(pts, lab, prims, title="box on desk", oblique=True)
    path = picture.write_png(tmp_path_factory.mktemp("pic") / "scene.png", img)
    back = np.asarray(o3d.io.read_image(str(path)))
    return img, back, pts, lab, prims


def test_png_holds_the_picture(written) -> None:
    img, back, *_ = written
    assert back.shape == img.shape and back.dtype == np.uint8
    assert np.array_equal(back, img)


def test_box_pixels_have_the_box_colour(written) -> None:
    _, back, pts, lab, _ = written
    # the sensor view starts below the title bar; pixel (v, u) shows the cloud's (v, u)
    view = back[picture._TITLE_H:picture._TITLE_H + CAM.height, :CAM.width]
    box_px = lab.reshape(CAM.height, CAM.width) == 1
    colour = view[box_px].astype(int)
    box_rgb = id_colors(np.array([1]))[0].astype(float)
    desk_rgb = id_colors(np.array([0]))[0].astype(float)
    # shading scales the colour; its direction (hue) stays the box's, not the desk's
    unit = colour / np.maximum(np.linalg.norm(colour, axis=1, keepdims=True), 1e-9)
    share_box = np.mean(unit @ (box_rgb / np.linalg.norm(box_rgb)) > 0.995)
    share_desk = np.mean(unit @ (desk_rgb / np.linalg.norm(desk_rgb)) > 0.995)
    assert share_box > 0.6  # the rest: outline, label, rim at depth edges
    assert share_desk < 0.05


def test_labels_name_each_object_in_both_views(written) -> None:
    _, back, *_ = written
    views = back[picture._TITLE_H:picture._TITLE_H + CAM.height]  # not the legend below
    sensor, oblique = views[:, :CAM.width], views[:, CAM.width:]
    for view in (sensor, oblique):
        assert _contains_text(view, "1 cuboid")
        assert _contains_text(view, "0 plane")
        assert not _contains_text(view, "1 cylinder")


def test_box_outline_runs_through_the_projected_corners(written) -> None:
    _, back, _, _, prims = written
    view = back[picture._TITLE_H:picture._TITLE_H + CAM.height, :CAM.width].astype(int)
    wire = np.array([int(v * picture.WIRE_SHADE) for v in id_colors(np.array([1]))[0]])
    is_wire = (np.abs(view - wire) <= 1).all(axis=2)
    edges = picture.primitive_wires(prims[1])
    corners = np.unique(np.vstack(edges).round(9), axis=0)
    uv = CAM.project(corners)
    seen = 0
    for u, v in np.rint(uv).astype(int):
        if 2 <= u < CAM.width - 2 and 2 <= v < CAM.height - 2:
            seen += bool(is_wire[v - 2:v + 3, u - 2:u + 3].any())
    assert seen >= 6  # hidden corners are dotted and may fall between dots


def test_write_png_downscales(tmp_path) -> None:
    import open3d as o3d

    img = np.zeros((10, 8, 3), dtype=np.uint8)
    img[:, :4] = 200
    path = picture.write_png(tmp_path / "small.png", img, downscale=2)
    back = np.asarray(o3d.io.read_image(str(path)))
    assert back.shape == (5, 4, 3)
    assert (back[:, :2] == 200).all() and (back[:, 2:] == 0).all()


def test_bad_input_is_refused(tmp_path) -> None:
    pts, lab, prims = _scene()
    with pytest.raises(InputError, match="points must be"):
        picture.scene_picture(np.zeros((5, 2)), np.zeros(5, dtype=int), prims)
    with pytest.raises(InputError, match="labels must be"):
        picture.scene_picture(pts, lab[:-1], prims)
    with pytest.raises(ValueError, match="png"):
        picture.write_png(tmp_path / "x.jpg", np.zeros((4, 4, 3), dtype=np.uint8))
    with pytest.raises(InputError, match="uint8"):
        picture.write_png(tmp_path / "x.png", np.zeros((4, 4, 3)))


def test_command_line_errors_are_one_line(tmp_path, capsys) -> None:
    assert picture.main([str(tmp_path / "missing.pcd"), "--out", str(tmp_path / "a.png")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("picture: error:") and err.count("\n") == 1
    assert picture.main([str(tmp_path / "missing.pcd"), "--out", str(tmp_path / "a.jpg")]) == 2
    assert "png" in capsys.readouterr().err
    assert not (tmp_path / "a.png").exists()
