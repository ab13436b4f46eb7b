"""Room scale through a depth camera: the synthetic office, segmented and modeled.

``python -m geomodel_ros.tools.bench_office [--noise none kinect-class kinect-real]
[--seeds 1 2] [--params FILE] [--json OUT]`` renders the office of
:mod:`geomodel_ros.tools.synth.office` (floor, back wall 3-4 m away with a door 3 cm proud
of it, side wall, two boxes on the floor at 2 and 2.6 m; walls at 3, 3.5 and 4 m, camera
yaw 0 and 20 deg) under each noise model, models every frame with ``model_scene`` (the
organized cloud, defaults unless ``--params``) and prints per object of the scene: how
many of its views were segmented with IoU >= 0.8, under-segmented (its best segment holds
more than a fifth of another object), how many reported objects it is split into (objects
of which it holds most points; 1 per view is whole), and the types of its best segments.
"""

from __future__ import annotations

import argparse
import json
from collections import Counter
from pathlib import Path
from typing import Sequence

import numpy as np

from geomodel_ros.core.modeling import model_scene
from geomodel_ros.core.params import ModelingParams, load_params_file
from geomodel_ros.tools.evaluation import segmentation_scores
from geomodel_ros.tools.synth.office import (OFFICE_DISTANCES, OFFICE_NAMES, OFFICE_YAWS,
                                             office_scene)
from geomodel_ros.tools.synth.scenes import KINECT_CLASS_NOISE, KINECT_REAL_NOISE, NoiseModel

__all__ = ["office_rows", "office_lines", "main"]

#: Noise models by name (``none``: the exact cloud).
NOISE = {"none": None, "kinect-class": KINECT_CLASS_NOISE, "kinect-real": KINECT_REAL_NOISE}
#: Objects with fewer visible points are not scored (as in the clutter benchmark).
MIN_SCORED_POINTS = 200
#: IoU of a well segmented object.
GOOD_IOU = 0.8


def office_rows(noise: NoiseModel | None, seeds: Sequence[int], params: ModelingParams
                ) -> list[dict]:
    """One row per object and view: view, object, IoU, under, over, parts, best type."""
    rows = []
    for distance in OFFICE_DISTANCES:
        for yaw in OFFICE_YAWS:
            for seed in seeds:
                scene = office_scene(distance, yaw, noise, rng=seed)
                truth = scene.label_image.ravel()
                labels, result = model_scene(scene.organized.reshape(-1, 3), params,
                                             organized_shape=scene.label_image.shape)
                types = {o.id: str(o.type) for o in result.objects}
                ids = [g for g in range(len(OFFICE_NAMES))
                       if np.count_nonzero(truth == g) >= MIN_SCORED_POINTS]
                # For every reported object, the true object holding most of its points.
                valid = (labels >= 0) & (truth >= 0)
                pairs = np.unique(np.stack([labels[valid], truth[valid]]), axis=1,
                                  return_counts=True)
                owner: dict[int, tuple[int, int]] = {}
                for (obj, gt), n in zip(pairs[0].T, pairs[1]):
                    if n > owner.get(int(obj), (-1, 0))[1]:
                        owner[int(obj)] = (int(gt), int(n))
                for score in segmentation_scores(labels, truth, ids):
                    own = labels[truth == score.gt_id]
                    own = own[own >= 0]
                    best = int(np.bincount(own).argmax()) if len(own) else -1
                    rows.append({"wall_m": distance, "yaw_deg": yaw, "seed": seed,
                                 "object": OFFICE_NAMES[score.gt_id], "iou": score.iou,
                                 "under": score.under, "over": score.over,
                                 "parts": sum(1 for g, _ in owner.values()
                                              if g == score.gt_id),
                                 "type": types.get(best, "none")})
    return rows


def office_lines(name: str, rows: list[dict]) -> list[str]:
    """Summary lines of one noise model's rows, per object."""
    views = {(r["wall_m"], r["yaw_deg"], r["seed"]) for r in rows}
    lines = [f"office {name}: {len(views)} views"]
    for obj in OFFICE_NAMES:
        mine = [r for r in rows if r["object"] == obj]
        if not mine:
            continue
        good = sum(r["iou"] >= GOOD_IOU for r in mine)
        under = sum(r["under"] for r in mine)
        parts = sum(r["parts"] for r in mine)
        types = ", ".join(f"{t} {n}" for t, n in Counter(r["type"] for r in mine).most_common())
        lines.append(f"  {obj:10s} views {len(mine):3d}  IoU>=0.8 {good:3d}  under {under:3d}  "
                     f"reported objects {parts:4d}  best segment types: {types}")
    return lines


def main(argv: list[str] | None = None) -> int:
    """Print the office figures; return the exit status."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--noise", nargs="+", choices=sorted(NOISE),
                    default=["none", "kinect-class", "kinect-real"], help="noise models")
    ap.add_argument("--seeds", nargs="+", type=int, default=[1, 2], help="noise seeds")
    ap.add_argument("--params", help="parameters YAML (default: the defaults)")
    ap.add_argument("--json", type=Path, help="write every row here")
    args = ap.parse_args(argv)
    params = load_params_file(args.params) if args.params else ModelingParams()
    out = {}
    for name in args.noise:
        rows = office_rows(NOISE[name], args.seeds if NOISE[name] is not None else [0],
                           params)
        out[name] = rows
        print("\n".join(office_lines(name, rows)), flush=True)
    if args.json:
        args.json.write_text(json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
