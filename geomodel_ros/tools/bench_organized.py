"""Organized fast path against the voxel path: accuracy, time per frame, top costs.

Both paths of :func:`~geomodel_ros.core.segmentation.segment_scene` (parameter
``organized_fast_path``) on the same frames in the same run:

* ``--part osd``: the osd_learn benchmark (45 real Kinect frames, config/kinect.yaml, or
  the defaults with ``--defaults``) of ``geomodel bench`` for each path: IoU >= 0.8 share,
  under/over-segmentation, and the type table of the best segments; ``--block B`` (a
  diagnosis, not a setting) forces the fast path's block edge to B pixels instead of
  :func:`~geomodel_ros.core.organized.block_size`'s choice, and runs the fast path only;
* ``--part time``: warm ``model_scene`` (segmentation + modeling) per frame, the two paths
  alternated, median of ``--repeats`` runs, on osd_learn frames (640 x 480) and the paper's
  scene3 (1104 x 624, 368k points);
* ``--part profile``: cProfile of warm ``model_scene`` with the fast path on one osd_learn
  frame, the functions with the largest own time;
* ``--part scenes``: the real organized scenes without labels (``pcl_scenes`` and the PCL
  mug, 640 x 480, the defaults): objects and their types on each path.

``--path voxel|organized`` runs the osd and scenes parts on one path only (the other
path's figures do not change with the fast path's code).

``python -m geomodel_ros.tools.bench_organized [--part osd|time|profile|scenes|all]``. Figures go to
BENCHMARKS.md; nothing here is a test.
"""

from __future__ import annotations

import argparse
import cProfile
import dataclasses
import io
import pstats
import statistics
import time

from collections import Counter

from geomodel_ros.core import organized
from geomodel_ros.core.modeling import model_scene
from geomodel_ros.core.params import ModelingParams, load_params_file
from geomodel_ros.tools.benchmark import osd_benchmark, osd_lines, osd_type_lines
from geomodel_ros.tools.io import load_osd
from geomodel_ros.tools.pcd_file import read_pcd
from geomodel_ros.tools.paths import CONFIG_DIR, data_dir

__all__ = ["main"]

#: osd_learn frames timed by default: one or two of each scene group.
TIMED_FRAMES = (0, 10, 20, 30, 40)
#: Real organized scenes without labels (relative to the data directory).
REAL_SCENES = ("pcl_scenes/region_growing_rgb_tutorial.pcd",
               "pcl_scenes/milk_cartoon_all_small_clorox.pcd",
               "pcl_mug/table_scene_mug_stereo_textured.pcd")
#: The two paths, by the value of ``organized_fast_path``.
PATHS = (("voxel", False), ("organized", True))


def _kinect(fast: bool) -> ModelingParams:
    return dataclasses.replace(load_params_file(CONFIG_DIR / "kinect.yaml"),
                               organized_fast_path=fast)


def _paths(only: str | None) -> tuple[tuple[str, bool], ...]:
    """Return the paths to run: both, or the one named ``only``."""
    return tuple(p for p in PATHS if only is None or p[0] == only)


def _osd(defaults: bool, block: int | None, only: str | None = None) -> None:
    paths = _paths(only) if block is None else (("organized", True),)
    if block is not None:
        organized.block_size = lambda _image, _voxel: block
    source = "defaults" if defaults else "config/kinect.yaml"
    for name, fast in paths:
        params = ModelingParams(organized_fast_path=fast) if defaults else _kinect(fast)
        rows = osd_benchmark(params)
        forced = "" if block is None else f", block edge forced to {block} px"
        print(f"\nosd_learn, {name} path ({source}{forced}):")
        print("\n".join(osd_lines(rows)))
        print("\n".join(osd_type_lines(rows)))


def _frames() -> list[tuple[str, object, tuple[int, int], bool]]:
    """(name, points (N, 3), shape, use Kinect parameters) of every timed frame."""
    from geomodel_ros.tools.synth import render_scene

    out = []
    for k in TIMED_FRAMES:
        points, _ = load_osd(data_dir() / "osd_learn" / f"learn{k}.pcd")
        out.append((f"learn{k}", points, (480, 640), True))
    scene = render_scene("scene3")
    out.append(("scene3", scene.organized.reshape(-1, 3), scene.organized.shape[:2], False))
    return out


