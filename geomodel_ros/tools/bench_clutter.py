"""Segmentation in clutter: figures over seeded synthetic clutter scenes (and osd_learn).

``python -m geomodel_ros.tools.bench_clutter --scenes 20`` renders clutter scenes 0..19
(:mod:`geomodel_ros.tools.synth.clutter`), noise-free and with Kinect-class noise,
segments them and prints the share of objects segmented with IoU >= 0.8, under- and
over-segmented (:func:`geomodel_ros.tools.evaluation.segmentation_scores`), in all and per
object kind, and the segmentation time. ``--osd`` adds the osd_learn figure
(:func:`geomodel_ros.tools.benchmark.osd_benchmark`, segmentation only);
``--noise-model kinect-real`` (or ``kinect-class``) adds the scenes under that noise model
(``KINECT_REAL_NOISE``: correlated error and quantisation calibrated on real frames).
``--camera hd720`` renders the scenes at 1280 x 720 with the Kinect's field of view across
(twice its pixels per degree); with ``decimation`` > 1 in ``--params`` every frame is
segmented from its samples and every pixel labelled from them
(:mod:`geomodel_ros.core.decimation`), as ``model_scene`` does. ``--types`` models every
frame (``model_scene``: segmentation and modeling) and adds the types: per kind, how many
of the objects segmented with IoU >= 0.8 got the type their kind must get (:data:`KIND_TYPES`)
and what the others got.
"""

from __future__ import annotations

import argparse
import json
import math
import statistics
import time
from collections import Counter, defaultdict
from pathlib import Path
from typing import Sequence

import numpy as np

from geomodel_ros.core.modeling import model_scene
from geomodel_ros.core.params import ModelingParams, load_params_file
from geomodel_ros.tools.evaluation import dimension_errors, segment_frame, segmentation_scores
from geomodel_ros.tools.paths import CONFIG_DIR
from geomodel_ros.tools.synth.camera import PinholeCamera
from geomodel_ros.tools.synth.clutter import (CAMERA_ELEVATION, KINECT_CAMERA, KINECT_NOISE,
                                              render_clutter)
from geomodel_ros.tools.synth.scenes import (KINECT_CLASS_NOISE, KINECT_REAL_NOISE,
                                             MIXED_EDGE_NOISE, NoiseModel)

#: Noise models run on request (``--noise-model``), beside the default rows: Kinect-class
#: i.i.d. noise, the same with the correlated error and quantisation of real frames, and
#: with mixed pixels at the depth edges (a time-of-flight camera's flying pixels).
OPTIONAL_NOISE = {"kinect-class": KINECT_CLASS_NOISE, "kinect-real": KINECT_REAL_NOISE,
                  "kinect-mixed": MIXED_EDGE_NOISE}

__all__ = ["clutter_rows", "clutter_lines", "desk_pieces", "main", "MIN_SCORED_POINTS",
           "GOOD_IOU", "KIND_TYPES", "type_lines"]

#: Objects with fewer visible points are not scored: slivers at the image border or
#: behind other objects (200 points are about 1 cm^2 at 1 m, close to the segmentation's
#: smallest object, ``seg_min_cluster_points`` = 150).
MIN_SCORED_POINTS = 200
#: An object counts as well segmented at this IoU (the project's osd_learn criterion).
GOOD_IOU = 0.8


#: The types an object of each clutter kind must be modeled as. A cup's rim is 1.0-1.3 times
#: its bottom radius (a wall 0-12 deg off its axis over its height): a cylinder or a frustum.
KIND_TYPES = {"box": ("cuboid",), "can": ("cylinder",), "lying_can": ("cylinder",),
              "sphere": ("sphere",), "cone": ("cone",), "cup": ("cylinder", "frustum"),
              "bowl": ("frustum",)}


#: Cameras the scenes can be rendered with (``--camera``): the Kinect's 640 x 480 and a
#: 1280 x 720 camera with the Kinect's horizontal field of view (twice its pixels per degree).
CAMERAS = {"kinect": KINECT_CAMERA,
           "hd720": PinholeCamera(fx=1050.0, fy=1050.0, cx=639.5, cy=359.5, width=1280,
                                  height=720)}


