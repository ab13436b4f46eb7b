"""Disparity levels per object: which reported objects are quantisation terraces.

A structured-light or stereo camera measures disparity in steps, so its depths take
discrete values of 1/z (Kinect v1: 2.85e-3 1/m per step; ``noise_calibration`` measures the
step). Far away a step is several centimetres (2.85e-3 z^2: 4.3 cm at 3.9 m), and a surface
seen there breaks into terraces of constant depth, each a flat piece facing the camera.
``python -m geomodel_ros.tools.depth_levels CLOUD`` models the cloud with the default
parameters and prints, per object, its type, point count, range span, the depth span of its
points along the optical axis, how many distinct disparity levels they take (1/z rounded to
``--step``) and the angle between its plane normal (planes) and the optical axis: an object
whose points all share one level is a terrace, not a surface of its own.
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

import numpy as np

from geomodel_ros.core.modeling import model_scene
from geomodel_ros.core.params import ModelingParams
from geomodel_ros.tools.io import read_cloud

__all__ = ["object_levels", "main"]

#: Kinect v1's disparity step in 1/z [1/m] (Khoshelham and Elberink 2012; osd_learn's tables
#: measure 2.82e-3 to 2.88e-3 with ``noise_calibration``).
KINECT_INV_DEPTH_STEP = 2.85e-3


def object_levels(points: np.ndarray, step: float, params: ModelingParams) -> list[dict]:
    """Model ``points`` (N, 3) [m] and describe each object's depth levels (see module doc)."""
    labels, result = model_scene(points, params)
    rows = []
    for obj in result.objects:
        own = points[labels == obj.id]
        own = own[own[:, 2] != 0.0]  # the optical axis is +z or -z (some PCL tutorials)
        if not len(own):
            continue
        rng = np.linalg.norm(own, axis=1)
        levels = np.unique(np.round(1.0 / np.abs(own[:, 2]) / step)).size
        axis_deg = None
        if str(obj.type) == "plane":
            axis_deg = math.degrees(math.acos(min(1.0, abs(float(obj.rotation[2, 2])))))
        rows.append({"id": obj.id, "type": str(obj.type), "points": len(own),
                     "range_m": (float(rng.min()), float(rng.max())),
                     "z_span_mm": 1000.0 * float(own[:, 2].max() - own[:, 2].min()),
                     "levels": int(levels), "normal_to_axis_deg": axis_deg})
    return rows


def main(argv: list[str] | None = None) -> int:
    """Print the table for one cloud; return the exit status."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("cloud", type=Path,
                        help="PCD, PLY or NPY file, sensor at the origin looking along +z or -z")
    parser.add_argument("--step", type=float, default=KINECT_INV_DEPTH_STEP,
                        help="disparity step in 1/z [1/m]")
    args = parser.parse_args(argv)
    rows = object_levels(read_cloud(args.cloud).points, args.step, ModelingParams())
    print("| id | type | points | range [m] | z span [mm] | levels | normal to axis [deg] |")
    print("|---|---|---|---|---|---|---|")
    for r in rows:
        axis = "-" if r["normal_to_axis_deg"] is None else f"{r['normal_to_axis_deg']:.1f}"
        print(f"| {r['id']} | {r['type']} | {r['points']} | {r['range_m'][0]:.2f}-"
              f"{r['range_m'][1]:.2f} | {r['z_span_mm']:.1f} | {r['levels']} | {axis} |")
    terraces = [r for r in rows if r["levels"] == 1]
    print(f"{len(rows)} objects, {len(terraces)} with all points on one disparity level")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
