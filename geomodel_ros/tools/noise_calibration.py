"""Calibration of the synthetic sensor noise against real frames (``KINECT_REAL_NOISE``).

Measures the sensor, not the method's results, the same way on real and rendered frames:

* ``scale``: :func:`geomodel_ros.core.noise.estimate_noise`'s ratio of the noise across the
  frame's dominant plane to the local noise (1 for pixel-independent noise; real cameras
  add errors that vary slowly over the image);
* ``local``: the local noise at the dominant plane's range over ``KINECT_CLASS_NOISE``'s
  sigma there;
* ``corr``: correlation of the residuals of the table (osd_learn label 0) or desk (label 0
  of the renders) from its robust plane, along the rays, between pixels ``LAGS`` apart
  along rows and columns;
* ``inv_z_gap``: median gap between the distinct values of 1/z on the table [1/m] (the
  disparity quantisation step of a structured-light camera).

Usage::

    python -m geomodel_ros.tools.noise_calibration --part osd
    python -m geomodel_ros.tools.noise_calibration --part suite --lengths 8 16 --ratios 1 2
"""

from __future__ import annotations

import argparse
import statistics
from dataclasses import replace
from typing import Sequence

import numpy as np

from geomodel_ros.core.noise import estimate_noise
from geomodel_ros.tools.synth.scenes import (KINECT_CLASS_NOISE, KINECT_REAL_NOISE, NoiseModel,
                                             apply_noise)

__all__ = ["LAGS", "plane_residuals", "lag_correlation", "measure", "osd_rows", "suite_rows",
           "main"]

#: Lags [px] of the residual correlation: from neighbours to about a tenth of the image.
LAGS = (1, 2, 4, 8, 16, 24, 32, 48)
#: Robust refits of the table plane, each to the points within PLANE_TRIM robust sigmas.
PLANE_ITERATIONS = 4
PLANE_TRIM = 3.0
#: 1.4826 MAD is the standard deviation of a Gaussian.
MAD_TO_SIGMA = 1.4826
#: Seed of estimate_noise's sample (any fixed value: the figures are reproducible).
ESTIMATE_SEED = 0
#: 1/z [1/m] is rounded to this many decimals before its distinct values are taken: far
#: finer than a disparity step (2.85e-3 1/m), coarser than float rounding (1e-16) and the
#: float32 storage of real frames (about 1e-7 at 1 m).
INV_Z_DECIMALS = 6


