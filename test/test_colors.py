"""One colour per object id: the map itself, and the PLY, RViz clouds and PNGs agreeing."""

from __future__ import annotations

import json

import numpy as np
import pytest
from std_msgs.msg import Header

from geomodel_ros.core.colors import NO_OBJECT_RGB, PALETTE, id_colors
from geomodel_ros.core.primitives import Primitive
from geomodel_ros.core.reconstruction import reconstruct
from geomodel_ros.tools.cli import main
from geomodel_ros.tools.io import read_ply
from geomodel_ros.tools.render import render_figures
from geomodel_ros.tools.synth import render_scene
from msg_adapters.markers import object_colours, reconstruction_cloud, segments_cloud
from msg_adapters.pointcloud2 import cloud_to_fields, unpack_rgb

#: Smallest RGB distance that tells two colours apart at a glance in a picture (chosen by
#: eye on the pictures; black and white are 441 apart).
DISTINGUISHABLE = 60.0


def _rgb_distance(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.linalg.norm(a.astype(float) - b.astype(float), axis=-1)


def test_colour_depends_on_the_id_only():
    ids = np.array([3, -1, 0, 18, 7, 10**12, 3])
    c = id_colors(ids)
    assert c.dtype == np.uint8 and c.shape == (7, 3)
    np.testing.assert_array_equal(c[0], c[6])
    for k, i in enumerate(ids):  # alone, or among other ids, in any order
        np.testing.assert_array_equal(id_colors(np.array([i]))[0], c[k])
    np.testing.assert_array_equal(id_colors(ids[::-1])[::-1], c)
    assert id_colors(np.zeros(0, dtype=np.int32)).shape == (0, 3)


def test_negative_ids_are_grey_and_objects_never_are():
    c = id_colors(np.array([-1, -7]))
    assert [tuple(int(v) for v in x) for x in c] == [NO_OBJECT_RGB, NO_OBJECT_RGB]
    objects = id_colors(np.arange(0, 500))
    assert _rgb_distance(objects, np.array(NO_OBJECT_RGB)).min() >= DISTINGUISHABLE
    # not grey at all: every object colour has a clear hue
    assert (objects.max(axis=1).astype(int) - objects.min(axis=1)).min() >= 100


def test_distinct_small_ids_get_distinguishable_colours():
    n = len(PALETTE)
    c = id_colors(np.arange(n))
    d = _rgb_distance(c[:, None, :], c[None, :, :])
    d[np.arange(n), np.arange(n)] = np.inf
    assert d.min() >= DISTINGUISHABLE
    # beyond the palette: no two of the next few hundred ids share a colour, and
    # consecutive ids (often neighbouring segments) are far apart
    assert len({tuple(x) for x in id_colors(np.arange(n, 400))}) == 400 - n
    neighbours = _rgb_distance(id_colors(np.arange(n, 999)), id_colors(np.arange(n + 1, 1000)))
    assert neighbours.min() >= DISTINGUISHABLE


@pytest.mark.parametrize("bad", [np.zeros((2, 2), dtype=int), np.array([0.5, 1.0])])
def test_id_colors_rejects_what_is_not_an_id_array(bad):
    with pytest.raises(ValueError, match=r"\(N,\) integer array"):
        id_colors(bad)


def test_ply_rviz_clouds_and_pictures_give_an_object_the_same_colour(tmp_path):
    import open3d as o3d

    scene = render_scene("tiny_shapes")
    pcd, out_json, ply = tmp_path / "s.pcd", tmp_path / "o.json", tmp_path / "r.ply"
    assert main(["synth", "tiny_shapes", "--out", str(pcd)]) == 0
    assert main(["model", str(pcd), "--labels-field", "label", "--json", str(out_json),
                 "--reconstruction", str(ply)]) == 0
    objects = json.loads(out_json.read_text())["objects"]
    prims = [Primitive(o["id"], o["type"], np.array(o["center"]), np.array(o["rotation"]),
                       o["dimensions"], o["point_count"], o["rmse"]) for o in objects]
    ids_present = sorted(o.id for o in prims if o.type != "unknown")
    assert len(ids_present) >= 5

    # PLY written by the command line: colour of every reconstruction sample by its id
    _, rec_ids = reconstruct(prims, 0.002)
    cloud = read_ply(ply)
    ply_rgb = np.stack([cloud.fields[c] for c in ("red", "green", "blue")], axis=1)
    assert len(ply_rgb) == len(rec_ids)
    ply_by_id = {i: ply_rgb[rec_ids == i] for i in ids_present}
    for i, rows in ply_by_id.items():
        assert (rows == rows[0]).all()  # one colour per object

    # RViz: the labelled clouds of the node (segments and reconstruction)
    header = Header(frame_id="camera_optical")
    seg = unpack_rgb(cloud_to_fields(segments_cloud(scene.points, scene.labels, header),
                                     ["rgb"])["rgb"])
    rec = unpack_rgb(cloud_to_fields(reconstruction_cloud(np.zeros((len(rec_ids), 3)),
                                                          rec_ids, header), ["rgb"])["rgb"])
    np.testing.assert_array_equal(rec, ply_rgb)
    for i in ids_present:
        assert (seg[scene.labels == i] == ply_by_id[i][0]).all()
        np.testing.assert_array_equal(object_colours(np.array([i]))[0], ply_by_id[i][0])

    # PNGs: every object's legend swatch is drawn in exactly that colour
    paths = render_figures(scene.points, scene.labels, prims, tmp_path / "fig",
                           size=(800, 520), intrinsics=scene.intrinsics, summary=False)
    for path in paths:
        img = np.asarray(o3d.io.read_image(str(path))).reshape(-1, 3)
        present = {tuple(int(v) for v in c) for c in np.unique(img, axis=0)}
        for i in ids_present:
            assert tuple(int(v) for v in ply_by_id[i][0]) in present, (path.name, i)
    # distinct objects, distinct colours
    assert len({tuple(ply_by_id[i][0]) for i in ids_present}) == len(ids_present)
