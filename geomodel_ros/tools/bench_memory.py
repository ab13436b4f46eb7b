"""Peak memory and time of ``model_scene`` on a huge generated cloud.

Run as::

    python -m geomodel_ros.tools.bench_memory --points 5000000

A floor of ``--extent`` x ``--extent`` metres seen from a sensor 1.5 m above it (in the
sensor frame: the floor is the plane z = +1.5 m, the sensor at the origin) with a few boxes
standing on it is sampled on a jittered grid whose spacing gives ``--points`` points in all
(10 m and 5M points: about 4.5 mm), unorganized. The cloud is written to a temporary
``.npy`` file; a fresh Python process loads it and runs
:func:`geomodel_ros.core.modeling.model_scene` with the default parameters (or
``--params``), and reports its peak resident set size (``resource.getrusage``, ``ru_maxrss``)
after loading and at the end, and the time of ``model_scene``. The child imports the
``geomodel_ros`` of the current working directory, so the same command run from another
checkout measures that checkout.

:func:`floor_with_boxes` is also used by the tests (small clouds).
"""

from __future__ import annotations

import argparse
import json
import math
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray

__all__ = ["BoxTruth", "floor_with_boxes", "main"]

#: Height of the sensor above the floor [m] (the floor is the plane z = FLOOR_Z).
FLOOR_Z = 1.5
#: Depth noise added to every point [m] (a good depth camera at 1.5 m).
NOISE_SIGMA = 0.0003
#: Boxes standing on the floor: centre (x, y) [m], size (length, width, height) [m], yaw
#: [rad]. Every face is under the segmentation's support area (0.1 m^2), so boxes stay
#: objects.
BOXES: tuple[tuple[tuple[float, float], tuple[float, float, float], float], ...] = (
    ((0.8, 0.6), (0.30, 0.25, 0.20), 0.3),
    ((-1.0, 0.4), (0.28, 0.18, 0.24), -0.5),
    ((0.2, -1.1), (0.22, 0.22, 0.30), 0.0),
)
#: Child process: load the cloud, run model_scene, print one JSON line.
_CHILD = """
import json, resource, sys, time
import numpy as np
from geomodel_ros.core.modeling import model_scene
from geomodel_ros.core.params import ModelingParams, load_params_file
pts = np.load(sys.argv[1])
params = load_params_file(sys.argv[2]) if sys.argv[2] else ModelingParams()
loaded = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
t0 = time.perf_counter()
labels, result = model_scene(pts, params)
took = time.perf_counter() - t0
peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
print(json.dumps({"points": len(pts), "loaded_kib": loaded, "peak_kib": peak,
                  "model_scene_s": took, "objects": len(result.objects),
                  "labelled": int((labels >= 0).sum()),
                  "types": [o.type.value for o in result.objects],
                  "timing": result.timing}))
"""


class BoxTruth(NamedTuple):
    """A generated box: centre of its bottom face (3,) [m], size (3,) [m], yaw [rad]."""

    center: NDArray[np.float64]
    size: NDArray[np.float64]
    yaw: float


def _grid(u: float, v: float, spacing: float, rng: np.random.Generator
          ) -> NDArray[np.float64]:
    """Jittered grid over [0, u] x [0, v] at ``spacing`` [m]: (K, 2) [m]."""
    nu, nv = max(int(round(u / spacing)), 1), max(int(round(v / spacing)), 1)
    gu, gv = np.meshgrid((np.arange(nu) + 0.5) * (u / nu), (np.arange(nv) + 0.5) * (v / nv),
                         indexing="ij")
    g = np.stack([gu.ravel(), gv.ravel()], axis=1)
    return g + rng.uniform(-0.25, 0.25, g.shape) * spacing