def plane_residuals(organized: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """Residuals along the rays [m] of the ``mask`` (H, W) pixels from their robust plane.

    Parameters
    ----------
    organized : (H, W, 3) float64 array [m]
    mask : (H, W) bool array
        Pixels of one plane (the table); non-finite pixels are left out.

    Returns
    -------
    (H, W) float64 array [m]
        NaN off the plane and beyond PLANE_TRIM robust sigmas of it (objects' rims).
    """
    mask = mask & np.isfinite(organized).all(axis=2)
    q = organized[mask]
    keep = np.ones(len(q), dtype=bool)
    for _ in range(PLANE_ITERATIONS):
        c = q[keep].mean(axis=0)
        normal = np.linalg.eigh((q[keep] - c).T @ (q[keep] - c))[1][:, 0]
        d = (q - c) @ normal
        keep = np.abs(d) <= PLANE_TRIM * MAD_TO_SIGMA * np.median(np.abs(d[keep]))
    ray = d / (np.abs(q @ normal) / np.linalg.norm(q, axis=1))
    out = np.full(mask.shape, np.nan)
    out[mask] = np.where(keep, ray, np.nan)
    return out


def lag_correlation(res: np.ndarray, lags: Sequence[int] = LAGS) -> list[float]:
    """Correlation of ``res`` (H, W, NaN = none) at each lag [px], rows and columns pooled."""
    ok = np.isfinite(res)
    v = np.where(ok, res - np.nanmean(res), 0.0)
    var = float(np.mean(v[ok] ** 2))
    out = []
    for lag in lags:
        a = (v[:, lag:] * v[:, :-lag])[ok[:, lag:] & ok[:, :-lag]]
        b = (v[lag:, :] * v[:-lag, :])[ok[lag:, :] & ok[:-lag, :]]
        out.append(float(np.concatenate([a, b]).mean() / var))
    return out


def measure(organized: np.ndarray, table: np.ndarray) -> dict:
    """Scale, local noise ratio, residual correlation and 1/z gap of one frame (H, W, 3)."""
    est = estimate_noise(organized.reshape(-1, 3), rng=ESTIMATE_SEED)
    z = est.plane_depth
    local = est.sigma(z) / est.scale / float(KINECT_CLASS_NOISE.sigma(z)) if z > 0 else 0.0
    inv = np.unique(np.round(1.0 / organized[table & np.isfinite(organized).all(axis=2)][:, 2],
                             INV_Z_DECIMALS))
    return {"scale": est.scale, "local": local, "plane_depth": z,
            "corr": lag_correlation(plane_residuals(organized, table)),
            "inv_z_gap": float(np.median(np.diff(inv))) if len(inv) > 1 else 0.0}


def osd_rows() -> list[dict]:
    """:func:`measure` of every osd_learn frame (table = label 0)."""
    from geomodel_ros.tools.benchmark import OSD_SCENE_COUNT
    from geomodel_ros.tools.io import load_osd
    from geomodel_ros.tools.paths import data_dir

    rows = []
    for k in range(OSD_SCENE_COUNT):
        pts, lab = load_osd(data_dir() / "osd_learn" / f"learn{k}.pcd")
        org = pts.reshape(480, 640, 3)
        rows.append({"frame": f"learn{k}", **measure(org, lab.reshape(480, 640) == 0)})
    return rows


def suite_rows(models: dict[str, NoiseModel], seeds: Sequence[int] = (1, 2)) -> list[dict]:
    """:func:`measure` of the suite's tabletop renders (desk = label 0) under each model."""
    from geomodel_ros.tools.synth.suite import (SUITE_DISTANCES, SUITE_LAYOUTS, SuiteCase,
                                                render_case)

    rows = []
    for layout in SUITE_LAYOUTS:
        for dist in SUITE_DISTANCES:
            clean = render_case(SuiteCase(layout, dist, "clean", 1))
            for name, model in models.items():
                for seed in seeds:
                    org, lab = apply_noise(clean.organized, clean.label_image, model, seed)
                    rows.append({"model": name, "scene": f"{layout}@{dist:g}m", "seed": seed,
                                 "distance": dist, **measure(org, lab == 0)})
    return rows


def summary(rows: list[dict], label: str) -> str:
    """One line: scale range and median, local ratio range, median correlation per lag."""
    sc = [r["scale"] for r in rows]
    lo = [r["local"] for r in rows]
    corr = np.median([r["corr"] for r in rows], axis=0)
    gap = statistics.median(r["inv_z_gap"] for r in rows)
    return (f"{label:<16} scale {min(sc):.2f}-{max(sc):.2f} (median {statistics.median(sc):.2f})"
            f"  local {min(lo):.2f}-{max(lo):.2f}  corr " + " ".join(f"{c:.2f}" for c in corr)
            + f"  1/z gap {gap:.2e}")


def main(argv: Sequence[str] | None = None) -> int:
    """Print the calibration figures of the chosen part."""
    ap = argparse.ArgumentParser(prog="python -m geomodel_ros.tools.noise_calibration",
                                 description=__doc__.splitlines()[0])
    ap.add_argument("--part", choices=("osd", "suite", "both"), default="both")
    ap.add_argument("--lengths", type=float, nargs="*", default=[],
                    help="correlation lengths [px] to try beside the presets")
    ap.add_argument("--ratios", type=float, nargs="*", default=[],
                    help="correlated shares (x sigma(z)) to try with each length")
    args = ap.parse_args(argv)
    print(f"lags [px]: {' '.join(str(v) for v in LAGS)}")
    if args.part in ("osd", "both"):
        print(summary(osd_rows(), "osd_learn (45)"))
    if args.part in ("suite", "both"):
        models = {"kinect-class": KINECT_CLASS_NOISE, "kinect-real": KINECT_REAL_NOISE}
        for length in args.lengths:
            for ratio in args.ratios:
                models[f"L{length:g} r{ratio:g}"] = replace(
                    KINECT_REAL_NOISE, corr_length_px=length, corr_ratio=ratio)
        rows = suite_rows(models)
        for name in models:
            print(summary([r for r in rows if r["model"] == name], name))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
