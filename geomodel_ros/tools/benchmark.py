"""Benchmarks of modeling accuracy, speed and segmentation quality.

Modeling accuracy and speed on the paper's synthetic scenes, segmentation quality on real
Kinect data (osd_learn) and the PCL mug scene.

Run through ``geomodel bench`` (``make bench``); figures go to BENCHMARKS.md. Nothing here
is used by tests as a timing assertion.
"""

from __future__ import annotations

import resource
import statistics
import time
from typing import Sequence

import numpy as np

from geomodel_ros.tools.evaluation import score_objects, segment_frame, segmentation_scores
from geomodel_ros.core.params import ModelingParams
from geomodel_ros.tools.paths import data_dir

__all__ = ["figure9_table", "run_benchmark", "summary_lines", "data_dir", "osd_benchmark",
           "osd_lines", "osd_type_lines", "mug_benchmark", "synthetic_segmentation", "peak_rss_mb"]


def peak_rss_mb() -> float:
    """Peak resident set size of this process so far [MiB]."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def _fmt_dims(errors, which: str) -> str:
    return ", ".join(f"{e.name[0].upper()}={getattr(e, which) * 1000:.3f}" for e in errors)


def figure9_table(scene, result) -> str:
    """Figure-9-style table: object, type, true size, estimate, error [mm]."""
    lines = [f"{'id':>3} {'true type':<9} {'modeled':<9} {'true size (mm)':<28} "
             f"{'estimate (mm)':<30} {'error (mm)':<24}"]
    for s in score_objects(result.objects, scene.objects):
        gt = next(o for o in scene.objects if o.id == s.gt_id)
        true = _fmt_dims(s.errors, "true") if s.errors else \
            ", ".join(f"{k[0].upper()}={v * 1000:.3f}" for k, v in gt.dimensions.items())
        est = _fmt_dims(s.errors, "estimate") if s.errors else "-"
        err = ", ".join(f"{e.error * 1000:+.3f}" for e in s.errors) if s.errors else "-"
        mark = "" if s.type_correct else "  <- type wrong"
        lines.append(f"{s.gt_id:>3} {s.true_type:<9} {s.estimated:<9} {true:<28} {est:<30} "
                     f"{err:<24}{mark}")
    return "\n".join(lines)


def run_benchmark(scenes: Sequence[str], repeats: int, noisy_params: ModelingParams,
                  clean_params: ModelingParams, seed: int = 1) -> dict:
    """Accuracy and parameter-extraction time over scenes, noise-free and noisy."""
    from geomodel_ros.core.modeling import model_objects
    from geomodel_ros.tools.synth import SENSOR_NOISE, render_scene

    report: dict = {"runs": []}
    for noisy in (False, True):
        params = noisy_params if noisy else clean_params
        for name in scenes:
            scene = render_scene(name, noise=SENSOR_NOISE if noisy else None, rng=seed)
            times, result = [], None
            points, labels = scene.points, scene.labels  # (computed properties: not timed)
            for _ in range(repeats):
                t0 = time.perf_counter()
                result = model_objects(points, labels, params)
                times.append(time.perf_counter() - t0)
            scores = score_objects(result.objects, scene.objects)
            errs = [abs(e.error) for s in scores for e in s.errors]
            report["runs"].append({
                "scene": name, "noisy": noisy, "points": int(len(scene.points)),
                "objects": len(scene.objects),
                "type_correct": sum(s.type_correct for s in scores),
                "size_errors_mm": [e * 1000 for e in errs],
                "time_median_s": statistics.median(times),
                "table": figure9_table(scene, result) if name == "scene3" else None,
            })
    return report


def summary_lines(report: dict) -> list[str]:
    lines = [f"{'scene':<8} {'noise':<6} {'points':>7} {'types':>7} "
             f"{'size err mm mean/median/max':>28} {'extract s (median)':>19}"]
    for noisy in (False, True):
        runs = [r for r in report["runs"] if r["noisy"] == noisy]
        for r in runs:
            e = r["size_errors_mm"] or [float("nan")]
            lines.append(f"{r['scene']:<8} {'noisy' if noisy else 'clean':<6} {r['points']:>7} "
                         f"{r['type_correct']:>3}/{r['objects']:<3} "
                         f"{np.mean(e):>9.3f} /{np.median(e):>7.3f} /{np.max(e):>7.3f} "
                         f"{r['time_median_s']:>19.3f}")
        if runs:
            allerr = [x for r in runs for x in r["size_errors_mm"]] or [float("nan")]
            correct = sum(r["type_correct"] for r in runs)
            total = sum(r["objects"] for r in runs)
            lines.append(f"{'all':<8} {'noisy' if noisy else 'clean':<6} {'':>7} "
                         f"{correct:>3}/{total:<3} {np.mean(allerr):>9.3f} "
                         f"/{np.median(allerr):>7.3f} /{np.max(allerr):>7.3f} {'':>19}   "
                         f"type accuracy {100 * correct / total:.1f}%")
    return lines




# ---------------------------------------------------------------------------------------
# Segmentation
# ---------------------------------------------------------------------------------------

#: Labelled frames of osd_learn (learn0.pcd .. learn44.pcd).
OSD_SCENE_COUNT = 45
#: osd_learn scene groups (see the data README).
OSD_GROUPS = {"boxes": range(0, 17), "stacked": range(17, 25), "occluded": range(25, 33),
              "cylinders": range(33, 45)}


def _groups_and_all() -> dict[str, range]:
    """:data:`OSD_GROUPS` and the group ``all`` of every scene."""
    return {**OSD_GROUPS, "all": range(0, OSD_SCENE_COUNT)}


def osd_benchmark(params: ModelingParams, scenes: Sequence[int] = tuple(range(OSD_SCENE_COUNT)),
                  model: bool = True) -> list[dict]:
    """Segment (and model) osd_learn scenes; per-scene IoU scores and timings."""
    from geomodel_ros.tools.io import load_osd
    from geomodel_ros.core.modeling import model_objects

    rows = []
    for k in scenes:
        path = data_dir() / "osd_learn" / f"learn{k}.pcd"
        points, gt = load_osd(path)
        organized = points.reshape(480, 640, 3)
        t0 = time.perf_counter()
        seg = segment_frame(organized, params)
        t1 = time.perf_counter()
        objects = [int(g) for g in np.unique(gt) if g >= 2]
        scores = segmentation_scores(seg.labels, gt, objects)
        row = {"scene": k, "objects": len(objects), "segmentation_s": t1 - t0,
               "scores": [(s.gt_id, s.iou, s.under, s.over, s.parts_iou) for s in scores]}
        if model:
            result = model_objects(points, seg.labels, params, supports=seg.support_planes,
                                   noise=seg.noise)
            row["total_s"] = time.perf_counter() - t0
            row["types"] = {o.id: o.type for o in result.objects}
            row["dimensions"] = {o.id: dict(o.dimensions) for o in result.objects}
            row["object_types"] = _best_segment_types(seg.labels, gt, objects, row["types"])
            row["cuboid_stretch"] = _cuboid_stretch(points, seg.labels, result.objects)
            row["completed"] = {str(o.id): list(o.completed) for o in result.objects
                                if o.completed}
        rows.append(row)
    return rows


def _best_segment_types(labels: np.ndarray, gt: np.ndarray, objects: list[int],
                        types: dict[int, str]) -> dict[int, str]:
    """Return the modeled type of each ground-truth object's best segment.

    The best segment has the highest IoU with the object; ``none`` when no segment touches
    it.
    """
    out = {}
    seg_sizes = np.bincount(labels[labels >= 0]) if (labels >= 0).any() else np.zeros(0)
    for g in objects:
        mask = gt == g
        ids, inter = np.unique(labels[mask & (labels >= 0)], return_counts=True)
        if not len(ids):
            out[g] = "none"
            continue
        iou = inter / (mask.sum() + seg_sizes[ids] - inter)
        out[g] = types.get(int(ids[np.argmax(iou)]), "none")
    return out


def _cuboid_stretch(points: np.ndarray, labels: np.ndarray, objects) -> list[float]:
    """Return, per cuboid, its largest observed side over its points' extent along that axis.

    The extent is the 1st-99th percentile of its own segment's points; 1 = as long as the
    points, 1.5 = half again. Sides completed down to the support (``completed``) reach
    beyond the points by design and are left out.
    """
    out = []
    names = ("length", "width", "height")
    for o in objects:
        if o.type != "cuboid":
            continue
        local = (points[labels == o.id] - o.center) @ o.rotation
        lo, hi = np.percentile(local, [1.0, 99.0], axis=0)
        ratio = [o.dimensions[n] / max(h - l_, 1e-3) for n, l_, h in zip(names, lo, hi)
                 if n not in o.completed]
        out.append(float(max(ratio, default=1.0)))
    return out


def osd_type_lines(rows: list[dict]) -> list[str]:
    """Per group: how the labelled objects (their best-matching segments) were modeled."""
    kinds = ("plane", "cuboid", "cylinder", "cone", "sphere", "frustum", "unknown", "none")
    lines = [f"{'group':<10} " + " ".join(f"{k:>8}" for k in kinds)]
    for name, members in _groups_and_all().items():
        ts = [t for r in rows if r["scene"] in members for t in r.get("object_types", {}).values()]
        if ts:
            lines.append(f"{name:<10} " + " ".join(f"{ts.count(k):>8}" for k in kinds))
    stretch = [v for r in rows for v in r.get("cuboid_stretch", [])]
    if stretch:
        lines.append(f"cuboids (all segments): {len(stretch)}, longer than 1.3x their points "
                     f"along an observed axis: {sum(v > 1.3 for v in stretch)}, most: "
                     f"{max(stretch):.2f}x")
    completed = [o for r in rows for o in r.get("completed", {}).values()]
    lines.append(f"objects with a size completed down to the support: {len(completed)}")
    return lines


def osd_lines(rows: list[dict]) -> list[str]:
    """Per-group summary of :func:`osd_benchmark` rows."""
    lines = [f"{'group':<10} {'scenes':>6} {'objects':>7} {'IoU>=0.8':>9} {'under':>6} "
             f"{'over':>5} {'mean IoU':>9} {'parts IoU>=0.8':>15} {'seg s (median)':>15} "
             f"{'seg+model s':>12}"]
    for name, members in _groups_and_all().items():
        rs = [r for r in rows if r["scene"] in members]
        if not rs:
            continue
        sc = [s for r in rs for s in r["scores"]]
        n = len(sc)
        good = sum(s[1] >= 0.8 for s in sc)
        under = sum(s[2] for s in sc)
        over = sum(s[3] for s in sc)
        seg_t = statistics.median(r["segmentation_s"] for r in rs)
        tot = [r["total_s"] for r in rs if "total_s" in r]
        tot_t = f"{statistics.median(tot):12.3f}" if tot else f"{'-':>12}"
        parts = sum(s[4] >= 0.8 for s in sc)
        lines.append(f"{name:<10} {len(rs):>6} {n:>7} {100 * good / n:>8.1f}% "
                     f"{100 * under / n:>5.1f}% {100 * over / n:>4.1f}% "
                     f"{np.mean([s[1] for s in sc]):>9.3f} {100 * parts / n:>14.1f}% "
                     f"{seg_t:>15.3f} {tot_t}")
    return lines


#: PCL cylinder-segmentation tutorial's answer for the mug scene.
MUG_AXIS = np.array([0.20495, -0.721649, -0.661225])
MUG_POINT = np.array([0.0452105, 0.0924601, 0.790215])
MUG_RADIUS = 0.0396354
MUG_TABLE = np.array([-0.0161854, 0.837724, 0.545855, -0.528787])
#: Points within this distance [m] of the tutorial's axis line and this far [m] from its
#: table plane: the mug chosen without our segmentation.
MUG_SELECT_RADIUS = 0.06
MUG_SELECT_HEIGHT = (0.01, 0.2)


def _line_angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    """Angle [deg] between the lines along unit vectors ``a`` and ``b`` (3,), in [0, 90]."""
    return float(np.degrees(np.arccos(min(1.0, abs(float(a @ b))))))


def _radial_quartiles(points: np.ndarray, center: np.ndarray, direction: np.ndarray
                      ) -> list[float]:
    """Quartiles of the distances [m] of ``points`` (N, 3) from the line (center, direction)."""
    v = points - center
    r = np.linalg.norm(v - np.outer(v @ direction, direction), axis=1)
    return [float(x) for x in np.percentile(r, [25, 50, 75])]


def _mug_cylinder(objects) -> tuple[float, object] | None:
    """Find the modeled cylinder whose axis passes nearest the tutorial's axis point.

    Returns ``(offset [m], primitive)``, or None without cylinders.
    """
    best = None
    for o in objects:
        if o.type != "cylinder":
            continue
        axis = o.rotation[:, 2]
        # distance of the tutorial's axis point from this cylinder's axis line
        off = np.linalg.norm(np.cross(MUG_POINT - o.center, axis))
        if best is None or off < best[0]:
            best = (off, o)
    return best


def _mug_comparison(pts: np.ndarray, labels: np.ndarray, o, offset: float,
                    table_n: np.ndarray | None) -> dict:
    """Our mug cylinder ``o`` against the tutorial's: sizes, axis, and the axis scans."""
    axis = o.rotation[:, 2]
    ref = MUG_AXIS / np.linalg.norm(MUG_AXIS)
    mug = pts[labels == o.id]
    out = dict(cylinder_radius=o.dimensions["radius"], cylinder_height=o.dimensions["height"],
               axis_error_deg=_line_angle_deg(axis, ref), axis_offset_m=float(offset),
               cylinder_points=o.point_count,
               radial_quartiles_ours_m=_radial_quartiles(mug, o.center, axis),
               radial_quartiles_tutorial_m=_radial_quartiles(mug, MUG_POINT, ref))
    if table_n is not None:
        out["axis_to_table_normal_deg"] = _line_angle_deg(axis, table_n)
        out["tutorial_axis_to_table_normal_deg"] = _line_angle_deg(ref, table_n)
    out.update(_axis_scan(mug, axis, ref, table_n))
    # The same scan on points chosen by the tutorial's own answer (independent of our
    # segmentation): near its axis line, off its table plane.
    v = pts - MUG_POINT
    near_axis = np.linalg.norm(v - np.outer(v @ ref, ref), axis=1) < MUG_SELECT_RADIUS
    height = np.abs(pts @ MUG_TABLE[:3] + MUG_TABLE[3])
    chosen = pts[near_axis & (height > MUG_SELECT_HEIGHT[0]) & (height < MUG_SELECT_HEIGHT[1])]
    scan = _axis_scan(chosen, axis, ref, table_n)
    out["tutorial_selection_points"] = int(len(chosen))
    out.update({f"tutorial_selection_{k}": v for k, v in scan.items()})
    return out


