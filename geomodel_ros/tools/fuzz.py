"""Property-based fuzzing of the core and the ``geomodel`` command at scale.

``python -m geomodel_ros.tools.fuzz core --cases 10000`` draws clouds with hypothesis (all
magnitudes from 1e-6 to 1e9 m, point spacings, NaN/inf patterns, duplicates, collinear,
coplanar and degenerate sets, tiny and large objects, organized and unorganized) and runs
each through segmentation + modeling (organized ones also with ``decimation`` 2);
``... cli --cases 10000`` writes each cloud to a ``.npy``, ``.pcd`` or ``.ply`` file
(sometimes truncated or corrupted) and runs ``geomodel model`` on it in-process. Every
case ends as one of:

- ``ok``: the call returned and every output number is finite;
- ``clear_error``: a typed error with a message (InputError / ParameterError /
  CloudFileError in the core, exit status 2 with one ``geomodel: error:`` line in the CLI);
- ``non_finite``: the call returned NaN/inf in an output (a defect);
- ``crash``: any other exception or exit status (a defect).

Prints the counts as JSON and exits 1 when there is any defect.
"""

from __future__ import annotations

import argparse
import contextlib
import io as _io
import json
import math
import shutil
import sys
import tempfile
import traceback
import warnings
from collections import Counter
from pathlib import Path
from typing import Any, Sequence

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import seed as hypothesis_seed
from hypothesis import strategies as st

__all__ = ["OUTCOMES", "clouds", "fuzz", "run_core_case", "run_cli_case", "main"]

#: Every outcome of a case, in report order (see the module doc).
OUTCOMES = ("ok", "clear_error", "non_finite", "crash")

#: Largest cloud drawn [points]: big enough for real objects, small enough for 10,000 cases.
MAX_POINTS = 3000
#: Coordinate magnitudes drawn [m]: from sub-micrometre to garbage driver values.
MAGNITUDES = (1e-6, 1e-3, 0.01, 0.1, 1.0, 10.0, 1e3, 1e6, 1e9)
#: Offsets of the whole cloud from the sensor [m] (times a random unit-scale direction).
OFFSETS = (0.0, 0.5, 1.0, 1e3, 1e6, 1e9)
#: Lattice spacings as a fraction of the object scale (0: none).
SPACINGS = (0.0, 0.0, 1e-4, 1e-2, 0.1)
KINDS = ("uniform", "plane", "line", "point", "sphere", "box", "duplicates", "grid")
#: NaN/inf patterns: none, whole rows, single coordinates, a contiguous block, everything.
BAD_VALUES = ("none", "nan_rows", "inf_rows", "nan_cells", "nan_block", "mixed", "all_nan",
              "all_inf")


