"""Warm time per frame of ``model_scene`` on real and synthetic frames.

Run as ``python -m geomodel_ros.tools.bench_frame [--repeats 5] [--params FILE]`` from a
checkout's root; it prints one JSON object, frame -> median seconds. To compare two versions
of the code on one machine, run it alternately in both checkouts (same data, same
parameters) and quote the medians of each and their ratio.
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

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


def frame_times(params: ModelingParams, repeats: int) -> dict[str, float]:
    """Median warm seconds of ``model_scene`` per frame (one untimed run first)."""
    result = {}
    for name, pts in frames().items():
        model_scene(pts, params)
        times = []
        for _ in range(repeats):
            t0 = time.perf_counter()
            model_scene(pts, params)
            times.append(time.perf_counter() - t0)
        result[name] = float(np.median(times))
    return result


def main(argv: list[str] | None = None) -> int:
    """Print the medians as JSON."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=5, help="timed runs per frame (default 5)")
    ap.add_argument("--params", help="parameters YAML (default: the defaults)")
    args = ap.parse_args(argv)
    params = load_params_file(args.params) if args.params else ModelingParams()
    print(json.dumps(frame_times(params, args.repeats)))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
