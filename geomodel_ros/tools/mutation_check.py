"""Mutation spot-check: whether the test suite catches plausible bugs in the core.

``python -m geomodel_ros.tools.mutation_check --repo CLONE`` applies one mutant at a time
(a plausible one-line bug, listed in :data:`MUTANTS`) to a *clone* of the repository, runs the
whole test suite there (stopping at the first failure) and restores the file. A mutant is
``caught`` when the suite fails, ``survived`` when it passes, ``stale`` when its original
text is no longer in the file (the list must then be updated). Never run it on a working
tree with uncommitted work: it rewrites files in place (and restores them).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

__all__ = ["Mutant", "MUTANTS", "run_mutant", "test_files", "main"]


@dataclass(frozen=True)
class Mutant:
    """One plausible bug: replace ``old`` (must occur exactly once) by ``new`` in ``path``."""

    name: str
    path: str
    old: str
    new: str


#: The mutants: the eight bugs a reader found surviving the suite (first eight), then
#: plausible slips in every step of the method.
MUTANTS: tuple[Mutant, ...] = (
    Mutant("reconstruction: cuboid rebuilt at twice its size",
           "geomodel_ros/core/reconstruction.py",
           'lx, ly, lz = dims["length"], dims["width"], dims["height"]',
           'lx, ly, lz = 2 * dims["length"], 2 * dims["width"], 2 * dims["height"]'),
    Mutant("reconstruction: cone rebuilt apex-down", "geomodel_ros/core/reconstruction.py",
           "rr * np.sin(t), -h / 2 + h * z]", "rr * np.sin(t), h / 2 - h * z]"),
    Mutant("ransac: cylinder hypothesis with its second point not projected",
           "geomodel_ros/core/ransac.py",
           "q1, q2 = p[:, 0], flat(p[:, 1] - p[:, 0]) + p[:, 0]", "q1, q2 = p[:, 0], p[:, 1]"),
    Mutant("ransac: cylinder normal check on the unprojected offset",
           "geomodel_ros/core/ransac.py",
           'cos = np.abs(np.einsum("bim,im->bm", radial, nt)) / np.maximum(rn, EPS)\n'
           "        return dist, cos\n\n    def distance(self, p: Array) -> Array:\n"
           '        """Signed distances (M,) [m] of ``p`` (M, 3) [m] (positive outside)."""\n'
           "        return self.distance_t(p.T)\n",
           'cos = np.abs(np.einsum("bim,im->bm", pt[None] - h.point[:, :, None], nt))'
           " / np.maximum(rn, EPS)\n"
           "        return dist, cos\n\n    def distance(self, p: Array) -> Array:\n"
           '        """Signed distances (M,) [m] of ``p`` (M, 3) [m] (positive outside)."""\n'
           "        return self.distance_t(p.T)\n"),
    Mutant("obb: ray_to_cylinder takes the far root", "geomodel_ros/core/obb.py",
           "s = np.where(np.abs(s1 - 1) < np.abs(s2 - 1), s1, s2)", "s = np.maximum(s1, s2)"),
    Mutant("surface type: CF divided by all weights, NaN radii included",
           "geomodel_ros/core/surface_type.py",
           "np.sum(w[valid] * cf[valid]) / np.sum(w[valid])",
           "np.sum(w[valid] * cf[valid]) / np.sum(w)"),
    Mutant("model graph: mixed-object veto ignores face size", "geomodel_ros/core/model_graph.py",
           " and faces[i].size > MIXED_VETO_SHARE * total", ""),
    Mutant("segmentation: occlusion join without its evidence check",
           "geomodel_ros/core/joins.py",
           "\n                    and _gap_is_hidden(segs, gap, params.seg_voxel_size)", ""),
    Mutant("verify: inlier ratio not checked", "geomodel_ros/core/fitting/verify.py",
           "if ratio < params.min_inlier_ratio:", "if ratio < 0.0:"),
    Mutant("verify: coverage not checked", "geomodel_ros/core/fitting/verify.py",
           "if share < MIN_COVERAGE:", "if share < 0.0:"),
    Mutant("verify: arc span not checked", "geomodel_ros/core/fitting/verify.py",
           "if arc < params.min_arc:", "if arc < 0.0:"),
    Mutant("verify: frustum accepted as a cone", "geomodel_ros/core/fitting/verify.py",
           "if lo > CONE_APEX_REACH * height:", "if lo > 10 * height:"),
    Mutant("verify: axis alignment test inverted", "geomodel_ros/core/fitting/verify.py",
           "abs(float(axis @ prior)) >= math.cos(tolerance)",
           "abs(float(axis @ prior)) <= math.cos(tolerance)"),
    Mutant("surface type: planar when CF is below the threshold",
           "geomodel_ros/core/surface_type.py",
           "total, total > cf_threshold)", "total, total < cf_threshold)"),
    Mutant("model graph: perpendicular test uses cos instead of sin",
           "geomodel_ros/core/model_graph.py",
           "perpendicular = cos_main <= math.sin(tol)",
           "perpendicular = cos_main <= math.cos(tol)"),
    Mutant("params: min_radius >= max_radius accepted", "geomodel_ros/core/params.py",
           "if self.min_radius >= self.max_radius:", "if self.min_radius > 10 * self.max_radius:"),
    Mutant("tracking: retired ids reused", "geomodel_ros/core/tracking.py",
           "        self._next_id += 1\n", ""),
    Mutant("segmentation: convexity vote accepts concave creases",
           "geomodel_ros/core/segmentation.py",
           "good = convexity[cross] >= -tolerance", "good = convexity[cross] <= tolerance"),
    Mutant("support: small planes taken as supports", "geomodel_ros/core/support.py",
           "if len(keep) * cell_area < params.seg_min_support_area:",
           "if len(keep) * cell_area < 0.01 * params.seg_min_support_area:"),
    Mutant("fastmath: centroid divided by n - 1", "geomodel_ros/core/fastmath.py",
           "return np.ones(n) @ p / n if n", "return np.ones(n) @ p / max(n - 1, 1) if n"),
)


#: Test files run first (fast unit tests of the core): most mutants fail there, and the
#: suite stops at the first failure. Every other test file follows.
FIRST = ("test_reconstruction.py", "test_fitting_units.py", "test_strategies.py",
         "test_fitters.py", "test_surface_type.py", "test_model_graph.py", "test_faces.py",
         "test_obb.py", "test_ray_to_cylinder.py", "test_params.py", "test_tracking.py",
         "test_support.py", "test_segmentation_joins.py", "test_pipeline.py",
         "test_segmentation.py")


def test_files(repo: Path) -> list[str]:
    """Every test file of ``repo``: :data:`FIRST` in its order, then the rest by name."""
    names = sorted(p.name for p in (repo / "test").glob("test_*.py"))
    return [f"test/{n}" for n in FIRST if n in names] + \
        [f"test/{n}" for n in names if n not in FIRST]


def run_mutant(repo: Path, mutant: Mutant, timeout: float) -> dict:
    """Apply ``mutant`` in ``repo``, run the suite, restore; the outcome as a dict."""
    path = repo / mutant.path
    original = path.read_text()
    if original.count(mutant.old) != 1:
        return {"name": mutant.name, "outcome": "stale", "seconds": 0.0}
    path.write_text(original.replace(mutant.old, mutant.new))
    env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST", PYTHONDONTWRITEBYTECODE="1")
    t0 = time.perf_counter()
    try:
        proc = subprocess.run([sys.executable, "-m", "pytest", "-x", "-q", "-p", "no:cacheprovider",
                               *test_files(repo)], cwd=repo, env=env, capture_output=True,
                              text=True, timeout=timeout)
        failed = proc.returncode != 0
        first = next((ln for ln in proc.stdout.splitlines() if ln.startswith("FAILED")), "")
    except subprocess.TimeoutExpired:
        failed, first = True, "timeout"
    finally:
        path.write_text(original)
    return {"name": mutant.name, "outcome": "caught" if failed else "survived",
            "by": first, "seconds": round(time.perf_counter() - t0, 1)}


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m geomodel_ros.tools.mutation_check",
                                 description=__doc__.splitlines()[0])
    ap.add_argument("--repo", required=True, type=Path, help="a clone to mutate (not your tree)")
    ap.add_argument("--only", nargs="*", help="names of the mutants to run (default: all)")
    ap.add_argument("--timeout", type=float, default=900.0, help="per mutant [s]")
    args = ap.parse_args(argv)
    chosen = [m for m in MUTANTS if not args.only or m.name in args.only]
    results = []
    for m in chosen:
        results.append(run_mutant(args.repo, m, args.timeout))
        print(json.dumps(results[-1]), flush=True)
    counts = {k: sum(r["outcome"] == k for r in results) for k in ("caught", "survived", "stale")}
    print(json.dumps(counts))
    return 0 if counts["survived"] == counts["stale"] == 0 else 1


if __name__ == "__main__":
    sys.exit(main())