def _time(repeats: int) -> None:
    print(f"{'frame':<8} {'path':<10} {'total ms':>9} {'segment ms':>11} {'model ms':>9} "
          f"{'objects':>8}")
    ratios = []
    for name, points, shape, kinect in _frames():
        medians = {}
        params = {fast: _kinect(fast) if kinect else ModelingParams(organized_fast_path=fast)
                  for _, fast in PATHS}
        runs: dict[bool, list[dict]] = {fast: [] for _, fast in PATHS}
        for fast in params:
            model_scene(points, params[fast], organized_shape=shape)   # warm-up
        for _ in range(repeats):
            for _, fast in PATHS:     # alternated, so that both see the same machine load
                t0 = time.perf_counter()
                _, result = model_scene(points, params[fast], organized_shape=shape)
                timing = dict(result.timing, wall_s=time.perf_counter() - t0,
                              objects=len(result.objects))
                runs[fast].append(timing)
        for label, fast in PATHS:
            r = runs[fast]
            medians[fast] = statistics.median(t["wall_s"] for t in r)
            print(f"{name:<8} {label:<10} {1000 * medians[fast]:>9.0f} "
                  f"{1000 * statistics.median(t['segmentation_s'] for t in r):>11.0f} "
                  f"{1000 * statistics.median(t['modeling_s'] for t in r):>9.0f} "
                  f"{r[-1]['objects']:>8}")
        ratios.append(medians[False] / medians[True])
        print(f"{name:<8} voxel / organized time: {ratios[-1]:.2f}")


def _profile(frame: int, top: int) -> None:
    points, _ = load_osd(data_dir() / "osd_learn" / f"learn{frame}.pcd")
    params = _kinect(True)
    model_scene(points, params, organized_shape=(480, 640))
    prof = cProfile.Profile()
    prof.enable()
    model_scene(points, params, organized_shape=(480, 640))
    prof.disable()
    out = io.StringIO()
    pstats.Stats(prof, stream=out).sort_stats("tottime").print_stats(top)
    print(out.getvalue())


def _scenes(only: str | None = None) -> None:
    for rel in REAL_SCENES:
        cloud = read_pcd(data_dir() / rel)
        if cloud.height <= 1:
            print(f"{rel}: unorganized, the fast path does not apply")
            continue
        for name, fast in _paths(only):
            _, result = model_scene(cloud.points, ModelingParams(organized_fast_path=fast),
                                    organized_shape=(cloud.height, cloud.width))
            types = Counter(o.type.value for o in result.objects)
            listed = ", ".join(f"{k} {v}" for k, v in sorted(types.items()))
            print(f"{rel} ({cloud.height} x {cloud.width}), {name} path: "
                  f"{len(result.objects)} objects ({listed})")


def main(argv: list[str] | None = None) -> int:
    """Run the parts asked for; print the figures."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--part", choices=("osd", "time", "profile", "scenes", "all"), default="all")
    ap.add_argument("--repeats", type=int, default=7, help="timed runs per frame and path")
    ap.add_argument("--frame", type=int, default=20, help="osd_learn frame to profile")
    ap.add_argument("--top", type=int, default=25, help="functions listed by the profile")
    ap.add_argument("--defaults", action="store_true",
                    help="osd part: the default parameters instead of config/kinect.yaml")
    ap.add_argument("--block", type=int, default=None,
                    help="osd part, diagnosis: force the fast path's block edge [px]")
    ap.add_argument("--path", choices=tuple(name for name, _ in PATHS), default=None,
                    help="osd and scenes parts: run this path only (default: both)")
    args = ap.parse_args(argv)
    if args.block is not None and args.block < 1:
        ap.error("--block must be >= 1 [px]")
    if args.part in ("osd", "all"):
        _osd(args.defaults, args.block, args.path)
    if args.part in ("time", "all"):
        _time(args.repeats)
    if args.part in ("profile", "all"):
        _profile(args.frame, args.top)
    if args.part in ("scenes", "all"):
        _scenes(args.path)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