def mug_benchmark(params: ModelingParams) -> dict:
    """Model the PCL mug scene (points with 0 <= z <= 1.5 m) and compare with the tutorial."""
    from geomodel_ros.tools.io import read_cloud
    from geomodel_ros.core.modeling import model_scene

    cloud = read_cloud(data_dir() / "pcl_mug" / "table_scene_mug_stereo_textured.pcd")
    pts = cloud.points
    keep = np.all(np.isfinite(pts), axis=1) & (pts[:, 2] >= 0) & (pts[:, 2] <= 1.5)
    pts = pts[keep]
    t0 = time.perf_counter()
    labels, result = model_scene(pts, params)
    dt = time.perf_counter() - t0
    out = {"points": int(len(pts)), "time_s": dt,
           "types": sorted(o.type for o in result.objects)}
    planes = [o for o in result.objects if o.type == "plane"]
    table_n = None
    if planes:
        table = max(planes, key=lambda o: o.point_count)
        table_n = table.rotation[:, 2]
        out["table_points"] = table.point_count
        out["table_normal"] = [float(v) for v in table_n]
    best = _mug_cylinder(result.objects)
    if best is not None:
        out.update(_mug_comparison(pts, labels, best[1], best[0], table_n))
    return out


#: Directions scanned around the mug's modeled axis, and the band [m] that counts a
#: point as on the circle.
MUG_SCAN_ANGLE = np.radians(20.0)
MUG_SCAN_BAND = 0.003


