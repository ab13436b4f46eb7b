"""``geomodel`` command line: synthesize scenes, model clouds, benchmark, demo.

Every user error (bad file, bad parameter, bad shape) prints one line
``geomodel: error: ...`` and exits with status 2, never a traceback.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path
from typing import Sequence

import numpy as np

from geomodel_ros.core.colors import id_colors
from geomodel_ros.core.fastmath import retain_freed_memory
from geomodel_ros.core.params import PARAMETERS, ModelingParams, ParameterError, load_params_file

__all__ = ["main"]

#: Defaults of ``synth --bag`` (same values as geomodel_ros.ros.bags, which needs ROS messages).
DEFAULT_TOPIC = "/camera/depth/points"
DEFAULT_FRAME_ID = "camera_depth_optical_frame"
STORAGE_CHOICES = ("mcap", "sqlite3")


class CliError(Exception):
    """A user error reported as one line with exit status 2."""


# ---------------------------------------------------------------------------------------
# helpers
# ---------------------------------------------------------------------------------------

#: Names of the parameters whose values are strings (``--set noise_model=fixed``).
_STRING_PARAMS = frozenset(p.name for p in PARAMETERS if p.type is str)


def parameter_overrides(items: list[str] | None) -> dict[str, object]:
    """Parse ``--set NAME=VALUE`` items into a name -> value mapping (values unchecked).

    Numbers and true / false are read as JSON; other text only for string parameters.

    Raises
    ------
    CliError
        For an item without ``=`` or a non-string parameter's value that is no number.
    """
    overrides: dict[str, object] = {}
    for item in items or []:
        if "=" not in item:
            raise CliError(f"--set expects NAME=VALUE, got {item!r}")
        name, raw = item.split("=", 1)
        try:
            value = json.loads(raw.lower() if raw.lower() in ("true", "false") else raw)
        except json.JSONDecodeError:
            if name.strip() not in _STRING_PARAMS:
                raise CliError(f"--set {name}: {raw!r} is not a number or true/false") from None
            value = raw  # a string parameter's value (its spec checks the choices)
        overrides[name.strip()] = value
    return overrides


def _params(args: argparse.Namespace) -> ModelingParams:
    params = load_params_file(args.params) if getattr(args, "params", None) else ModelingParams()
    overrides = parameter_overrides(getattr(args, "set", None))
    return ModelingParams.from_mapping(overrides, base=params) if overrides else params


def params_yaml(node: str = "modeler") -> str:
    """Return the parameter defaults as a ROS 2 params file (config/modeler.yaml)."""
    lines = [
        "# Defaults of every modeling parameter of geomodel_ros (generated from",
        "# geomodel_ros/core/params.py by `geomodel params`; keep them in sync).",
        f"{node}:",
        "  ros__parameters:",
    ]
    for p in PARAMETERS:
        value = str(p.default).lower() if isinstance(p.default, bool) else repr(p.default)
        rng = "" if p.low is None else f" [{p.low}, {p.high}]"
        unit = f" [{p.unit}]" if p.unit and p.unit not in ("1", "count") else ""
        lines.append(f"    # {p.description}{unit}{rng}")
        lines.append(f"    {p.name}: {value}")
    return "\n".join(lines) + "\n"


def _load_points(path: str):
    from geomodel_ros.tools.io import read_cloud

    cloud = read_cloud(path)
    return cloud


def _labels_for(args: argparse.Namespace, cloud) -> np.ndarray | None:
    """Object labels given on the command line, or None (the scene is segmented)."""
    n = len(cloud.points)
    if args.labels:
        try:
            labels = np.load(args.labels, allow_pickle=False)
        except (OSError, ValueError) as exc:
            raise CliError(f"cannot read labels {args.labels}: {exc}") from None
        if labels.shape != (n,) or not np.issubdtype(labels.dtype, np.integer):
            raise CliError(f"labels {args.labels} must be an ({n},) integer array aligned with "
                           f"the input points, got {labels.dtype} {labels.shape}")
        return labels.astype(np.int64)
    if args.labels_field:
        if args.labels_field not in cloud.fields:
            raise CliError(f"input has no field {args.labels_field!r}; fields: "
                           f"{', '.join(sorted(cloud.fields)) or 'none'}")
        field = np.asarray(cloud.fields[args.labels_field])
        if field.shape != (n,) or not np.issubdtype(field.dtype, np.integer):
            raise CliError(f"field {args.labels_field!r} must hold one integer per point, got "
                           f"{field.dtype} {field.shape}")
        return field.astype(np.int64)
    return None


# ---------------------------------------------------------------------------------------
# commands
# ---------------------------------------------------------------------------------------

def cmd_synth(args: argparse.Namespace) -> int:
    from geomodel_ros.tools.io import write_pcd
    from geomodel_ros.tools.synth import SCENE_NAMES, SENSOR_NOISE, render_scene

    if (args.out is None) == (args.bag is None):
        raise CliError("give exactly one of --out FILE.pcd (one scene) and --bag DIR")
    for name in args.names:
        if name not in SCENE_NAMES:
            raise CliError(f"unknown scene {name!r}; choose one of {', '.join(SCENE_NAMES)}")
    if args.bag is not None:
        return _synth_bag(args)
    if len(args.names) != 1:
        raise CliError(f"--out writes one scene, got {len(args.names)}; use --bag for several")
    scene = render_scene(args.names[0], noise=SENSOR_NOISE if args.noise else None,
                         rng=args.seed)
    out = Path(args.out)
    write_pcd(out, scene.organized, {"label": scene.label_image.astype(np.int32)})
    gt_path = out.with_suffix(".json")
    gt_path.write_text(json.dumps({
        "scene": scene.name, "intrinsics": scene.intrinsics,
        "noise": bool(args.noise), "seed": args.seed,
        "objects": [o.to_dict() for o in scene.objects]}, indent=2))
    print(f"wrote {out} ({len(scene.points)} valid points, {len(scene.objects)} objects) "
          f"and {gt_path}")
    return 0


def _bags():
    """:mod:`geomodel_ros.ros.bags`, imported with DDS discovery kept on loopback."""
    os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    from geomodel_ros.ros import bags

    return bags


def _bag_command(func):
    """Report :class:`geomodel_ros.ros.bags.BagError` as a one-line CLI error."""
    def run(args: argparse.Namespace) -> int:
        bags = _bags()
        try:
            return func(args, bags)
        except bags.BagError as exc:
            raise CliError(str(exc)) from None
    run.__name__ = func.__name__
    return run


@_bag_command
def _synth_bag(args: argparse.Namespace, bags) -> int:
    truth = bags.write_synth_bag(args.bag, args.names, frames=args.frames, rate=args.rate,
                                 noise=args.noise, seed=args.seed, topic=args.topic,
                                 frame_id=args.frame_id, storage=args.storage)
    print(f"wrote {args.bag} ({truth['frames']} frames of {', '.join(args.names)} on "
          f"{args.topic}, {args.storage}) and {bags.ground_truth_path(args.bag)}")
    return 0


@_bag_command
def cmd_bag(args: argparse.Namespace, bags) -> int:
    params = _params(args)
    sensor = _sensor_pose(args.sensor_pose)
    show = sys.stderr.isatty() if args.progress is None else args.progress
    state = {"open": False}

    def progress(k: int, n: int) -> None:
        sys.stderr.write(f"\r[{k}/{n}]")
        sys.stderr.flush()
        state["open"] = True

    def end_line() -> None:
        if state["open"]:
            sys.stderr.write("\n")
            state["open"] = False

    def warn(text: str) -> None:
        end_line()
        print(f"geomodel: warning: {text}", file=sys.stderr)

    try:
        summary = bags.process_bag(args.input, args.output, params=params, topic=args.topic,
                                   storage=args.storage, namespace=args.namespace,
                                   segments=not args.no_segments,
                                   reconstruction=not args.no_reconstruction,
                                   progress=progress if show else None, warn=warn,
                                   sensor=sensor)
    finally:
        end_line()
    skipped = f", {len(summary.skipped)} skipped" if summary.skipped else ""
    print(f"{summary.processed}/{summary.frames} clouds of {summary.topic} modeled{skipped} "
          f"in {summary.seconds:.1f} s -> {args.output} "
          f"({', '.join(f'{t}: {n}' for t, n in summary.output_topics.items())})")
    return 0


@_bag_command
def cmd_play(args: argparse.Namespace, bags) -> int:
    def started(topics: dict[str, str]) -> None:
        shown = ", ".join(t if t == p else f"{t} -> {p}" for t, p in topics.items())
        print(f"playing {args.bag} ({shown}) at x{args.rate:g}"
              + (", looping" if args.loop else "")
              + (f"; waiting up to {args.wait:g} s for a subscriber" if args.wait else ""),
              file=sys.stderr)

    n = bags.play(args.bag, rate=args.rate, loop=args.loop, topics=args.topic,
                  remap=args.remap, wait_timeout=args.wait, on_start=started)
    print(f"published {n} messages", file=sys.stderr)
    return 0


def cmd_model(args: argparse.Namespace) -> int:
    from geomodel_ros.core.fastmath import rows_finite
    from geomodel_ros.core.input import in_range, origin_rows
    from geomodel_ros.core.modeling import model_objects, model_scene
    from geomodel_ros.core.reconstruction import reconstruct

    params = _params(args)
    sensor = _sensor_pose(args.sensor_pose)
    t0 = time.perf_counter()
    cloud = _load_points(args.input)
    labels = _labels_for(args, cloud)
    t_load = time.perf_counter() - t0
    seen = cloud.points if sensor is None else sensor.to_sensor(cloud.points)
    far = int(np.count_nonzero(rows_finite(seen) & ~in_range(seen, params.max_range)))
    far -= len(origin_rows(seen))  # no returns, not far points
    if far:
        print(f"geomodel: warning: {far} of {len(cloud.points)} points are farther than "
              f"max_range = {params.max_range:g} m from the "
              f"{'origin' if sensor is None else 'sensor'} and were ignored", file=sys.stderr)
    if labels is None:
        labels, result = model_scene(cloud.points, params, organized_shape=(
            (cloud.height, cloud.width) if cloud.is_organized else None), sensor=sensor)
        result.timing["segmentation"] = result.timing["segmentation_s"]
    elif sensor is None:
        result = model_objects(cloud.points, labels, params)
    else:
        result = sensor.result_to_input(model_objects(seen, labels, params))
    if args.labels_out:
        np.save(args.labels_out, labels.astype(np.int32))
    out = result.to_dict()
    out["timing"]["load_s"] = t_load
    if args.reconstruction:
        from geomodel_ros.tools.io import write_ply

        t1 = time.perf_counter()
        pts, ids = reconstruct(result.objects, params.reconstruction_spacing)
        write_ply(args.reconstruction, pts, id_colors(ids))
        out["timing"]["reconstruction_s"] = time.perf_counter() - t1
    out["timing"]["total_s"] = time.perf_counter() - t0
    Path(args.json).write_text(json.dumps(out, indent=2))
    counts: dict[str, int] = {}
    for o in result.objects:
        counts[o.type] = counts.get(o.type, 0) + 1
    summary = ", ".join(f"{v} {k}" for k, v in sorted(counts.items())) or "no objects"
    noise = "" if result.noise is None else \
        f"; noise sigma {1000 * result.noise.sigma(1.0):.2f} mm at 1 m"
    frag = f", {result.fragments} fragments left out" if result.fragments else ""
    print(f"{len(result.objects)} objects ({summary}{frag}) in {out['timing']['total_s']:.2f} s"
          f"{noise} -> {args.json}")
    return 0


def _sensor_pose(values: list[float] | None):
    """Return the ``--sensor-pose`` (x y z qx qy qz qw) as a SensorPose, or None."""
    if values is None:
        return None
    from geomodel_ros.core.viewpoint import SensorPose

    try:
        return SensorPose.from_transform(values[:3], values[3:])
    except ValueError as exc:
        raise CliError(f"--sensor-pose: {exc}") from None


def cmd_params(_args: argparse.Namespace) -> int:
    """Print the parameter defaults (every command takes the parsed arguments)."""
    sys.stdout.write(params_yaml())
    return 0


def cmd_bench(args: argparse.Namespace) -> int:
    from geomodel_ros.tools import benchmark as bm
    from geomodel_ros.tools.synth import SENSOR_NOISE

    # One parameter set for every run (noise_model = auto adapts to each frame's noise);
    # --noisy-params overrides it for the noisy runs.
    clean = _params(args)
    noisy = clean if args.noisy_params is None else load_params_file(args.noisy_params)
    report: dict = {}
    if args.part in ("modeling", "all"):
        report["modeling"] = bm.run_benchmark(args.scenes, args.repeats, noisy, clean,
                                              seed=args.seed)
        for r in report["modeling"]["runs"]:
            if r["table"]:
                print(f"\nFigure 9 table, {r['scene']} ({'noisy' if r['noisy'] else 'noise-free'}, "
                      "ground-truth object labels):")
                print(r["table"])
        print("\nModeling with ground-truth object labels (extraction = model_objects wall time):")
        print("\n".join(bm.summary_lines(report["modeling"])))
    if args.part in ("segmentation", "all"):
        print("\nEnd to end (segmentation + modeling) on the synthetic scenes:")
        print(f"{'scene':<8} {'noise':<6} {'objects':>7} {'IoU>=0.8':>8} {'min IoU':>8} "
              f"{'types':>6} {'size err mm median/max':>23} {'seg s':>7} {'total s':>8}")
        rows = []
        for noise in (None, SENSOR_NOISE):
            params = clean if noise is None else noisy
            for r in bm.synthetic_segmentation(args.scenes, params, args.repeats, noise, args.seed):
                r["noisy"] = noise is not None
                rows.append(r)
                e = r["size_errors_mm"] or [float("nan")]
                print(f"{r['scene']:<8} {'noisy' if noise else 'clean':<6} {r['objects']:>7} "
                      f"{r['iou_ok']:>4}/{r['objects']:<3} {r['min_iou']:>8.3f} "
                      f"{r['types']:>3}/{r['objects']:<2} {np.median(e):>11.3f} /{np.max(e):>9.3f} "
                      f"{r['segmentation_s']:>7.3f} {r['total_s']:>8.3f}")
        report["synthetic_segmentation"] = rows
        osd = bm.osd_benchmark(clean)
        report["osd"] = osd
        print("\nReal Kinect scenes, osd_learn (objects = labels >= 20):")
        print("\n".join(bm.osd_lines(osd)))
        if any("object_types" in r for r in osd):
            print("\nModeled type of each labelled object's best-matching segment:")
            print("\n".join(bm.osd_type_lines(osd)))
        mug = bm.mug_benchmark(clean)
        report["mug"] = mug
        print("\nPCL mug scene:", json.dumps(mug))
    print(f"\npeak RSS {bm.peak_rss_mb():.0f} MiB")
    if args.json:
        Path(args.json).write_text(json.dumps(report, indent=2, default=float))
    return 0


def cmd_demo(args: argparse.Namespace) -> int:
    from geomodel_ros.core.modeling import model_objects
    from geomodel_ros.tools.synth import render_scene

    params = _params(args)
    scene = render_scene("scene3")
    t0 = time.perf_counter()
    result = model_objects(scene.points, scene.labels, params)
    dt = time.perf_counter() - t0
    print(f"Scene 3 (paper Figure 9 objects): {len(scene.points)} points, "
          f"{len(scene.objects)} objects, modeled in {dt:.3f} s with ground-truth labels\n")
    from geomodel_ros.tools.benchmark import figure9_table

    print(figure9_table(scene, result))
    return 0 if result.objects else 1


# ---------------------------------------------------------------------------------------

def _add_params(p: argparse.ArgumentParser) -> None:
    """Add ``--params`` and ``--set`` (the modeling parameters) to a command."""
    p.add_argument("--params", help="parameter YAML (flat or ROS params-file layout)")
    p.add_argument("--set", action="append", metavar="NAME=VALUE",
                   help="override one parameter (repeatable)")


def _add_synth(sub) -> None:
    """Add the ``synth`` command to the subparsers ``sub``."""
    p = sub.add_parser("synth", help="render synthetic depth-camera scenes to PCD + JSON or "
                       "to a rosbag2 of PointCloud2 frames + JSON")
    p.add_argument("names", nargs="+", metavar="NAME", help="scene name (several with --bag)")
    p.add_argument("--out", help="output .pcd (ground truth goes to .json beside it)")
    p.add_argument("--bag", help="output rosbag2 directory (ground truth goes to BAG.json)")
    p.add_argument("--frames", type=int, default=3, help="--bag: frames per scene (default 3)")
    p.add_argument("--rate", type=float, default=10.0, help="--bag: frame rate [Hz] (default 10)")
    p.add_argument("--topic", default=DEFAULT_TOPIC, help=f"--bag: topic (default {DEFAULT_TOPIC})")
    p.add_argument("--frame-id", default=DEFAULT_FRAME_ID,
                   help=f"--bag: header frame_id (default {DEFAULT_FRAME_ID})")
    p.add_argument("--storage", choices=STORAGE_CHOICES, default="mcap",
                   help="--bag: storage plugin (default mcap)")
    p.add_argument("--noise", action="store_true", help="add sensor noise (1 mm at 0.5 m, 2%% "
                   "dropout; drawn anew for every bag frame)")
    p.add_argument("--seed", type=int, default=1)
    p.set_defaults(func=cmd_synth)


def _add_bag(sub) -> None:
    """Add the ``bag`` command to the subparsers ``sub``."""
    p = sub.add_parser("bag", help="model every PointCloud2 of a rosbag2 offline, as the node "
                       "would, into a new bag")
    p.add_argument("input", help="input bag (rosbag2 directory, .mcap or .db3)")
    p.add_argument("output", help="output bag directory (must not exist)")
    p.add_argument("--topic", help="cloud topic (default: the bag's only PointCloud2 topic)")
    p.add_argument("--storage", choices=STORAGE_CHOICES,
                   help="storage of the output (default: the input's)")
    p.add_argument("--namespace", default="/modeler",
                   help="namespace of the output topics (default /modeler: /modeler/primitives, "
                   "/modeler/objects, /modeler/segments, /modeler/reconstruction)")
    p.add_argument("--no-segments", action="store_true", help="do not write <namespace>/segments")
    p.add_argument("--no-reconstruction", action="store_true",
                   help="do not write <namespace>/reconstruction")
    p.add_argument("--progress", action=argparse.BooleanOptionalAction, default=None,
                   help="show a [k/N] counter on stderr (default: when stderr is a terminal)")
    _add_sensor_pose(p)
    _add_params(p)
    p.set_defaults(func=cmd_bag)


def _add_play(sub) -> None:
    """Add the ``play`` command to the subparsers ``sub``."""
    p = sub.add_parser("play", help="publish a bag's PointCloud2 records at the recorded rate")
    p.add_argument("bag", help="rosbag2 directory, .mcap or .db3")
    p.add_argument("--rate", type=float, default=1.0, help="speed factor (default 1)")
    p.add_argument("--loop", action="store_true", help="start over at the end (Ctrl-C stops)")
    p.add_argument("--topic", action="append", help="play only this topic (repeatable; "
                   "default: every PointCloud2 topic)")
    p.add_argument("--remap", action="append", metavar="OLD:=NEW", help="publish topic OLD as "
                   "NEW (repeatable)")
    p.add_argument("--wait", type=float, default=10.0, metavar="SECONDS",
                   help="wait this long for a subscriber before starting (default 10; 0 = "
                   "start at once)")
    p.set_defaults(func=cmd_play)


def _add_model(sub) -> None:
    """Add the ``model`` command to the subparsers ``sub``."""
    p = sub.add_parser("model", help="segment a cloud (or take its labels) and model its objects")
    p.add_argument("input", help="cloud file (.pcd, .ply, .npy)")
    p.add_argument("--json", required=True, help="output JSON")
    p.add_argument("--labels", help="per-point integer object ids (.npy), -1 = none")
    p.add_argument("--labels-field", help="use this field of the input file as object ids")
    p.add_argument("--labels-out", help="write the per-point object ids used (.npy, int32, "
                   "-1 = none); without --labels/--labels-field these come from segmentation")
    p.add_argument("--reconstruction", help="write the reconstructed surfaces (.ply)")
    _add_sensor_pose(p)
    _add_params(p)
    p.set_defaults(func=cmd_model)


def _add_sensor_pose(p) -> None:
    """Add ``--sensor-pose`` to the command parser ``p`` (read by :func:`_sensor_pose`)."""
    p.add_argument("--sensor-pose", nargs=7, type=float, metavar=("X", "Y", "Z", "QX", "QY",
                                                                   "QZ", "QW"),
                   help="where the sensor's optical frame (z forward) is in the cloud's "
                   "frame, as tf2 gives it [m, quaternion]: the cloud is modeled from there "
                   "and every output stays in its frame (for a cloud moved out of the "
                   "sensor's frame; an organized one gives its camera itself)")


def _add_bench(sub) -> None:
    """Add the ``bench`` command to the subparsers ``sub``."""
    p = sub.add_parser("bench", help="accuracy and speed on the paper's synthetic scenes")
    p.add_argument("--scenes", nargs="+", default=["scene1", "scene2", "scene3"])
    p.add_argument("--repeats", type=int, default=5)
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--noisy-params", help="parameters file for the noisy runs (default: the "
                   "same parameters as the noise-free runs, i.e. the defaults with --set)")
    p.add_argument("--part", choices=("modeling", "segmentation", "all"), default="all")
    p.add_argument("--json", help="write the full report here")
    _add_params(p)
    p.set_defaults(func=cmd_bench)


def build_parser() -> argparse.ArgumentParser:
    """Return the parser of every ``geomodel`` command."""
    ap = argparse.ArgumentParser(prog="geomodel", description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest="command", required=True)
    for add in (_add_synth, _add_bag, _add_play, _add_model, _add_bench):
        add(sub)
    p = sub.add_parser("demo", help="model the paper's Scene 3 and print its Figure 9 table")
    _add_params(p)
    p.set_defaults(func=cmd_demo)
    p = sub.add_parser("params", help="print the parameter defaults as a ROS params file")
    p.set_defaults(func=cmd_params)
    return ap


def main(argv: Sequence[str] | None = None) -> int:
    from geomodel_ros.tools.io import CloudFileError
    from geomodel_ros.core.modeling import InputError

    parser = build_parser()
    args = parser.parse_args(argv)
    retain_freed_memory()
    try:
        return int(args.func(args))
    except KeyboardInterrupt:
        print("geomodel: interrupted", file=sys.stderr)
        return 130
    except (CliError, ParameterError, CloudFileError, InputError) as exc:
        print(f"geomodel: error: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:
        print(f"geomodel: error: {exc.filename or ''}: {exc.strerror}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
