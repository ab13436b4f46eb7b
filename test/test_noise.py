"""Per-frame noise estimate and the tolerances it resolves (``noise_model``).

Expectations come from the noise put into rendered scenes (sigma(z) of the NoiseModel)
and from the mapping's stated factors worked out by hand, not from the code's output.
"""

from __future__ import annotations

import dataclasses
import json
import math

import numpy as np
import pytest

from geomodel_ros.core import noise as nz
from geomodel_ros.core.modeling import model_objects, model_scene
from geomodel_ros.core.noise import (NoiseEstimate, estimate_noise, is_fragment, object_params,
                                     resolve_params)
from geomodel_ros.core.params import PARAMETERS, ModelingParams, ParameterError
from geomodel_ros.tools.synth import (KINECT_CLASS_NOISE, NoiseModel, PinholeCamera, Rectangle,
                                      apply_noise, render_scene)
from geomodel_ros.tools.synth.scenes import room_scene

#: Noise-dependent fields the auto mode may raise.
RESOLVED = ("noise_amplitude", "ransac_threshold", "voxel_size", "seg_voxel_size",
            "seg_plane_threshold", "reconstruction_spacing", "angle_tolerance")


def _ramp_plane(noise: NoiseModel, seed: int) -> np.ndarray:
    """Render a plane seen from 0.8 to 1.3 m depth by a narrow camera, with ``noise``.

    The camera's half field of view is 8.3 x 6.2 degrees, so the range of every point
    exceeds its depth z by at most 1 - cos(10.4 deg) = 1.6 %; the plane through (0, 0, 1)
    tilts 65 degrees about x (z - 1 = y tan 65), so along the rays y = +-0.109 z the depth
    runs from 1 / (1 + 0.233) = 0.81 to 1 / (1 - 0.233) = 1.30 m.
    """
    cam = PinholeCamera(fx=1100.0, fy=1100.0, cx=159.5, cy=119.5, width=320, height=240)
    tilt = np.radians(65.0)
    rot = np.array([[1.0, 0.0, 0.0], [0.0, np.cos(tilt), -np.sin(tilt)],
                    [0.0, np.sin(tilt), np.cos(tilt)]])
    plane = Rectangle(3.0, 3.0, center=[0.0, 0.0, 1.0], rotation=rot)
    organized, labels = cam.render([plane])
    organized, _ = apply_noise(organized, labels, noise, seed)
    return organized.reshape(-1, 3)


def test_estimator_recovers_known_sigma_of_depth():
    # sigma(z) = 1.2 mm + 0.8 mm z^2 put in along the rays; the plane fills the view.
    # About 2000 neighbourhoods in 6 depth bins: each bin's median of a residual with
    # 17 degrees of freedom has a relative standard error of about 1.25 / sqrt(2 * 17 * 330)
    # = 1.2 %, and the fit of two parameters to six medians stays within 3 standard errors
    # (4 %); the dominant plane's scale (>= 1, a MAD of 5000 points and the incidence
    # cosines) adds up to +6 % (measured over seeds), the range-vs-depth difference 1.6 %,
    # and the median residual of a 20-point plane fit runs about 4 % low: 10 %.
    noise = NoiseModel(sigma_offset=0.0012, sigma_at_0_5m=0.0002)
    pts = _ramp_plane(noise, seed=3)
    est = estimate_noise(pts, rng=0)
    assert est.samples > 1500
    for z in (0.85, 1.0, 1.2):
        assert est.sigma(z) == pytest.approx(float(noise.sigma(z)), rel=0.1), z
    # A single plane: the dominant plane's residual is the local noise (scale 1 within
    # the same statistics).
    assert est.scale == pytest.approx(1.0, abs=0.1)
    # Negative: a noise twice as large is not mistaken for this one.
    loud = estimate_noise(_ramp_plane(NoiseModel(sigma_offset=0.0024, sigma_at_0_5m=0.0004),
                                      seed=3), rng=0)
    assert loud.sigma(1.0) > 1.7 * est.sigma(1.0)


