"""Snapshot of everything the method outputs, to prove a change behaviour-preserving.

``python -m geomodel_ros.tools.regression snapshot OUT.json`` models, with fixed seeds:

- every synthetic scene, noise-free and with sensor noise, from ground-truth labels
  (``model_objects``) and end to end (``model_scene``);
- the 45 osd_learn Kinect frames (segmentation + modeling, ``config/kinect.yaml``);
- the PCL mug scene and the two ``pcl_scenes`` (defaults and ``config/kinect.yaml``);

and stores every object (type, centre, rotation, dimensions, point count, rmse, faces,
reason) and every segmentation (labels as a digest, support planes), without timings.
``python -m geomodel_ros.tools.regression compare A.json B.json`` lists every difference
(floats compared to ``--atol``, default 0: identical) and exits 1 when there is any;
with ``--ignore-timing`` it compares two ``geomodel bench --json`` reports the same way.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import math
import sys
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from geomodel_ros.core.params import ModelingParams, load_params_file
from geomodel_ros.tools.paths import CONFIG_DIR, data_dir

__all__ = ["snapshot", "compare", "main"]

SEED = 1


def _objects(result: Any) -> list[dict]:
    return [o.to_dict() for o in result.objects]


def _labels_digest(labels: np.ndarray) -> dict:
    lab = np.ascontiguousarray(labels, dtype=np.int64)
    return {"sha1": hashlib.sha1(lab.tobytes()).hexdigest(),
            "segments": int(len(np.unique(lab[lab >= 0])))}


def _synthetic(clean: ModelingParams, noisy: ModelingParams) -> dict:
    from geomodel_ros.core.modeling import model_objects, model_scene
    from geomodel_ros.tools.synth import SCENE_NAMES, SENSOR_NOISE, render_scene

    out = {}
    for name in SCENE_NAMES:
        for noise, params in ((None, clean), (SENSOR_NOISE, noisy)):
            scene = render_scene(name, noise=noise, rng=SEED)
            key = f"{name}/{'noisy' if noise else 'clean'}"
            gt = model_objects(scene.points, scene.labels, params)
            labels, seg = model_scene(scene.points, params)
            out[key] = {"ground_truth_labels": _objects(gt), "scene_labels": _labels_digest(labels),
                        "scene": _objects(seg)}
    return out


def _osd(params: ModelingParams) -> dict:
    from geomodel_ros.core.modeling import model_objects
    from geomodel_ros.core.segmentation import segment_scene
    from geomodel_ros.tools.io import load_osd

    out = {}
    for k in range(45):
        points, _ = load_osd(data_dir() / "osd_learn" / f"learn{k}.pcd")
        seg = segment_scene(points.reshape(480, 640, 3), params)
        result = model_objects(points, seg.labels, params, supports=seg.support_planes)
        out[f"learn{k}"] = {
            "labels": _labels_digest(seg.labels),
            "supports": {str(i): [*map(float, n), float(d)] for i, (n, d) in
                         sorted(seg.support_planes.items())},
            "objects": _objects(result)}
    return out


def _real_scenes(params_by_name: dict[str, ModelingParams]) -> dict:
    from geomodel_ros.core.modeling import model_scene
    from geomodel_ros.tools.io import read_cloud

    files = [data_dir() / "pcl_mug" / "table_scene_mug_stereo_textured.pcd",
             *sorted((data_dir() / "pcl_scenes").glob("*.pcd"))]
    out = {}
    for path in files:
        pts = read_cloud(path).points
        for pname, params in params_by_name.items():
            labels, result = model_scene(pts, params)
            out[f"{path.stem}/{pname}"] = {"labels": _labels_digest(labels),
                                           "objects": _objects(result)}
    return out


def snapshot(parts: Sequence[str] = ("synthetic", "osd", "real")) -> dict:
    """Every output of the method on the project's scenes (see the module doc)."""
    defaults = ModelingParams()
    noisy = load_params_file(CONFIG_DIR / "sensor_noise.yaml")
    kinect = load_params_file(CONFIG_DIR / "kinect.yaml")
    out: dict[str, Any] = {}
    if "synthetic" in parts:
        out["synthetic"] = _synthetic(defaults, noisy)
    if "osd" in parts:
        out["osd"] = _osd(kinect)
    if "real" in parts:
        out["real"] = _real_scenes({"defaults": defaults, "kinect": kinect})
    return out


def _is_timing(key: str) -> bool:
    """Keys of ``geomodel bench`` JSON that hold times (``*_s``, ``time*``, peak RSS)."""
    return key.endswith("_s") or key.startswith("time") or key == "peak_rss_mb"


def compare(a: Any, b: Any, atol: float = 0.0, path: str = "",
            ignore_timing: bool = False) -> list[str]:
    """Differences between two snapshots, one line each (empty when they agree).

    With ``ignore_timing`` the timing keys of ``geomodel bench`` JSON files are skipped, so
    two benchmark reports can be compared for identical results.
    """
    if isinstance(a, dict) and isinstance(b, dict):
        keys_a = {k for k in a if not (ignore_timing and _is_timing(k))}
        keys_b = {k for k in b if not (ignore_timing and _is_timing(k))}
        diffs = [f"{path}/{k}: only in the first" for k in sorted(keys_a - keys_b)]
        diffs += [f"{path}/{k}: only in the second" for k in sorted(keys_b - keys_a)]
        for k in sorted(keys_a & keys_b):
            diffs += compare(a[k], b[k], atol, f"{path}/{k}", ignore_timing)
        return diffs
    if isinstance(a, list) and isinstance(b, list):
        if len(a) != len(b):
            return [f"{path}: {len(a)} vs {len(b)} entries"]
        return [d for i, (x, y) in enumerate(zip(a, b))
                for d in compare(x, y, atol, f"{path}[{i}]", ignore_timing)]
    if isinstance(a, float) and isinstance(b, float):
        same = (math.isnan(a) and math.isnan(b)) or abs(a - b) <= atol
        return [] if same else [f"{path}: {a!r} vs {b!r}"]
    return [] if a == b else [f"{path}: {a!r} vs {b!r}"]


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m geomodel_ros.tools.regression",
                                 description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    p = sub.add_parser("snapshot", help="write every output of the method to a JSON file")
    p.add_argument("out")
    p.add_argument("--parts", nargs="+", default=["synthetic", "osd", "real"],
                   choices=["synthetic", "osd", "real"])
    p = sub.add_parser("compare", help="list the differences between two snapshots")
    p.add_argument("first")
    p.add_argument("second")
    p.add_argument("--atol", type=float, default=0.0, help="float tolerance (default: identical)")
    p.add_argument("--ignore-timing", action="store_true",
                   help="skip timing keys (to compare two `geomodel bench --json` reports)")
    args = ap.parse_args(argv)
    if args.cmd == "snapshot":
        Path(args.out).write_text(json.dumps(snapshot(args.parts), indent=1, default=float))
        return 0
    diffs = compare(json.loads(Path(args.first).read_text()),
                    json.loads(Path(args.second).read_text()), args.atol,
                    ignore_timing=args.ignore_timing)
    print("\n".join(diffs[:200]) if diffs else "identical")
    if len(diffs) > 200:
        print(f"... {len(diffs) - 200} more")
    return 1 if diffs else 0


if __name__ == "__main__":
    sys.exit(main())
