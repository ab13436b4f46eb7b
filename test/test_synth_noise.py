"""Realistic synthetic depth noise: correlated range error and disparity quantisation.

Expectations are worked out by hand: a Gaussian kernel of standard deviation s convolved
with itself has standard deviation s sqrt(2), so white noise smoothed by it and scaled to
unit variance has correlation exp(-r^2 / (2 L^2)) at lag r with L = s sqrt(2); a camera that
quantises 1/z in steps q reports depths 1 / (n q), n integer, terraces q z^2 apart.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from geomodel_ros.core.noise import estimate_noise
from geomodel_ros.tools.synth.scenes import (KINECT_CLASS_NOISE, KINECT_INV_DEPTH_STEP,
                                             KINECT_REAL_NOISE, NoiseModel, apply_noise,
                                             correlated_field, quantize_disparity, render_scene)
from geomodel_ros.tools.synth.suite import SuiteCase, render_case


def _old_apply_noise(organized, label_image, noise, rng):
    """apply_noise as it was before the correlated error and quantisation existed."""
    rng = np.random.default_rng(rng)
    pts = np.array(organized, dtype=np.float64, copy=True)
    lab = np.array(label_image, dtype=np.int32, copy=True)
    height, width = lab.shape
    flat, flat_lab = pts.reshape(-1, 3), lab.reshape(-1)
    valid = np.flatnonzero(np.isfinite(flat).all(axis=1))
    if (noise.sigma_at_0_5m > 0.0 or noise.sigma_offset > 0.0) and valid.size:
        p = flat[valid]
        e = rng.standard_normal(valid.size) * noise.sigma(p[:, 2])
        flat[valid] = p + (e / np.linalg.norm(p, axis=1))[:, None] * p
    if noise.dropout > 0.0 and valid.size:
        drop = rng.choice(valid, size=int(round(noise.dropout * valid.size)), replace=False)
        flat[drop] = np.nan
        flat_lab[drop] = -1
    if noise.holes:
        vv, uu = np.mgrid[0:height, 0:width]
        scale = min(height, width)
        hole = np.zeros((height, width), dtype=bool)
        for _ in range(noise.holes):
            cu, cv = rng.uniform(0.0, width), rng.uniform(0.0, height)
            a, b = np.maximum(rng.uniform(0.02, 0.08, size=2) * scale, 1.0)
            ang = rng.uniform(0.0, np.pi)
            du, dv = uu - cu, vv - cv
            x = du * np.cos(ang) + dv * np.sin(ang)
            y = -du * np.sin(ang) + dv * np.cos(ang)
            hole |= (x / a) ** 2 + (y / b) ** 2 <= 1.0
        pts[hole] = np.nan
        lab[hole] = -1
    return pts, lab


def _wall(depth: float, height: int = 240, width: int = 320, f: float = 300.0) -> np.ndarray:
    """(H, W, 3) fronto-parallel plane at ``depth`` [m] seen by a pinhole camera."""
    v, u = np.mgrid[0:height, 0:width].astype(np.float64)
    x = (u - (width - 1) / 2) / f * depth
    y = (v - (height - 1) / 2) / f * depth
    return np.stack([x, y, np.full_like(x, depth)], axis=2)


def _lag_corr(img: np.ndarray, lag: int) -> float:
    """Correlation of a zero-mean image with itself shifted by ``lag`` along rows and columns."""
    a = np.mean(img[:, lag:] * img[:, :-lag]) + np.mean(img[lag:, :] * img[:-lag, :])
    return float(a / 2 / np.mean(img * img))


# ----------------------------------------------------------------------------- defaults
@pytest.mark.parametrize("noise", [KINECT_CLASS_NOISE,
                                   NoiseModel(sigma_at_0_5m=0.001, dropout=0.02),
                                   NoiseModel(holes=4, sigma_offset=0.002)])
def test_default_fields_draw_exactly_what_the_old_code_drew(noise):
    scene = render_scene("tiny_shapes")
    new = apply_noise(scene.organized, scene.label_image, noise, 7)
    old = _old_apply_noise(scene.organized, scene.label_image, noise, 7)
    np.testing.assert_array_equal(new[0], old[0])
    np.testing.assert_array_equal(new[1], old[1])


def test_realistic_noise_keeps_the_iid_draws_and_appends_its_own():
    # Same seed: the i.i.d. part, the dropout and the holes are the Kinect-class draw's.
    scene = render_scene("tiny_shapes")
    real = apply_noise(scene.organized, scene.label_image, KINECT_REAL_NOISE, 3)
    iid = apply_noise(scene.organized, scene.label_image, KINECT_CLASS_NOISE, 3)
    np.testing.assert_array_equal(real[1], iid[1])
    ok = np.isfinite(iid[0]).all(axis=2)
    np.testing.assert_array_equal(np.isfinite(real[0]).all(axis=2), ok)
    assert not np.allclose(real[0][ok], iid[0][ok], atol=1e-4)   # something was added
    # ... along the rays: the points stay on the rays of the i.i.d. draw.
    cross = np.cross(real[0][ok], iid[0][ok])
    assert np.max(np.linalg.norm(cross, axis=1) / np.linalg.norm(iid[0][ok], axis=1) ** 2) < 1e-9


@pytest.mark.parametrize("kwargs, match", [({"corr_ratio": -0.1}, "corr_ratio"),
                                           ({"corr_length_px": 0.0}, "corr_length_px"),
                                           ({"corr_length_px": np.inf}, "corr_length_px"),
                                           ({"inv_depth_step": -1e-3}, "inv_depth_step"),
                                           ({"inv_depth_step": np.nan}, "inv_depth_step")])
def test_invalid_new_fields_are_rejected(kwargs, match):
    with pytest.raises(ValueError, match=match):
        NoiseModel(sigma_offset=0.001, **kwargs)


# ----------------------------------------------------------------------------- field
@pytest.mark.parametrize("length", [3.0, 6.0])
def test_field_has_unit_variance_and_gaussian_correlation(length):
    fields = [correlated_field((384, 384), length, seed) for seed in range(4)]
    stack = np.stack(fields)
    assert abs(float(stack.mean())) < 0.03
    assert float(stack.std()) == pytest.approx(1.0, abs=0.03)
    for lag in (1, int(length), int(2 * length)):
        want = np.exp(-lag ** 2 / (2 * length ** 2))
        got = np.mean([_lag_corr(f, lag) for f in fields])
        assert got == pytest.approx(want, abs=0.03), lag
    # Negative: no correlation left at four correlation lengths (exp(-8) = 3e-4).
    assert abs(np.mean([_lag_corr(f, int(4 * length)) for f in fields])) < 0.03


def test_field_is_stationary_up_to_the_border():
    # Padding by the kernel radius: the border pixels have the same variance as the centre.
    stack = np.stack([correlated_field((64, 64), 8.0, seed) for seed in range(300)])
    border = np.concatenate([stack[:, 0, :].ravel(), stack[:, :, -1].ravel()])
    centre = stack[:, 24:40, 24:40].ravel()
    assert float(border.std()) == pytest.approx(1.0, abs=0.05)
    assert float(centre.std()) == pytest.approx(1.0, abs=0.05)


def test_correlated_error_has_the_models_amplitude_and_length():
    # Fronto-parallel wall at 1 m: sigma(1 m) = 1.2 mm + 0.8 mm = 2.0 mm; the correlated
    # part is 1.5 x that = 3 mm, correlated 0.607 at one correlation length (6 px). The
    # difference of two draws with the same seed, one without the correlated part, is it.
    depth, ratio, length = 1.0, 1.5, 6.0
    base = NoiseModel(sigma_offset=0.0012, sigma_at_0_5m=0.0002)
    corr = replace(base, corr_ratio=ratio, corr_length_px=length)
    wall = _wall(depth)
    labels = np.zeros(wall.shape[:2], dtype=np.int32)
    diffs = []
    for seed in range(3):
        a = apply_noise(wall, labels, corr, seed)[0]
        b = apply_noise(wall, labels, base, seed)[0]
        diffs.append(np.linalg.norm(a, axis=2) - np.linalg.norm(b, axis=2))
    sigma = 0.0012 + 0.0002 * (depth / 0.5) ** 2
    assert float(np.std(diffs)) == pytest.approx(ratio * sigma, rel=0.06)
    got = np.mean([_lag_corr(d - d.mean(), int(length)) for d in diffs])
    assert got == pytest.approx(np.exp(-0.5), abs=0.04)
    # The i.i.d. part alone is uncorrelated between neighbours.
    iid = np.linalg.norm(apply_noise(wall, labels, base, 0)[0], axis=2) - np.linalg.norm(
        wall, axis=2)
    assert abs(_lag_corr(iid - iid.mean(), 1)) < 0.03


# ----------------------------------------------------------------------------- quantisation
def test_quantised_depth_by_hand():
    # 1/z = 1 1/m is 350.88 steps of 2.85e-3: rounded to 351, z = 1 / (351 * 2.85e-3).
    pts = np.array([[0.2, -0.1, 1.0], [np.nan, np.nan, np.nan]])
    out = quantize_disparity(pts, 2.85e-3)
    assert out[0, 2] == pytest.approx(1.0 / 1.00035, rel=1e-12)
    np.testing.assert_allclose(out[0], pts[0] * out[0, 2], rtol=1e-12)   # along the ray
    assert np.isnan(out[1]).all()
    assert pts[0, 2] == 1.0                                               # input untouched


def test_quantised_depths_lie_on_the_disparity_steps():
    step = KINECT_INV_DEPTH_STEP
    rng = np.random.default_rng(0)
    z = rng.uniform(0.4, 3.0, 5000)
    pts = np.column_stack([rng.uniform(-0.5, 0.5, 5000) * z, rng.uniform(-0.4, 0.4, 5000) * z, z])
    out = quantize_disparity(pts, step)
    n = 1.0 / (out[:, 2] * step)
    np.testing.assert_allclose(n, np.rint(n), atol=1e-6)                # on a step
    assert np.max(np.abs(1.0 / out[:, 2] - 1.0 / z)) <= step / 2 + 1e-12  # the nearest one
    np.testing.assert_allclose(np.cross(out, pts), 0.0, atol=1e-12)      # along the ray
    # Terraces q z^2 apart: 2.85 mm at 1 m, 11.4 mm at 2 m (to first order in q z).
    for depth in (1.0, 2.0):
        k = np.rint(1.0 / (depth * step))
        gap = 1.0 / (k * step) - 1.0 / ((k + 1) * step)
        assert gap == pytest.approx(step * depth ** 2, rel=0.01)


def test_a_tilted_plane_becomes_terraces():
    # A plane receding from 0.9 to 1.1 m spans (1/0.9 - 1/1.1) / 2.85e-3 = 70.9 steps of
    # 1/z: 71 or 72 distinct depths, not the 240 rows' own.
    wall = _wall(1.0)
    wall[..., 2] = np.linspace(0.9, 1.1, wall.shape[0])[:, None]
    out = quantize_disparity(wall, KINECT_INV_DEPTH_STEP)
    assert len(np.unique(np.round(out[..., 2], 12))) in (71, 72)


def test_apply_noise_quantises_after_the_noise():
    noise = NoiseModel(sigma_offset=0.002, inv_depth_step=KINECT_INV_DEPTH_STEP)
    wall = _wall(1.2)
    out, _ = apply_noise(wall, np.zeros(wall.shape[:2], np.int32), noise, 1)
    n = 1.0 / (out[..., 2] * KINECT_INV_DEPTH_STEP)
    np.testing.assert_allclose(n, np.rint(n), atol=1e-6)
    # Noise of 2 mm over steps of 4.1 mm at 1.2 m: several terraces, not one.
    assert len(np.unique(np.rint(n))) >= 3


# ----------------------------------------------------------------------------- calibration
def test_real_preset_measures_like_a_real_kinect_frame():
    # The 45 osd_learn frames: estimate_noise scale 1.62-2.45. Kinect-class i.i.d. noise
    # alone measures ~1 (the local noise is all of it); the preset lands in the real range
    # with its local noise still the Kinect-class sigma(z).
    case = render_case(SuiteCase("set_a", 1.0, "clean", 1))
    real = apply_noise(case.organized, case.label_image, KINECT_REAL_NOISE, 1)[0]
    iid = apply_noise(case.organized, case.label_image, KINECT_CLASS_NOISE, 1)[0]
    est_real = estimate_noise(real.reshape(-1, 3), rng=0)
    est_iid = estimate_noise(iid.reshape(-1, 3), rng=0)
    assert est_iid.scale < 1.2
    assert 1.62 <= est_real.scale <= 2.45
    z = est_real.plane_depth
    local = est_real.sigma(z) / est_real.scale
    assert local == pytest.approx(float(KINECT_CLASS_NOISE.sigma(z)), rel=0.2)


# ----------------------------------------------------------------------------- calibration tool
def test_calibration_measures_a_known_quantised_wall():
    from geomodel_ros.tools.noise_calibration import lag_correlation, measure, plane_residuals

    # A fronto-parallel wall at 1 m, displaced along the rays by a field of known std and
    # correlation length: residuals along the rays = the displacement (up to its mean).
    wall = _wall(1.0)
    field = 0.002 * correlated_field(wall.shape[:2], 6.0, 5)
    bumped = wall * (1.0 + field / np.linalg.norm(wall, axis=2))[..., None]
    res = plane_residuals(bumped, np.ones(wall.shape[:2], dtype=bool))
    ok = np.isfinite(res)
    assert ok.mean() > 0.98                       # 3 robust sigmas keep nearly all
    assert float(np.std(res[ok])) == pytest.approx(float(np.std(field[ok])), rel=0.05)
    assert lag_correlation(res, (6,))[0] == pytest.approx(np.exp(-0.5), abs=0.08)
    # The 1/z step of a quantised wall is the quantisation step.
    quant = quantize_disparity(bumped, KINECT_INV_DEPTH_STEP)
    got = measure(quant, np.ones(wall.shape[:2], dtype=bool))
    assert got["inv_z_gap"] == pytest.approx(KINECT_INV_DEPTH_STEP, rel=1e-3)


# ----------------------------------------------------------------------------- benches
def test_suite_runs_the_realistic_level_only_on_request():
    from geomodel_ros.tools.synth.suite import SUITE_NOISE, suite_cases

    assert {c.noise for c in suite_cases()} == set(SUITE_NOISE)
    assert "kinect-real" not in SUITE_NOISE
    cases = suite_cases((1,), ("kinect", "kinect-real"))
    assert {c.noise for c in cases} == {"kinect", "kinect-real"}
    clean = render_case(SuiteCase("set_a", 1.0, "clean", 1))
    real = render_case(SuiteCase("set_a", 1.0, "kinect-real", 1))
    want = apply_noise(clean.organized, clean.label_image, KINECT_REAL_NOISE, 1)
    np.testing.assert_array_equal(real.organized, want[0])
    np.testing.assert_array_equal(real.label_image, want[1])


def test_sensor_summary_keeps_its_columns_for_the_default_levels():
    from geomodel_ros.tools.bench_sensors import summary_lines

    row = {"type": "plane", "type_correct": True, "recalled": True, "size_errors_m": [0.001],
           "scene": "s", "time_s": 0.5}
    default = summary_lines([{**row, "noise": "kinect"}])
    assert default[0].startswith("noise   ") and default[1].startswith("kinect  ")
    wide = summary_lines([{**row, "noise": "kinect"}, {**row, "noise": "kinect-real"}])
    assert wide[1].startswith("kinect       ") and wide[2].startswith("kinect-real ")
    assert len(wide[1]) == len(wide[2])                      # aligned columns