def test_estimator_recovers_sigma_on_a_rendered_desk_scene():
    # The paper's scene 3 with Kinect-class noise: desk and objects at 0.4-0.6 m.
    scene = render_scene("scene3", noise=KINECT_CLASS_NOISE, rng=1)
    est = estimate_noise(scene.points, rng=0)
    z = est.depth
    assert est.sigma(z) == pytest.approx(float(KINECT_CLASS_NOISE.sigma(z)), rel=0.08)


def test_estimator_point_spacing_of_a_camera():
    # 1100 px focal length: a plane facing the camera at 1 m and at 2 m is sampled every
    # z / 1100 in both directions, so spacing_per_m = 1 / 1100 at both distances (the
    # Poisson approximation of the subset's nearest neighbours is good to about 10 % on
    # such a grid).
    cam = PinholeCamera(fx=1100.0, fy=1100.0, cx=159.5, cy=119.5, width=320, height=240)
    for z in (1.0, 2.0):
        organized, _ = cam.render([Rectangle(3.0, 3.0, center=[0.0, 0.0, z])])
        est = estimate_noise(organized.reshape(-1, 3), rng=0)
        assert est.spacing_per_m == pytest.approx(1.0 / 1100, rel=0.1), z
        assert est.spacing == pytest.approx(z / 1100, rel=0.1), z


def test_noise_free_scene_estimates_about_zero_and_resolves_nothing():
    scene = render_scene("scene3")
    params = ModelingParams()
    resolved, est = resolve_params(scene.points, params)
    assert est is not None and est.samples > 0
    assert est.sigma(1.0) < 1e-5
    # Every noise-dependent threshold stays at its given (noise-free) value.
    for name in RESOLVED:
        assert getattr(resolved, name) == getattr(params, name), name


def test_noise_free_auto_equals_fixed_end_to_end():
    # On a noise-free scene auto must not change a single output (nor a random draw).
    scene = render_scene("apart")
    la, ra = model_scene(scene.points, ModelingParams())
    lf, rf = model_scene(scene.points, ModelingParams(noise_model="fixed"))
    np.testing.assert_array_equal(la, lf)
    assert [o.to_dict() for o in ra.objects] == [o.to_dict() for o in rf.objects]
    assert ra.noise is not None and rf.noise is None and ra.fragments == 0


def test_fixed_returns_the_parameters_given_and_estimates_nothing():
    scene = render_scene("apart", noise=KINECT_CLASS_NOISE, rng=2)
    params = ModelingParams(noise_model="fixed", ransac_threshold=0.0031)
    resolved, est = resolve_params(scene.points, params)
    assert resolved is params and est is None
    noisy = NoiseEstimate(a=0.01, b=0.0, spacing_per_m=0.01, samples=100)
    assert object_params(params, noisy, 1.0, 0.1) is params
    assert not is_fragment(1, 1.0, noisy, params)
    _, result = model_scene(scene.points, params)
    assert result.noise is None and result.fragments == 0
    assert result.to_dict()["noise"] is None


def test_mapping_worked_out_by_hand():
    # sigma(1 m) = 1 mm + 1 mm = 2 mm; spacing 2 mm at 1 m; dominant plane at 1 m seen at
    # cos 0.5; object 0.3 m across.
    est = NoiseEstimate(a=0.001, b=0.001, spacing_per_m=0.002, spacing=0.002, depth=1.0,
                        samples=1000, plane_cos=0.5, plane_depth=1.0)
    p = object_params(ModelingParams(), est, 1.0, 0.3)
    assert p.noise_amplitude == pytest.approx(0.002)           # 1 sigma
    assert p.ransac_threshold == pytest.approx(0.007)          # 3.5 sigma
    assert p.voxel_size == pytest.approx(0.010)                # 5 sigma (< 0.3 m / 10)
    assert p.seg_voxel_size == pytest.approx(0.004)            # 2 spacings = the floor
    assert p.seg_plane_threshold == pytest.approx(0.004)       # 4 sigma * 0.5
    assert p.reconstruction_spacing == pytest.approx(0.002)    # 1 spacing = the floor
    # Sparse sampling (a room 5 m away at 7 mm/m: 35 mm spacing) sets the voxels.
    far = dataclasses.replace(est, a=0.001, b=0.0, spacing_per_m=0.007)
    q = object_params(ModelingParams(), far, 5.0, 2.0)
    assert q.seg_voxel_size == pytest.approx(0.070) and q.voxel_size == pytest.approx(0.035)
    # atan(7 mm / 300 mm) = 0.02333 rad, in quadrature with 0.14 rad.
    assert p.angle_tolerance == pytest.approx(math.hypot(0.14, math.atan(0.007 / 0.3)))
    # A small object keeps at least ten voxels across it: 60 mm -> 6 mm, not 10 mm.
    assert object_params(ModelingParams(), est, 1.0, 0.06).voxel_size == pytest.approx(0.006)