def _box_faces(size: NDArray[np.float64], spacing: float, rng: np.random.Generator
               ) -> NDArray[np.float64]:
    """Top and four sides of a box standing on z = 0 with its bottom centred at 0 (box frame).

    The box's height runs along -z (towards the sensor above the floor).
    """
    a, b, h = size
    top = _grid(a, b, spacing, rng) - [a / 2, b / 2]
    faces = [np.column_stack([top, np.full(len(top), -h)])]
    for length, fixed_axis, half in ((a, 1, b / 2), (b, 0, a / 2)):
        for sign in (-1.0, 1.0):
            g = _grid(length, h, spacing, rng)
            side = np.empty((len(g), 3))
            side[:, 1 - fixed_axis] = g[:, 0] - length / 2
            side[:, fixed_axis] = sign * half
            side[:, 2] = -g[:, 1]
            faces.append(side)
    return np.concatenate(faces)


def _rotation_z(yaw: float) -> NDArray[np.float64]:
    c, s = math.cos(yaw), math.sin(yaw)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def floor_with_boxes(n_points: int, extent: float = 10.0, *, seed: int = 0
                     ) -> tuple[NDArray[np.float64], list[BoxTruth]]:
    """Unorganized cloud of a square floor with :data:`BOXES` standing on it.

    Parameters
    ----------
    n_points : int
        Approximate number of points; the sampling spacing is sqrt(area / n_points).
    extent : float [m]
        Edge of the floor square, centred under the sensor.
    seed : int

    Returns
    -------
    points : (N, 3) float64 array [m], N close to ``n_points``, in the sensor frame
    boxes : list of BoxTruth
    """
    rng = np.random.default_rng(seed)
    sizes = [np.array(s) for _, s, _ in BOXES]
    box_area = sum(a * b + 2 * h * (a + b) for a, b, h in sizes)
    spacing = math.sqrt((extent * extent + box_area) / n_points)
    floor = _grid(extent, extent, spacing, rng) - extent / 2
    keep = np.ones(len(floor), dtype=bool)
    parts, truths = [], []
    for (cx, cy), size, yaw in zip((c for c, _, _ in BOXES), sizes, (y for _, _, y in BOXES)):
        rot = _rotation_z(yaw)
        local = (floor - [cx, cy]) @ rot[:2, :2]
        keep &= ~np.all(np.abs(local) <= size[:2] / 2, axis=1)
        center = np.array([cx, cy, FLOOR_Z])
        parts.append(_box_faces(size, spacing, rng) @ rot.T + center)
        truths.append(BoxTruth(center, size, yaw))
    floor = np.column_stack([floor[keep], np.full(int(keep.sum()), FLOOR_Z)])
    points = np.concatenate([floor, *parts])
    points[:, 2] += rng.normal(0.0, NOISE_SIGMA, len(points))
    return points, truths


def main(argv: list[str] | None = None) -> int:
    """Generate the cloud, model it in a fresh process, print peak RSS and time."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--points", type=int, default=5_000_000)
    ap.add_argument("--extent", type=float, default=10.0, help="floor edge [m]")
    ap.add_argument("--params", default="", help="parameter YAML (default: defaults)")
    ap.add_argument("--json", help="also write the figures to this file")
    args = ap.parse_args(argv)
    points, _ = floor_with_boxes(args.points, args.extent)
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "cloud.npy"
        np.save(path, points)
        del points
        proc = subprocess.run([sys.executable, "-c", _CHILD, str(path), args.params],
                              capture_output=True, text=True, check=False)
    if proc.returncode != 0:
        print(proc.stderr, file=sys.stderr)
        return 1
    out = json.loads(proc.stdout.strip().splitlines()[-1])
    mib = 1.0 / 1024.0
    print(f"{out['points']} points ({out['points'] * 24 / 2**20:.0f} MiB as float64): "
          f"model_scene {out['model_scene_s']:.1f} s, peak RSS {out['peak_kib'] * mib:.0f} MiB "
          f"({out['loaded_kib'] * mib:.0f} MiB after loading the cloud); "
          f"{out['objects']} objects, {out['labelled']} points labelled")
    stages = ("downsample_s", "segmentation_s", "modeling_s")
    print("  " + ", ".join(f"{k[:-2]} {out['timing'][k]:.1f} s" for k in stages
                           if k in out["timing"]))
    if args.json:
        Path(args.json).write_text(json.dumps(out, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