def _axis_scan(mug: np.ndarray, ours: np.ndarray, tutorial: np.ndarray,
               table_n: np.ndarray | None) -> dict:
    """Find the axis direction the mug's points support, independently of the fitter.

    A circle is fitted to the segment's points seen along every direction within
    MUG_SCAN_ANGLE of our axis (which includes the tutorial's); reported: the best
    direction, and the best one within 5 degrees of the tutorial's axis.
    """
    from geomodel_ros.tools.evaluation import circle_along, scan_axis

    fits = scan_axis(mug, ours, MUG_SCAN_ANGLE, MUG_SCAN_BAND)
    best = fits[0]
    near = [f for f in fits if _line_angle_deg(f.direction, tutorial) <= 5.0][0]

    def summary(f) -> dict:
        row = {"share_within_3mm": f.share, "median_residual_m": f.median_residual,
               "radius_m": f.radius, "to_ours_deg": _line_angle_deg(f.direction, ours),
               "to_tutorial_deg": _line_angle_deg(f.direction, tutorial)}
        if table_n is not None:
            row["to_table_normal_deg"] = _line_angle_deg(f.direction, table_n)
        return row

    return {"axis_scan_best": summary(best),
            "axis_scan_best_within_5deg_of_tutorial": summary(near),
            "axis_scan_at_ours": summary(circle_along(mug, ours, MUG_SCAN_BAND)),
            "axis_scan_at_tutorial": summary(circle_along(mug, tutorial, MUG_SCAN_BAND))}