def test_mapping_keeps_floors_and_never_lowers_a_value():
    tiny = NoiseEstimate(a=1e-6, b=0.0, spacing_per_m=1e-4, samples=1000)
    params = ModelingParams(ransac_threshold=0.01, voxel_size=0.02)
    p = object_params(params, tiny, 1.0, 0.2)
    for name in RESOLVED:
        assert getattr(p, name) >= getattr(params, name) - 1e-15, name
    assert p.ransac_threshold == 0.01 and p.voxel_size == 0.02


def test_huge_noise_is_clipped_to_the_allowed_ranges():
    wild = NoiseEstimate(a=10.0, b=0.0, spacing_per_m=10.0, samples=1000)
    p = object_params(ModelingParams(), wild, 1.0, 100.0)
    highs = {s.name: s.high for s in PARAMETERS}
    for name in ("ransac_threshold", "voxel_size", "seg_voxel_size", "noise_amplitude"):
        assert getattr(p, name) == highs[name], name


def test_fragment_rule():
    # Spacing 2 mm at 1 m; segmentation voxel max(4 mm, 2 spacings) = 4 mm; a square of
    # 12 voxels = 48 mm: 0.0023 m^2 = 576 points of 4 mm^2.
    est = NoiseEstimate(a=0.001, b=0.0, spacing_per_m=0.002, samples=1000)
    params = ModelingParams()
    assert is_fragment(575, 1.0, est, params)
    assert not is_fragment(577, 1.0, est, params)
    assert not is_fragment(575, 1.0, NoiseEstimate(), params)   # no estimate
    assert not is_fragment(575, 1.0, None, params)


def test_noise_model_parameter_is_validated():
    assert ModelingParams().noise_model == "auto"
    with pytest.raises(ParameterError, match="noise_model.*auto, fixed"):
        ModelingParams(noise_model="adaptive")
    with pytest.raises(ParameterError, match="noise_model"):
        ModelingParams(noise_model=1)


def test_noisy_scene_that_failed_with_fixed_defaults_types_correctly():
    # Scene 3 of the paper with Kinect-class noise, ground-truth labels: with every
    # threshold at its noise-free default two objects came out unknown (a box and the
    # sphere); auto types all eight.
    from geomodel_ros.tools.evaluation import score_objects

    scene = render_scene("scene3", noise=KINECT_CLASS_NOISE, rng=1)
    result = model_objects(scene.points, scene.labels, ModelingParams())
    scores = score_objects(result.objects, scene.objects)
    assert [s.estimated for s in scores if not s.type_correct] == []
    assert result.noise is not None
    assert result.noise.sigma(0.5) == pytest.approx(float(KINECT_CLASS_NOISE.sigma(0.5)), rel=0.1)


def _room_types(params: ModelingParams) -> dict[int, str]:
    """Ground-truth id -> type of the object that holds most of its points, or "none"."""
    scene = room_scene(rng=1)
    labels, result = model_scene(scene.points, params)
    by_id = {o.id: o for o in result.objects}
    got = {}
    for gt in scene.objects:
        inter = np.bincount(labels[(scene.labels == gt.id) & (labels >= 0)])
        got[gt.id] = str(by_id[int(np.argmax(inter))].type) if inter.size else "none"
    return got


def test_room_scene_with_defaults_gives_walls_and_floor_as_planes():
    # Walls and floor at 1-9 m, a table and a cabinet; laser-like 5 mm noise, 5 cm spacing
    # far away. fixed (desk-scale voxels) cannot segment it.
    truth = {o.id: o.type for o in room_scene(rng=1).objects}
    got = _room_types(ModelingParams())
    planes = [i for i, t in truth.items() if t == "plane"]
    assert len(planes) == 4
    assert all(got[i] == "plane" for i in planes), got
    fixed = _room_types(ModelingParams(noise_model="fixed"))
    assert sum(fixed[i] == "plane" for i in planes) < 4


