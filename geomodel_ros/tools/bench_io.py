"""Measure the memory the cloud file readers hold while reading a large file.

``python -m geomodel_ros.tools.bench_io [--points 3000000] [--dir /tmp]`` writes one cloud
(organized, a noisy plane with 30 % NaN holes, float32 x y z, a uint32 ``label``) in every
format, then reads each file in a fresh Python process and prints, per format: the file
size, the size of the result (points and fields), the peak of traced allocations while
reading (``tracemalloc``; numpy's arrays are traced) and the growth of the peak resident
set size (``VmHWM``) over the resident size before reading, each also as a multiple of the
file size.

``python -m geomodel_ros.tools.bench_io --load-time FILE [FILE ...]`` instead prints the
median wall time of ``--repeat`` (20) ``read_cloud`` calls per file [ms].
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

from geomodel_ros.tools.io import write_npy, write_pcd, write_ply

#: Formats measured: name -> (file name, writer keyword arguments).
FORMATS = {
    "pcd binary": ("cloud_binary.pcd", {}),
    "pcd binary_compressed": ("cloud_compressed.pcd", {"compressed": True}),
    "pcd ascii": ("cloud_ascii.pcd", {"binary": False}),
    "ply binary": ("cloud_binary.ply", {}),
    "ply ascii": ("cloud_ascii.ply", {"encoding": "ascii"}),
    "npy": ("cloud.npy", {}),
}
#: Fraction of the pixels left invalid (NaN), as in a depth image with holes.
HOLE_FRACTION = 0.3

_CHILD = """
import json, sys, tracemalloc
from geomodel_ros.tools.io import read_cloud

def status(key):
    for line in open("/proc/self/status"):
        if line.startswith(key):
            return int(line.split()[1]) * 1024
    return 0

path, traced = sys.argv[1], sys.argv[2] == "1"
if traced:
    tracemalloc.start()
rss = status("VmRSS:")
cloud = read_cloud(path)
peak = tracemalloc.get_traced_memory()[1] if traced else 0
result = cloud.points.nbytes + sum(v.nbytes for v in cloud.fields.values())
print(json.dumps({"peak": peak, "rss": status("VmHWM:") - rss, "result": result}))
"""


def make_cloud(points: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Return an organized (H, W, 3) float32 cloud [m] with NaN holes and its (H, W) labels."""
    width = 2000
    height = max(points // width, 2)
    v, u = np.mgrid[0:height, 0:width].astype(np.float32) / 1000.0
    depth = 1.5 + 0.1 * u + rng.normal(0.0, 0.002, size=u.shape).astype(np.float32)
    cloud = np.stack([u, v, depth], axis=-1).astype(np.float32)
    cloud[rng.random(u.shape) < HOLE_FRACTION] = np.nan
    labels = (u * 10).astype(np.uint32) % 7
    return cloud, labels


def write_all(folder: Path, points: int) -> dict[str, Path]:
    """Write the benchmark cloud in every format of :data:`FORMATS`; return the paths."""
    cloud, labels = make_cloud(points, np.random.default_rng(0))
    paths = {}
    for kind, (name, kwargs) in FORMATS.items():
        path = folder / name
        if kind.startswith("pcd"):
            write_pcd(path, cloud, {"label": labels}, **kwargs)
        elif kind.startswith("ply"):
            write_ply(path, cloud, fields={"label": labels.ravel()}, **kwargs)
        else:
            write_npy(path, cloud)
        paths[kind] = path
    return paths


def measure(path: Path) -> dict[str, int]:
    """Read ``path`` in fresh processes; return traced peak, RSS growth and result bytes."""
    out: dict[str, int] = {}
    for traced in ("1", "0"):  # tracing slows reading and adds its own memory: separate runs
        run = subprocess.run(
            [sys.executable, "-c", _CHILD, str(path), traced],
            check=True,
            capture_output=True,
            text=True,
        )
        values = json.loads(run.stdout)
        out["result"] = values["result"]
        out["peak" if traced == "1" else "rss"] = values["peak" if traced == "1" else "rss"]
    return out


def load_time_ms(path: Path, repeat: int) -> float:
    """Return the median wall time [ms] of ``repeat`` reads of ``path``."""
    import statistics
    import timeit

    from geomodel_ros.tools.io import read_cloud

    times = timeit.repeat(lambda: read_cloud(path), number=1, repeat=repeat)
    return statistics.median(times) * 1000.0


def main(argv: list[str] | None = None) -> int:
    """Write the files, measure each reader and print a Markdown table."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--points", type=int, default=3_000_000, help="points per cloud")
    parser.add_argument("--dir", type=Path, default=None, help="where to write (default: temp)")
    parser.add_argument("--load-time", type=Path, nargs="+", metavar="FILE",
                        help="only time reading these files")
    parser.add_argument("--repeat", type=int, default=20, help="reads per file (--load-time)")
    args = parser.parse_args(argv)
    if args.load_time:
        for path in args.load_time:
            print(f"{path}: {load_time_ms(path, args.repeat):.1f} ms (median of {args.repeat})")
        return 0
    with tempfile.TemporaryDirectory(dir=args.dir) as folder:
        paths = write_all(Path(folder), args.points)
        mb = 1e6
        print("| format | file MB | result MB | traced peak MB (x file) | RSS growth MB (x file) |")
        print("|---|---|---|---|---|")
        for kind, path in paths.items():
            size = path.stat().st_size
            m = measure(path)
            print(
                f"| {kind} | {size / mb:.1f} | {m['result'] / mb:.1f} | "
                f"{m['peak'] / mb:.1f} ({m['peak'] / size:.2f}) | "
                f"{m['rss'] / mb:.1f} ({m['rss'] / size:.2f}) |",
                flush=True,
            )
    return 0


if __name__ == "__main__":
    sys.exit(main())