def synthetic_segmentation(scenes: Sequence[str], params: ModelingParams, repeats: int = 5,
                           noise=None, seed: int = 1) -> list[dict]:
    """End-to-end (segmentation + modeling) on synthetic scenes: IoU, types, sizes, time."""
    from geomodel_ros.tools.evaluation import dimension_errors, expected_type
    from geomodel_ros.core.modeling import model_scene
    from geomodel_ros.tools.synth import render_scene

    rows = []
    for name in scenes:
        scene = render_scene(name, noise=noise, rng=seed)
        seg_t, tot_t = [], []
        for _ in range(repeats):
            labels, result = model_scene(scene.points, params)
            seg_t.append(result.timing["segmentation_s"])
            tot_t.append(result.timing["total_s"])
        ids = [o.id for o in scene.objects]
        scores = segmentation_scores(labels, scene.labels, ids)
        by_id = {o.id: o for o in result.objects}
        types, errs = 0, []
        for sc, gt in zip(scores, scene.objects):
            # the segment that best matches this object
            inter = np.bincount(labels[(scene.labels == gt.id) & (labels >= 0)])
            est = by_id.get(int(np.argmax(inter))) if inter.size else None
            types += est is not None and est.type == expected_type(gt.type)
            if est is not None:
                errs += [abs(e.error) * 1000 for e in dimension_errors(est, gt)]
        rows.append({"scene": name, "objects": len(ids), "points": int(len(scene.points)),
                     "iou_ok": sum(s.iou >= 0.8 for s in scores),
                     "under": sum(s.under for s in scores), "over": sum(s.over for s in scores),
                     "min_iou": min(s.iou for s in scores), "types": types,
                     "size_errors_mm": errs,
                     "segmentation_s": statistics.median(seg_t),
                     "total_s": statistics.median(tot_t)})
    return rows
