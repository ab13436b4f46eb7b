"""Room-scale sizes: the furniture of the synthetic room, end to end and from true labels.

``python -m geomodel_ros.tools.bench_room --seeds 0 1 2 3 4 5`` renders
:func:`geomodel_ros.tools.synth.scenes.room_scene` (seed 0: no noise, otherwise the room's
laser-like noise drawn with that seed) and prints, for every cuboid of the ground truth
(the table and the cabinet), the type and the size error of

* ``e2e``: the object of :func:`~geomodel_ros.core.modeling.model_scene` that holds most of
  its points;
* ``true``: :func:`~geomodel_ros.core.modeling.model_objects` on the true labels, with the
  segmentation's support planes;

as estimate minus truth [mm] per dimension, the dimensions sorted by size, and which of
them were completed.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from geomodel_ros.core.modeling import model_objects, model_scene
from geomodel_ros.core.params import ModelingParams
from geomodel_ros.core.primitives import Primitive
from geomodel_ros.core.segmentation import segment_scene
from geomodel_ros.tools.synth.scenes import room_scene

__all__ = ["room_rows", "main"]

#: Ground-truth label -> name of the room's furniture (room_scene's labels).
FURNITURE = {4: "table", 5: "cabinet"}


def _size_error(obj: Primitive | None, truth: dict[str, float]) -> dict:
    """Type, sorted size errors [mm] and completed dimensions of ``obj`` against ``truth``."""
    if obj is None:
        return {"type": None}
    out: dict = {"type": str(obj.type)}
    if str(obj.type) == "cuboid":
        dims = sorted(obj.dimensions.items(), key=lambda kv: kv[1])
        out["error_mm"] = [round(1000.0 * (v - t), 1)
                           for (_, v), t in zip(dims, sorted(truth.values()))]
        out["completed"] = sorted(obj.completed)
    return out


def room_rows(seeds: list[int], params: ModelingParams) -> list[dict]:
    """One row per seed and furniture piece: ``seed``, ``name``, ``e2e`` and ``true``."""
    rows = []
    for seed in seeds:
        scene = room_scene(noise=None) if seed == 0 else room_scene(rng=seed)
        labels, result = model_scene(scene.points, params)
        by_id = {o.id: o for o in result.objects}
        seg = segment_scene(scene.points, params, noise=result.noise)
        true = {o.id: o for o in model_objects(scene.points, scene.labels, params,
                                               supports=seg.support_planes,
                                               noise=seg.noise).objects}
        for gt in scene.objects:
            if gt.id not in FURNITURE:
                continue
            mine = labels[(scene.labels == gt.id) & (labels >= 0)]
            e2e = by_id.get(int(np.argmax(np.bincount(mine)))) if mine.size else None
            rows.append({"seed": seed, "name": FURNITURE[gt.id],
                         "truth_m": sorted(gt.dimensions.values()),
                         "e2e": _size_error(e2e, gt.dimensions),
                         "true": _size_error(true.get(gt.id), gt.dimensions)})
    return rows


def _cell(entry: dict) -> str:
    """One table cell: the size errors and completions, or the type when not a cuboid."""
    if "error_mm" not in entry:
        return str(entry["type"])
    errs = " / ".join(f"{e:+.1f}" for e in entry["error_mm"])
    return errs + (f" (completed: {', '.join(entry['completed'])})" if entry["completed"] else "")


def main(argv: list[str] | None = None) -> int:
    """Run the benchmark and print its table; return the exit status."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2, 3, 4, 5],
                        help="noise seeds (0: no noise)")
    parser.add_argument("--json", type=Path, default=None, help="write the rows here")
    args = parser.parse_args(argv)
    rows = room_rows(args.seeds, ModelingParams())
    print("| seed | object | end to end, error [mm] | true labels, error [mm] |")
    print("|---|---|---|---|")
    for r in rows:
        print(f"| {r['seed'] or 'no noise'} | {r['name']} | {_cell(r['e2e'])} | "
              f"{_cell(r['true'])} |")
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