def _shape_points(kind: str, n: int, rng: np.random.Generator) -> np.ndarray:
    """``n`` unit-scale points of one kind of set (some deliberately degenerate)."""
    if kind == "plane":
        p = np.column_stack([rng.uniform(-1, 1, (n, 2)), np.zeros(n)])
    elif kind == "line":
        p = np.outer(rng.uniform(-1, 1, n), rng.normal(size=3))
    elif kind == "point":
        p = np.zeros((n, 3))
    elif kind == "sphere":
        v = rng.normal(size=(n, 3))
        p = v / np.maximum(np.linalg.norm(v, axis=1, keepdims=True), 1e-12)
    elif kind == "box":
        p = rng.uniform(-1, 1, (n, 3))
        axis = rng.integers(0, 3, n)
        p[np.arange(n), axis] = np.sign(p[np.arange(n), axis])
    elif kind == "duplicates":
        p = np.repeat(rng.uniform(-1, 1, (max(1, n // 50), 3)), 50, axis=0)[:n]
    elif kind == "grid":
        side = max(1, int(round(n ** 0.5)))
        g = np.stack(np.meshgrid(np.arange(side), np.arange(side)), -1).reshape(-1, 2) / side
        p = np.column_stack([g, np.zeros(len(g))])[:n]
    else:
        p = rng.uniform(-1, 1, (n, 3))
    return p


@st.composite
def clouds(draw: Any, max_points: int = MAX_POINTS, max_magnitude: float = MAGNITUDES[-1]
           ) -> tuple[np.ndarray, tuple[int, int] | None]:
    """Draw a fuzzed cloud: ``(points (N, 3), organized (H, W) with H * W = N, or None)``.

    ``max_magnitude`` [m] caps the drawn object scales and offsets (coordinates reach a few
    times it); ``max_points`` caps N.
    """
    seed = draw(st.integers(0, 2**32 - 1))
    rng = np.random.default_rng(seed)
    n = draw(st.integers(0, max_points))
    parts = draw(st.lists(st.sampled_from(KINDS), min_size=1, max_size=3))
    scale = draw(st.sampled_from([m for m in MAGNITUDES if m <= max_magnitude]))
    offset = draw(st.sampled_from([o for o in OFFSETS if o <= max_magnitude])) \
        * rng.normal(size=3)
    chunks = [_shape_points(k, max(1, n // len(parts)), rng) * scale * rng.uniform(0.1, 1)
              + rng.normal(size=3) * scale for k in parts]
    pts = (np.concatenate(chunks) + offset)[:n] if n else np.zeros((0, 3))
    noise = draw(st.sampled_from((0.0, 1e-4, 1e-2)))
    pts = pts + rng.normal(size=pts.shape) * noise * scale
    spacing = draw(st.sampled_from(SPACINGS)) * scale
    if spacing > 0:  # a sensor's quantisation: a lattice, many exact duplicates
        pts = np.round(pts / spacing) * spacing
    pts = _spoil(pts, draw(st.sampled_from(BAD_VALUES)), rng)
    organized = None
    if len(pts) >= 4 and draw(st.booleans()):
        w = draw(st.sampled_from([d for d in (2, 4, 8, 16) if len(pts) % d == 0] or [1]))
        organized = (len(pts) // w, w)
    return pts, organized


def _spoil(pts: np.ndarray, bad: str, rng: np.random.Generator) -> np.ndarray:
    """Put NaN/inf into ``pts`` (N, 3) following the pattern ``bad`` (see BAD_VALUES)."""
    if not len(pts) or bad == "none":
        return pts
    mask = rng.random(len(pts)) < (1.0 if bad in ("all_nan", "all_inf") else 0.2)
    if bad == "nan_cells":
        pts[mask, rng.integers(0, 3)] = np.nan
    elif bad == "nan_block":  # an organized sensor's invalid patch: a run of rows
        start = int(rng.integers(0, len(pts)))
        pts[start:start + max(1, len(pts) // 4)] = np.nan
    elif bad == "mixed":
        pts[mask] = rng.choice([np.nan, np.inf, -np.inf], size=(int(mask.sum()), 3))
    else:
        pts[mask] = np.inf if bad in ("inf_rows", "all_inf") else np.nan
    return pts


def _finite_result(result: Any) -> bool:
    for o in result.objects:
        nums = [*np.ravel(o.center), *np.ravel(o.rotation), *o.dimensions.values(), o.rmse]
        if not all(math.isfinite(float(v)) for v in nums):
            return False
    return True


def run_core_case(points: np.ndarray, organized: tuple[int, int] | None) -> str:
    """Segment + model one cloud; the outcome class (see the module doc).

    An organized cloud is also modeled decimated (``decimation`` 2): both runs must give
    a label per point and finite results.
    """
    from geomodel_ros.core.errors import InputError
    from geomodel_ros.core.modeling import model_scene
    from geomodel_ros.core.params import ModelingParams

    runs = [ModelingParams()] + ([ModelingParams(decimation=2)] if organized else [])
    try:
        outcomes = [model_scene(points, params, organized_shape=organized, rng=0)
                    for params in runs]
    except InputError:
        return "clear_error"
    if any(labels.shape != (len(points),) for labels, _ in outcomes):
        return "crash"
    return "ok" if all(_finite_result(result) for _, result in outcomes) else "non_finite"


def run_cli_case(points: np.ndarray, suffix: str, damage: str, folder: Path) -> str:
    """Write ``points`` as a file, damage it, run ``geomodel model`` on it; outcome class."""
    from geomodel_ros.tools.cli import main as cli_main
    from geomodel_ros.tools.io import write_npy, write_pcd, write_ply

    path = folder / f"cloud{suffix}"
    writer = {".npy": write_npy, ".pcd": write_pcd, ".ply": write_ply}[suffix]
    try:
        writer(path, points)
    except ValueError:
        return "clear_error"  # the writer refused the cloud with a reason
    data = path.read_bytes()
    if damage == "truncate":
        path.write_bytes(data[: len(data) // 2])
    elif damage == "corrupt" and len(data) > 16:
        pos = len(data) // 3
        path.write_bytes(data[:pos] + bytes(255 - b for b in data[pos:pos + 8]) + data[pos + 8:])
    out = folder / "out.json"
    err = _io.StringIO()
    with contextlib.redirect_stdout(_io.StringIO()), contextlib.redirect_stderr(err):
        code = cli_main(["model", str(path), "--json", str(out)])
    if code == 2:
        lines = err.getvalue().strip().splitlines()
        return "clear_error" if len(lines) == 1 and lines[0].startswith("geomodel: error:") \
            else "crash"
    if code != 0:
        return "crash"
    doc = json.loads(out.read_text())
    nums = [v for o in doc["objects"] for v in [*o["center"], *sum(o["rotation"], []),
                                                *o["dimensions"].values(), o["rmse"]]]
    return "ok" if all(math.isfinite(v) for v in nums) else "non_finite"


def _crash_kind(exc: BaseException) -> str:
    """``'<Exception> in <function>'`` of the innermost frame: groups crashes by defect."""
    frames = traceback.extract_tb(exc.__traceback__)
    where = f" in {Path(frames[-1].filename).stem}.{frames[-1].name}" if frames else ""
    return f"{type(exc).__name__}{where}"


def fuzz(target: str, cases: int, seed: int, show: int = 3, *,
         max_magnitude: float = MAGNITUDES[-1], max_points: int = MAX_POINTS) -> dict:
    """Run ``cases`` hypothesis-drawn cases through ``target`` (``core`` or ``cli``).

    Returns the counts of each outcome (see the module doc), ``crash_kinds`` (exception and
    innermost function -> count), up to ``show`` crash tracebacks, and the numpy
    ``RuntimeWarning`` s raised (inf * 0, overflow, ...: by file, line and message, and how
    many cases raised any; information, not an outcome: the output may still be finite).
    """
    counts: Counter[str] = Counter()
    kinds: Counter[str] = Counter()
    numeric: Counter[str] = Counter()  # numpy RuntimeWarnings (inf*0, overflow...) by place
    examples: list[str] = []
    folder = Path(tempfile.mkdtemp(prefix="geomodel_fuzz_"))

    @settings(max_examples=cases, deadline=None, database=None, derandomize=False,
              suppress_health_check=list(HealthCheck))
    @given(cloud=clouds(max_points=max_points, max_magnitude=max_magnitude),
           suffix=st.sampled_from((".npy", ".pcd", ".ply")),
           damage=st.sampled_from(("none", "none", "truncate", "corrupt")))
    def case(cloud: tuple[np.ndarray, tuple[int, int] | None], suffix: str, damage: str) -> None:
        points, organized = cloud
        try:
            with warnings.catch_warnings(record=True) as seen:
                warnings.simplefilter("always", RuntimeWarning)
                outcome = run_core_case(points, organized) if target == "core" \
                    else run_cli_case(points, suffix, damage, folder)
            where = {f"{Path(w.filename).stem}:{w.lineno} {w.message}"[:80] for w in seen
                     if issubclass(w.category, RuntimeWarning)}
            numeric.update(where)
            counts["with_numeric_warnings"] += bool(where)
        except Exception as exc:  # noqa: BLE001 -- any other exception is what we count as a crash
            outcome = "crash"
            kinds[_crash_kind(exc)] += 1
            if len(examples) < show:
                examples.append(traceback.format_exc(limit=-4))  # innermost frames
        counts[outcome] += 1

    hypothesis_seed(seed)(case)()  # reproducible: the same seed draws the same cases
    shutil.rmtree(folder, ignore_errors=True)
    return {"target": target, "cases": sum(counts[k] for k in OUTCOMES),
            **{k: counts.get(k, 0) for k in OUTCOMES}, "crash_kinds": dict(kinds),
            "cases_with_numeric_warnings": counts["with_numeric_warnings"],
            "numeric_warnings": dict(numeric),
            "crash_examples": examples}


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m geomodel_ros.tools.fuzz",
                                 description=__doc__.splitlines()[0])
    ap.add_argument("target", choices=("core", "cli"))
    ap.add_argument("--cases", type=int, default=10_000)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--max-magnitude", type=float, default=MAGNITUDES[-1],
                    help="largest object scale and offset drawn [m] (default 1e9)")
    args = ap.parse_args(argv)
    report = fuzz(args.target, args.cases, args.seed, max_magnitude=args.max_magnitude)
    print(json.dumps(report, indent=1))
    return 1 if report.get("crash", 0) or report.get("non_finite", 0) else 0


if __name__ == "__main__":
    sys.exit(main())