def test_room_scene_with_defaults_gives_furniture_as_cuboids():
    truth = {o.id: o.type for o in room_scene(rng=1).objects}
    got = _room_types(ModelingParams())
    assert all(got[i] == "cuboid" for i, t in truth.items() if t == "cuboid"), got


def test_noise_and_fragments_in_json_output(tmp_path):
    from geomodel_ros.tools.cli import main
    from geomodel_ros.tools.io import write_npy

    scene = render_scene("apart", noise=KINECT_CLASS_NOISE, rng=1)
    cloud = tmp_path / "apart.npy"
    write_npy(cloud, scene.points)
    out = tmp_path / "out.json"
    assert main(["model", str(cloud), "--json", str(out)]) == 0
    data = json.loads(out.read_text())
    assert set(data["noise"]) >= {"a", "b", "spacing_per_m", "samples"}
    assert data["noise"]["samples"] > 0 and isinstance(data["fragments"], int)
    assert data["noise"]["a"] + data["noise"]["b"] * 0.25 == pytest.approx(
        float(KINECT_CLASS_NOISE.sigma(0.5)), rel=0.15)


def test_max_range_default_allows_room_scale_and_still_drops_garbage():
    params = ModelingParams()
    assert params.max_range >= 15.0
    far = np.array([[0.0, 0.0, 14.9], [0.0, 0.0, 1e9]])
    from geomodel_ros.core.input import in_range
    assert in_range(far, params.max_range).tolist() == [True, False]


def test_estimate_is_reproducible_and_does_not_touch_the_callers_stream():
    scene = render_scene("apart", noise=KINECT_CLASS_NOISE, rng=4)
    assert nz.frame_noise(scene.points, ModelingParams()) == \
        nz.frame_noise(scene.points, ModelingParams())
    rng = np.random.default_rng(7)
    state = rng.bit_generator.state
    resolve_params(scene.points, ModelingParams())
    assert rng.bit_generator.state == state


def test_degenerate_clouds_give_no_estimate():
    assert estimate_noise(np.zeros((0, 3))).samples == 0
    assert estimate_noise(np.full((500, 3), np.nan)).samples == 0
    line = np.column_stack([np.linspace(0, 1, 50), np.zeros(50), np.ones(50)])
    assert estimate_noise(line).samples == 0
    params = ModelingParams()
    resolved, est = resolve_params(line, params)
    assert resolved == params and est.samples == 0


def test_replace_keeps_noise_model():
    p = dataclasses.replace(ModelingParams(noise_model="fixed"), voxel_size=0.004)
    assert p.noise_model == "fixed"


def test_noise_values_for_diagnostics():
    from msg_adapters.diagnostics import noise_values

    est = NoiseEstimate(a=0.001, b=0.0005, spacing_per_m=0.002, samples=1234)
    values = noise_values(est, 3)
    assert list(values) == ["noise_sigma_a_m", "noise_sigma_b_per_m", "noise_sigma_at_1m_m",
                            "noise_spacing_per_m", "noise_samples", "fragments"]
    assert values["noise_sigma_at_1m_m"] == "0.001500"        # a + b * 1^2
    assert values["noise_samples"] == "1234" and values["fragments"] == "3"
    assert noise_values(None, 0) == {"fragments": "0"}          # noise_model fixed


def test_processed_frame_carries_the_noise_for_diagnostics():
    from ros_helpers import scene_cloud

    from geomodel_ros.ros.processing import process_cloud

    frame = process_cloud(scene_cloud("tiny_box"), ModelingParams(), segments=False,
                          reconstruction=False)
    assert int(frame.diagnostics["noise_samples"]) > 0
    assert float(frame.diagnostics["noise_sigma_at_1m_m"]) < 1e-5   # a noise-free render
    fixed = process_cloud(scene_cloud("tiny_box"), ModelingParams(noise_model="fixed"),
                          segments=False, reconstruction=False)
    assert fixed.diagnostics == {"fragments": "0"}
