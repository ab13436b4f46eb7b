"""Warm time per frame of ``model_scene`` on real and synthetic frames.

Run as ``python -m geomodel_ros.tools.bench_frame [--repeats 5] [--params FILE]`` from a
checkout's root; it prints one JSON object, frame -> median seconds. With ``--stages`` each
frame gives the medians of the whole call and of ``model_scene``'s stages (its ``timing``:
noise estimate, segmentation and its normals / supports / objects, modeling) instead.
``--retain-freed-memory`` first lets the process keep freed memory as the node and the
``geomodel`` CLI do (:func:`geomodel_ros.core.fastmath.retain_freed_memory`), so that
the times are the node's. To compare two versions of the code on one machine, run it
alternately in both checkouts (same data, same parameters) and quote the medians of each
and their ratio.
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

from geomodel_ros.core.fastmath import retain_freed_memory
from geomodel_ros.core.modeling import model_scene
from geomodel_ros.core.params import ModelingParams, load_params_file
from geomodel_ros.tools.io import load_osd
from geomodel_ros.tools.paths import data_dir
from geomodel_ros.tools.synth import SENSOR_NOISE, render_scene

#: osd_learn frames timed (one per scene kind: boxes, stacked, occluded, cylinders).
OSD_FRAMES = (0, 10, 20, 30, 40)


def frames() -> dict[str, np.ndarray]:
    """Frame name -> (N, 3) points [m]: five osd_learn frames and the paper's scene3."""
    out = {f"learn{n}": load_osd(data_dir() / "osd_learn" / f"learn{n}.pcd")[0]
           for n in OSD_FRAMES}
    out["scene3"] = render_scene("scene3").points
    out["scene3_noisy"] = render_scene("scene3", noise=SENSOR_NOISE, rng=1).points
    return out


#: Stages of ``ModelingResult.timing`` reported by ``--stages`` (seconds).
STAGES = ("noise_s", "segmentation_s", "seg_normals_s", "seg_supports_s", "seg_objects_s",
          "modeling_s")


def frame_times(params: ModelingParams, repeats: int) -> dict[str, float]:
    """Median warm seconds of ``model_scene`` per frame (one untimed run first)."""
    return {name: stages["total"] for name, stages in stage_times(params, repeats).items()}


def stage_times(params: ModelingParams, repeats: int) -> dict[str, dict[str, float]]:
    """Median warm seconds per frame of the whole call ("total") and of its STAGES."""
    result = {}
    for name, pts in frames().items():
        model_scene(pts, params)
        runs: dict[str, list[float]] = {key: [] for key in ("total", *STAGES)}
        for _ in range(repeats):
            t0 = time.perf_counter()
            _, res = model_scene(pts, params)
            runs["total"].append(time.perf_counter() - t0)
            for key in STAGES:
                runs[key].append(res.timing.get(key, float("nan")))
        result[name] = {key: float(np.median(v)) for key, v in runs.items()}
    return result


def main(argv: list[str] | None = None) -> int:
    """Print the medians as JSON."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=5, help="timed runs per frame (default 5)")
    ap.add_argument("--params", help="parameters YAML (default: the defaults)")
    ap.add_argument("--stages", action="store_true",
                    help="medians of the total and of every stage per frame")
    ap.add_argument("--retain-freed-memory", action="store_true",
                    help="keep freed memory in the process, as the node and the CLI do")
    args = ap.parse_args(argv)
    if args.retain_freed_memory:
        retain_freed_memory()
    params = load_params_file(args.params) if args.params else ModelingParams()
    times = stage_times(params, args.repeats) if args.stages else \
        frame_times(params, args.repeats)
    print(json.dumps(times))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