def clutter_rows(seeds: Sequence[int], noisy: bool | NoiseModel, params: ModelingParams,
                 camera: PinholeCamera = KINECT_CAMERA, types: bool = False,
                 elevation: tuple[float, float] = CAMERA_ELEVATION) -> list[dict]:
    """Segment the clutter scenes ``seeds``; one row per scored object.

    ``elevation``: the range [rad] of the camera's elevation above the desk (the same
    objects seen from another height, :func:`~geomodel_ros.tools.synth.clutter.
    clutter_layout`).

    ``noisy``: True for the clutter's KINECT_NOISE, False for none, or a NoiseModel.
    Objects with fewer than MIN_SCORED_POINTS pixels of a 640 x 480 frame (more in
    proportion for a finer ``camera``) are not scored.

    Each row holds ``seed``, ``id``, ``kind``, ``points``, ``iou``, ``under``, ``over``, the
    scene's ``segmentation_s`` and its ``desk_pieces``: segments reported as objects (not
    supports) whose points are mostly the desk's (:func:`desk_pieces`). With ``types`` each
    frame is modeled (``model_scene``, whose labels are its objects' ids) and each row also
    holds ``type``, the type of the object of the best-matching segment ("none" when its
    points are all noise), and ``size_errors``, its absolute size errors [m] where that
    type is the object's true type (:func:`~geomodel_ros.tools.evaluation.dimension_errors`);
    ``segmentation_s`` is then the segmentation's share of the frame.
    """
    rows = []
    for seed in seeds:
        noise = noisy if isinstance(noisy, NoiseModel) else (KINECT_NOISE if noisy else None)
        scene = render_clutter(seed, noise, camera, elevation)
        model_of: dict = {}
        if types:
            labels, result = model_scene(scene.organized, params)
            seconds = result.timing["segmentation_s"]
            support_ids = list(result.supports)
            model_of = {o.id: o for o in result.objects}
        else:
            t0 = time.perf_counter()
            seg = segment_frame(scene.organized, params)
            seconds = time.perf_counter() - t0
            labels, support_ids = seg.labels, seg.support_ids
        gt = scene.label_image.ravel()
        counts = np.bincount(gt[gt >= 0], minlength=len(scene.kinds))
        least = MIN_SCORED_POINTS * camera.width * camera.height / (640 * 480)
        ids = [i for i in range(1, len(scene.kinds)) if counts[i] >= least]
        pieces = desk_pieces(labels, gt, support_ids)
        for s in segmentation_scores(labels, gt, ids):
            row = {"seed": seed, "id": s.gt_id, "kind": scene.kinds[s.gt_id],
                   "points": int(counts[s.gt_id]), "iou": s.iou, "under": s.under,
                   "over": s.over, "segmentation_s": seconds, "desk_pieces": pieces}
            if types:
                est = model_of.get(s.segment)
                row["type"] = est.type if est is not None else "none"
                errors = [] if est is None else dimension_errors(est, scene.objects[s.gt_id])
                row["size_errors"] = [abs(e.estimate - e.true) for e in errors]
            rows.append(row)
    return rows


def desk_pieces(labels: np.ndarray, gt: np.ndarray, support_ids: Sequence[int]) -> int:
    """Count the segments, supports left out, whose labelled points are mostly desk (gt 0)."""
    seen = (labels >= 0) & (gt >= 0)
    objects = seen & ~np.isin(labels, list(support_ids))
    if not objects.any():
        return 0
    n = int(labels[objects].max()) + 1
    desk = np.bincount(labels[objects], weights=gt[objects] == 0, minlength=n)
    total = np.bincount(labels[objects], minlength=n)
    return int(np.count_nonzero(desk > 0.5 * total))


def _figures(rows: list[dict]) -> str:
    n = len(rows)
    if not n:
        return "no objects"
    good = sum(r["iou"] >= GOOD_IOU for r in rows)
    under = sum(r["under"] for r in rows)
    over = sum(r["over"] for r in rows)
    return (f"{n:>4} objects  IoU>=0.8 {100 * good / n:5.1f} %  under {100 * under / n:5.1f} %"
            f"  over {100 * over / n:5.1f} %")


def clutter_lines(rows: list[dict], label: str) -> list[str]:
    """Summary lines of :func:`clutter_rows`: all objects, then per kind."""
    lines = [f"{label}: {_figures(rows)}"]
    by_kind = defaultdict(list)
    for r in rows:
        by_kind[r["kind"]].append(r)
    for kind in sorted(by_kind):
        lines.append(f"  {kind:<10} {_figures(by_kind[kind])}")
    pieces = {r["seed"]: r.get("desk_pieces", 0) for r in rows}
    if pieces:
        lines.append(f"  desk pieces reported as objects: {sum(pieces.values())} in "
                     f"{sum(v > 0 for v in pieces.values())} of {len(pieces)} scenes")
    times = sorted({(r["seed"], r["segmentation_s"]) for r in rows})
    if times:
        secs = [t for _, t in times]
        lines.append(f"  segmentation s per frame: median {statistics.median(secs):.3f}, "
                     f"max {max(secs):.3f}")
    return lines


