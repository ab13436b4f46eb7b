"""The ``geomodel`` command line, run in-process (geomodel_ros.tools.cli.main)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from geomodel_ros.tools.cli import main, params_yaml
from geomodel_ros.tools.io import read_pcd, read_ply
from geomodel_ros.core.primitives import DIMENSION_NAMES, PRIMITIVE_TYPES, Primitive
from geomodel_ros.core.reconstruction import reconstruct
from geomodel_ros.tools.synth import render_scene

SCENE = "tiny_box"


@pytest.fixture(scope="module")
def scene_files(tmp_path_factory):
    """`geomodel synth tiny_box --out x.pcd` once for the module."""
    d = tmp_path_factory.mktemp("cli")
    pcd = d / "x.pcd"
    assert main(["synth", SCENE, "--out", str(pcd)]) == 0
    return d, pcd


def _run(capsys, argv):
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def _assert_one_error_line(code, err, match):
    assert code == 2
    assert "Traceback" not in err
    lines = err.splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith("geomodel: error: ")
    assert match in lines[0], lines[0]


# ---------------------------------------------------------------------------------------
# synth and model
# ---------------------------------------------------------------------------------------


def test_synth_writes_pcd_and_ground_truth(scene_files):
    _, pcd = scene_files
    scene = render_scene(SCENE)
    cloud = read_pcd(pcd)
    assert (cloud.width, cloud.height) == (160, 120)
    np.testing.assert_allclose(cloud.points[cloud.finite_mask()], scene.points, atol=1e-6)
    np.testing.assert_array_equal(cloud.fields["label"].reshape(-1)[cloud.finite_mask()],
                                  scene.labels)
    gt = json.loads(pcd.with_suffix(".json").read_text())
    assert gt["scene"] == SCENE
    assert gt["noise"] is False
    assert gt["intrinsics"] == scene.intrinsics
    assert [o["type"] for o in gt["objects"]] == ["plane", "cuboid"]
    assert [o["id"] for o in gt["objects"]] == [0, 1]


def test_synth_unknown_scene(tmp_path, capsys):
    code, _, err = _run(capsys, ["synth", "no_such_scene", "--out", tmp_path / "y.pcd"])
    _assert_one_error_line(code, err, "unknown scene 'no_such_scene'")
    assert not (tmp_path / "y.pcd").exists()


def test_model_writes_json_and_ply(scene_files, capsys):
    d, pcd = scene_files
    out_json, ply = d / "out.json", d / "r.ply"
    code, out, err = _run(capsys, ["model", pcd, "--labels-field", "label", "--json", out_json,
                                   "--reconstruction", ply])
    assert (code, err) == (0, "")
    assert out.startswith("2 objects (1 cuboid, 1 plane) in ")
    result = json.loads(out_json.read_text())
    assert set(result) == {"objects", "noise", "sensor", "fragments", "timing"}
    assert result["sensor"] is None  # a cloud in its sensor's frame
    assert {"modeling_s", "load_s", "reconstruction_s", "total_s"} <= set(result["timing"])
    assert [(o["id"], o["type"]) for o in result["objects"]] == [(0, "plane"), (1, "cuboid")]
    for o in result["objects"]:
        assert set(o) == {"id", "type", "center", "rotation", "dimensions", "completed",
                          "point_count", "rmse", "confidence", "confidence_terms", "faces",
                          "reason"}
        assert o["type"] in PRIMITIVE_TYPES
        assert len(o["center"]) == 3
        rot = np.array(o["rotation"])
        assert rot.shape == (3, 3)
        np.testing.assert_allclose(rot.T @ rot, np.eye(3), atol=1e-9)
        assert np.linalg.det(rot) == pytest.approx(1.0)
        assert set(o["dimensions"]) == set(DIMENSION_NAMES[o["type"]])
        assert all(set(f) == {"surface", "cf", "point_count"} for f in o["faces"])
        assert o["point_count"] == int(np.count_nonzero(render_scene(SCENE).labels == o["id"]))
    box = result["objects"][1]
    assert sorted(box["dimensions"].values()) == pytest.approx([0.05, 0.06, 0.08], abs=1e-3)

    # The PLY holds exactly the reconstruction of the objects in the JSON (float32 xyz).
    prims = [Primitive(o["id"], o["type"], np.array(o["center"]), np.array(o["rotation"]),
                       o["dimensions"], o["point_count"], o["rmse"]) for o in result["objects"]]
    expected, ids = reconstruct(prims, 0.002)
    cloud = read_ply(ply)
    assert len(cloud) == len(expected) > 0
    np.testing.assert_allclose(cloud.points, expected, atol=1e-6)
    assert {"red", "green", "blue"} <= set(cloud.fields)
    colours = np.stack([cloud.fields[c] for c in ("red", "green", "blue")], axis=1)
    assert len({tuple(colours[ids == i][0]) for i in (0, 1)}) == 2   # one colour per object


def test_model_with_labels_npy(tmp_path, capsys):
    scene = render_scene(SCENE)
    pts, labels = tmp_path / "pts.npy", tmp_path / "labels.npy"
    np.save(pts, scene.points)
    np.save(labels, scene.labels.astype(np.int64))
    out_json = tmp_path / "o.json"
    code, _, err = _run(capsys, ["model", pts, "--labels", labels, "--json", out_json,
                                 "--set", "seed=3", "--set", "edge_correction=false"])
    assert (code, err) == (0, "")
    result = json.loads(out_json.read_text())
    assert [o["type"] for o in result["objects"]] == ["plane", "cuboid"]


def test_model_with_params_file(scene_files, tmp_path, capsys):
    _, pcd = scene_files
    params = tmp_path / "p.yaml"
    params.write_text("modeler:\n  ros__parameters:\n    min_object_points: 100000\n")
    out_json = tmp_path / "o.json"
    code, _, err = _run(capsys, ["model", pcd, "--labels-field", "label", "--json", out_json,
                                 "--params", params])
    assert (code, err) == (0, "")
    assert [o["type"] for o in json.loads(out_json.read_text())["objects"]] == ["unknown"] * 2


def test_params_command_prints_the_yaml(capsys):
    code, out, err = _run(capsys, ["params"])
    assert (code, err) == (0, "")
    assert out == params_yaml()


# ---------------------------------------------------------------------------------------
# Error paths: exit 2, one line `geomodel: error: ...`, no traceback
# ---------------------------------------------------------------------------------------


def _model(capsys, inp, *extra, json_out=None, labels_field="label"):
    json_out = json_out if json_out is not None else inp.parent / "err.json"
    argv = ["model", inp, "--json", json_out]
    if labels_field:
        argv += ["--labels-field", labels_field]
    return _run(capsys, argv + list(extra))


def test_missing_file(tmp_path, capsys):
    code, _, err = _model(capsys, tmp_path / "nope.pcd")
    _assert_one_error_line(code, err, "nope.pcd: no such file")
    assert not (tmp_path / "err.json").exists()


def test_corrupt_pcd(tmp_path, capsys):
    f = tmp_path / "garbage.pcd"
    f.write_bytes(np.random.default_rng(0).integers(0, 256, 4096, dtype=np.uint8).tobytes())
    code, _, err = _model(capsys, f)
    _assert_one_error_line(code, err, "garbage.pcd")


def test_truncated_pcd(scene_files, tmp_path, capsys):
    _, pcd = scene_files
    f = tmp_path / "truncated.pcd"
    f.write_bytes(pcd.read_bytes()[:5000])
    code, _, err = _model(capsys, f)
    _assert_one_error_line(code, err, "truncated.pcd")


@pytest.mark.parametrize("suffix", [".pcd", ".ply", ".npy"])
def test_empty_file(tmp_path, capsys, suffix):
    f = tmp_path / f"empty{suffix}"
    f.write_bytes(b"")
    code, _, err = _model(capsys, f)
    _assert_one_error_line(code, err, f"empty{suffix}: file is empty")


def test_wrong_suffix(tmp_path, capsys):
    f = tmp_path / "cloud.txt"
    f.write_text("0 0 0\n")
    code, _, err = _model(capsys, f)
    _assert_one_error_line(code, err, "unsupported file suffix '.txt'")


def test_npy_of_wrong_shape(tmp_path, capsys):
    f = tmp_path / "flat.npy"
    np.save(f, np.zeros((5, 2)))
    code, _, err = _model(capsys, f, labels_field=None)
    _assert_one_error_line(code, err, "shape (5, 2) is not allowed")


def test_labels_npy_of_wrong_length(tmp_path, capsys):
    pts, labels = tmp_path / "p.npy", tmp_path / "l.npy"
    np.save(pts, np.random.default_rng(0).normal(size=(10, 3)))
    np.save(labels, np.zeros(4, dtype=np.int64))
    code, _, err = _model(capsys, pts, "--labels", labels, labels_field=None)
    _assert_one_error_line(code, err, "must be an (10,) integer array")


def test_labels_npy_of_floats(tmp_path, capsys):
    pts, labels = tmp_path / "p.npy", tmp_path / "l.npy"
    np.save(pts, np.random.default_rng(0).normal(size=(10, 3)))
    np.save(labels, np.zeros(10))
    code, _, err = _model(capsys, pts, "--labels", labels, labels_field=None)
    _assert_one_error_line(code, err, "got float64 (10,)")


def test_labels_file_not_npy(tmp_path, capsys):
    pts, labels = tmp_path / "p.npy", tmp_path / "l.npy"
    np.save(pts, np.random.default_rng(0).normal(size=(10, 3)))
    labels.write_bytes(b"not an npy file")
    code, _, err = _model(capsys, pts, "--labels", labels, labels_field=None)
    _assert_one_error_line(code, err, "cannot read labels")


def test_missing_labels_field(scene_files, capsys):
    _, pcd = scene_files
    code, _, err = _model(capsys, pcd, labels_field="segment")
    _assert_one_error_line(code, err, "input has no field 'segment'; fields: label")


def test_without_labels_the_scene_is_segmented(scene_files, capsys):
    d, pcd = scene_files
    out_json, labels_out = d / "seg.json", d / "seg_labels.npy"
    code, out, err = _model(capsys, pcd, "--labels-out", labels_out, json_out=out_json,
                            labels_field=None)
    assert code == 0, err
    data = json.loads(out_json.read_text())
    assert "segmentation" in data["timing"] and data["timing"]["segmentation"] > 0
    types = sorted(o["type"] for o in data["objects"])
    assert types == ["cuboid", "plane"]  # tiny_box: a box on a desk
    labels = np.load(labels_out)
    assert labels.dtype == np.int32 and labels.ndim == 1
    assert set(np.unique(labels[labels >= 0]).tolist()) == {o["id"] for o in data["objects"]}


def test_unknown_set_parameter(scene_files, capsys):
    _, pcd = scene_files
    code, _, err = _model(capsys, pcd, "--set", "voxelsize=0.004")
    _assert_one_error_line(code, err, "unknown parameter(s) voxelsize")


@pytest.mark.parametrize(("item", "match"), [
    ("voxel_size", "--set expects NAME=VALUE, got 'voxel_size'"),
    ("voxel_size=abc", "--set voxel_size: 'abc' is not a number or true/false"),
])
def test_malformed_set(scene_files, capsys, item, match):
    _, pcd = scene_files
    code, _, err = _model(capsys, pcd, "--set", item)
    _assert_one_error_line(code, err, match)


def test_out_of_range_set(scene_files, capsys):
    d, pcd = scene_files
    out_json = d / "oor.json"
    code, _, err = _model(capsys, pcd, "--set", "voxel_size=-1", json_out=out_json)
    _assert_one_error_line(code, err, "voxel_size")
    assert "[0.0002, 0.2]" in err
    assert not out_json.exists()


def test_invalid_params_yaml(scene_files, tmp_path, capsys):
    _, pcd = scene_files
    bad = tmp_path / "bad.yaml"
    bad.write_text("modeler:\n  ros__parameters: [1, 2\n    voxel_size: :\n")
    code, _, err = _model(capsys, pcd, "--params", bad)
    _assert_one_error_line(code, err, "bad.yaml is not valid YAML")


def test_invalid_params_yaml_exit_code(scene_files, tmp_path, capsys):
    """Whatever its length, the message is an error with status 2 and no traceback."""
    _, pcd = scene_files
    bad = tmp_path / "bad.yaml"
    bad.write_text("modeler:\n  ros__parameters: [1, 2\n    voxel_size: :\n")
    code, _, err = _model(capsys, pcd, "--params", bad)
    assert code == 2
    assert err.startswith("geomodel: error: parameter file ")
    assert "Traceback" not in err


def test_missing_params_yaml(scene_files, tmp_path, capsys):
    _, pcd = scene_files
    code, _, err = _model(capsys, pcd, "--params", tmp_path / "missing.yaml")
    _assert_one_error_line(code, err, "cannot read parameter file")


def test_params_yaml_is_a_directory(scene_files, tmp_path, capsys):
    _, pcd = scene_files
    code, _, err = _model(capsys, pcd, "--params", tmp_path)
    _assert_one_error_line(code, err, "cannot read parameter file")


def test_params_yaml_not_a_mapping(scene_files, tmp_path, capsys):
    _, pcd = scene_files
    f = tmp_path / "list.yaml"
    f.write_text("- voxel_size\n")
    code, _, err = _model(capsys, pcd, "--params", f)
    _assert_one_error_line(code, err, "must hold a mapping, got list")


def test_unwritable_json(scene_files, tmp_path, capsys):
    _, pcd = scene_files
    code, _, err = _model(capsys, pcd, json_out=tmp_path / "no" / "such" / "dir" / "o.json")
    _assert_one_error_line(code, err, "No such file or directory")


def test_labels_field_with_count_two(tmp_path, capsys):
    from geomodel_ros.tools.io import write_pcd

    f = tmp_path / "count2.pcd"
    write_pcd(f, np.random.default_rng(0).normal(size=(10, 3)),
              {"label": np.zeros((10, 2), dtype=np.int32)})
    code, _, err = _model(capsys, f)
    _assert_one_error_line(code, err, "label")
