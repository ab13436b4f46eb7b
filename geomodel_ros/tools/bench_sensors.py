"""Real-sensor benchmark with one parameter set: the synthetic suite and the room scene.

Every case of :mod:`geomodel_ros.tools.synth.suite` (each type at 0.5, 1.0, 1.5 m,
noise-free to Kinect-class) and the room scene go end to end through ``model_scene``
(segmentation + modeling) with the default parameters (or ``--set`` overrides). Each
ground-truth object is matched to the segment holding most of its points; it is
*recalled* when that segment's IoU with it is at least :data:`RECALL_IOU` and the segment
is reported as an object; its type is right when the object's type is the expected one
(``unknown`` for the torus); size errors are taken for right types.

Usage::

    python -m geomodel_ros.tools.bench_sensors [--seeds 1 2] [--set noise_model=fixed]
        [--noise-model kinect-real] [--json out.json]
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
from collections import defaultdict
from typing import Sequence

import numpy as np

from geomodel_ros.core.modeling import model_scene
from geomodel_ros.core.params import ModelingParams
from geomodel_ros.tools.cli import parameter_overrides
from geomodel_ros.tools.evaluation import dimension_errors, expected_type, segmentation_scores

__all__ = ["RECALL_IOU", "score_scene", "run_suite", "summary_lines", "main"]

#: A ground-truth object is recalled when its best segment has at least this IoU with it.
RECALL_IOU = 0.5


def score_scene(scene, params: ModelingParams, unsized: tuple[str, ...] = ()) -> list[dict]:
    """Model ``scene`` end to end; one row per ground-truth object (type, recall, errors).

    Objects of the types in ``unsized`` get no size errors (the room's walls and floor
    reach beyond the sensor's view: their true sizes are not observable).
    """
    if params.mixed_pixel_filter:  # the filter needs the image grid: model every pixel
        labels, result = model_scene(scene.organized.reshape(-1, 3), params,
                                     organized_shape=scene.label_image.shape)
        labels = labels[scene.valid_mask.ravel()]
    else:
        labels, result = model_scene(scene.points, params)
    ids = [o.id for o in scene.objects]
    scores = {s.gt_id: s for s in segmentation_scores(labels, scene.labels, ids)}
    by_id = {o.id: o for o in result.objects}
    rows = []
    for gt in scene.objects:
        inter = np.bincount(labels[(scene.labels == gt.id) & (labels >= 0)])
        est = by_id.get(int(np.argmax(inter))) if inter.size else None
        want = expected_type(gt.type)
        recalled = est is not None and scores[gt.id].iou >= RECALL_IOU
        right = recalled and str(est.type) == want
        errs = [abs(e.error) for e in dimension_errors(est, gt)] if right and want not in \
            ("unknown", *unsized) else []
        rows.append({"scene": scene.name, "id": gt.id, "type": want,
                     "estimated": str(est.type) if est is not None else "none",
                     "iou": float(scores[gt.id].iou), "recalled": bool(recalled),
                     "type_correct": bool(right), "size_errors_m": errs,
                     "time_s": result.timing["total_s"], "fragments": result.fragments})
    return rows


def run_suite(params: ModelingParams, seeds: Sequence[int] = (1,), room: bool = True,
              extra_noise: Sequence[str] = ()) -> list[dict]:
    """Rows of :func:`score_scene` over every suite case (and the room scene).

    ``extra_noise`` adds levels of ``OPTIONAL_NOISE`` beside the suite's own.
    """
    from geomodel_ros.tools.synth.scenes import room_scene
    from geomodel_ros.tools.synth.suite import SUITE_NOISE, render_case, suite_cases

    rows = []
    for case in suite_cases(tuple(seeds), (*SUITE_NOISE, *extra_noise)):
        for r in score_scene(render_case(case), params):
            rows.append({**r, "noise": case.noise, "distance": case.distance,
                         "seed": case.seed})
    if room:
        for seed in seeds:
            for r in score_scene(room_scene(rng=seed), params, unsized=("plane",)):
                rows.append({**r, "noise": "laser", "distance": "1-9", "seed": seed})
    return rows


def summary_lines(rows: list[dict]) -> list[str]:
    """Per noise level: type accuracy per type, recall, median and max size error [mm]."""
    types = sorted({r["type"] for r in rows})
    w = max(7, *(len(r["noise"]) for r in rows))
    lines = [f"{'noise':<{w}} " + " ".join(f"{t:>10}" for t in types)
             + f" {'recall':>8} {'size err mm median/max':>23} {'s/frame':>8}"]
    by_noise: dict[str, list[dict]] = defaultdict(list)
    for r in rows:
        by_noise[r["noise"]].append(r)
    for noise, rs in by_noise.items():
        cells = []
        for t in types:
            of = [r for r in rs if r["type"] == t]
            cells.append(f"{sum(r['type_correct'] for r in of):>4}/{len(of):<5}" if of
                         else f"{'-':>10}")
        errs = [1000 * e for r in rs for e in r["size_errors_m"]] or [float("nan")]
        times = {r["scene"]: r["time_s"] for r in rs}
        lines.append(f"{noise:<{w}} " + " ".join(cells)
                     + f" {sum(r['recalled'] for r in rs) / len(rs):>8.3f}"
                     f" {np.median(errs):>11.3f} /{np.max(errs):>9.3f}"
                     f" {statistics.median(times.values()):>8.2f}")
    return lines


def main(argv: Sequence[str] | None = None) -> int:
    """Run the suite and print its summary (``--json`` writes every row)."""
    from geomodel_ros.tools.synth.suite import OPTIONAL_NOISE

    ap = argparse.ArgumentParser(prog="python -m geomodel_ros.tools.bench_sensors",
                                 description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[1])
    ap.add_argument("--set", action="append", default=[], metavar="NAME=VALUE",
                    help="parameter override (default: every parameter at its default)")
    ap.add_argument("--no-room", action="store_true", help="skip the room scene")
    ap.add_argument("--noise-model", action="append", default=[], choices=sorted(OPTIONAL_NOISE),
                    help="also run the suite with this noise model (correlated range error "
                         "and disparity quantisation calibrated on real Kinect frames)")
    ap.add_argument("--json", help="write every row here")
    args = ap.parse_args(argv)
    params = ModelingParams.from_mapping(parameter_overrides(args.set))
    rows = run_suite(params, args.seeds, room=not args.no_room, extra_noise=args.noise_model)
    print("\n".join(summary_lines(rows)))
    wrong = [r for r in rows if not r["type_correct"]]
    for r in wrong:
        print(f"  {r['scene']} seed {r['seed']} id {r['id']}: {r['type']} -> {r['estimated']} "
              f"(IoU {r['iou']:.2f})")
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(rows, fh, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
