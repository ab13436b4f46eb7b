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

__all__ = ["Mutant", "MUTANTS", "run_mutant", "main"]


@dataclass(frozen=True)
class Mutant:
    """One plausible bug: replace ``old`` (must occur exactly once) by ``new`` in ``path``."""

    name: str
    path: str
    old: str
    new: str


#: The mutants, filled with the bugs a reader would plausibly make in each step.
MUTANTS: tuple[Mutant, ...] = ()


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
                               "test"], cwd=repo, env=env, capture_output=True, text=True,
                              timeout=timeout)
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