def type_lines(rows: list[dict]) -> list[str]:
    """Per kind: objects segmented with IoU >= 0.8 that got their kind's type, and the rest."""
    good = [r for r in rows if "type" in r and r["iou"] >= GOOD_IOU]
    if not good:
        return []
    right = sum(r["type"] in KIND_TYPES[r["kind"]] for r in good)
    errors = [e for r in good for e in r["size_errors"]]
    lines = [f"  types of the {len(good)} objects at IoU >= 0.8: {right} right "
             f"({100 * right / len(good):.1f} %); size errors where typed as they are: "
             f"median {_mm(errors, 50)}, p90 {_mm(errors, 90)} mm ({len(errors)} sizes)"]
    by_kind = defaultdict(list)
    for r in good:
        by_kind[r["kind"]].append(r["type"])
    for kind in sorted(by_kind):
        got = by_kind[kind]
        ok = sum(t in KIND_TYPES[kind] for t in got)
        wrong = Counter(t for t in got if t not in KIND_TYPES[kind])
        rest = ", ".join(f"{t} {n}" for t, n in wrong.most_common())
        errs = [e for r in good if r["kind"] == kind for e in r["size_errors"]]
        lines.append(f"    {kind:<10} {ok:>4} / {len(got):<4} {'/'.join(KIND_TYPES[kind])}"
                     f"{'  (' + rest + ')' if rest else ''}; sizes median {_mm(errs, 50)}, "
                     f"p90 {_mm(errs, 90)} mm")
    return lines


def _mm(errors: list[float], percentile: float) -> str:
    return f"{1e3 * float(np.percentile(errors, percentile)):.1f}" if errors else "-"



def _osd_lines(params: ModelingParams) -> list[str]:
    from geomodel_ros.tools.benchmark import osd_benchmark

    rows = osd_benchmark(params, model=False)
    scores = [s for r in rows for s in r["scores"]]
    good = sum(s[1] >= GOOD_IOU for s in scores)
    under = sum(s[2] for s in scores)
    secs = [r["segmentation_s"] for r in rows]
    return [f"osd_learn: {len(scores)} objects  IoU>=0.8 {good} ({100 * good / len(scores):.1f}"
            f" %)  under {under}  segmentation s median {statistics.median(secs):.3f}"]


def main(argv: list[str] | None = None) -> int:
    """Run the benchmark and print its figures; return the exit status."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", type=int, default=20, help="number of seeds (0 ..)")
    parser.add_argument("--first", type=int, default=0, help="first seed")
    parser.add_argument("--noise", choices=("both", "clean", "kinect"), default="both")
    parser.add_argument("--noise-model", action="append", default=[],
                        choices=sorted(OPTIONAL_NOISE),
                        help="also run the scenes with this noise model (kinect-real: "
                             "correlated error and quantisation calibrated on real frames)")
    parser.add_argument("--params", type=Path, default=None,
                        help="parameter YAML for the clutter scenes (default: defaults)")
    parser.add_argument("--osd", action="store_true",
                        help="also osd_learn (config/kinect.yaml, as `geomodel bench`)")
    parser.add_argument("--camera", choices=sorted(CAMERAS), default="kinect",
                        help="render the scenes with this camera (default: kinect, 640 x 480)")
    parser.add_argument("--elevation", type=float, nargs=2, metavar=("LO", "HI"),
                        default=None,
                        help="camera elevation above the desk drawn in [LO, HI] degrees "
                             "(default 25 75; the same objects for any range)")
    parser.add_argument("--json", type=Path, default=None, help="write the rows here")
    parser.add_argument("--failures", action="store_true", help="list objects with IoU < 0.8")
    parser.add_argument("--types", action="store_true",
                        help="model every frame and score the types of the objects segmented "
                             "with IoU >= 0.8")
    args = parser.parse_args(argv)
    params = load_params_file(args.params) if args.params else ModelingParams()
    seeds = range(args.first, args.first + args.scenes)
    elevation = CAMERA_ELEVATION
    if args.elevation is not None:
        if not 0.0 < args.elevation[0] <= args.elevation[1] <= 90.0:
            parser.error("--elevation needs 0 < LO <= HI <= 90 [deg]")
        elevation = (math.radians(args.elevation[0]), math.radians(args.elevation[1]))
    report = {}
    runs = [("kinect-noise" if noisy else "noise-free", noisy)
            for noisy in {"both": (False, True), "clean": (False,), "kinect": (True,)}[args.noise]]
    runs += [(f"{name}-noise", OPTIONAL_NOISE[name]) for name in args.noise_model]
    for label, noisy in runs:
        rows = report[label] = clutter_rows(seeds, noisy, params, CAMERAS[args.camera],
                                            args.types, elevation)
        print("\n".join(clutter_lines(rows, f"clutter {label}") + type_lines(rows)))
        if args.failures:
            for r in rows:
                if r["iou"] < GOOD_IOU or r["under"]:
                    print(f"    seed {r['seed']:>3} id {r['id']:>2} {r['kind']:<10} "
                          f"{r['points']:>6} pts IoU {r['iou']:.3f}"
                          f"{' under' if r['under'] else ''}{' over' if r['over'] else ''}")
                elif args.types and r["type"] not in KIND_TYPES[r["kind"]]:
                    print(f"    seed {r['seed']:>3} id {r['id']:>2} {r['kind']:<10} "
                          f"{r['points']:>6} pts IoU {r['iou']:.3f} typed {r['type']}")
    if args.osd:
        print("\n".join(_osd_lines(load_params_file(CONFIG_DIR / "kinect.yaml"))))
    if args.json:
        args.json.write_text(json.dumps(report, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
