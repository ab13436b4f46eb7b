"""Per-object confidence: its terms measured against geometry worked out by hand."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from geomodel_ros.core.confidence import (VIEW_COVERAGE, confidence_value, coverage,
                                          estimate_confidence, surface_distance)
from geomodel_ros.core.modeling import model_objects
from geomodel_ros.core.params import ModelingParams
from geomodel_ros.core.primitives import Confidence, Primitive, PrimitiveType
from geomodel_ros.tools.synth import SENSOR_NOISE, render_scene

NOISE = 0.002  # noise scale [m] (the default ransac_threshold)
EYE = np.eye(3)


def _cylinder(radius=0.04, height=0.1) -> Primitive:
    return Primitive(1, PrimitiveType.CYLINDER, np.zeros(3), EYE,
                     {"radius": radius, "height": height}, 0, 0.0)


def _arc(radius: float, degrees: float, height: float, n_angle: int = 361,
         n_z: int = 21) -> np.ndarray:
    """Points on a cylinder's side (axis z through the origin) over an arc from angle 0."""
    a = np.radians(np.linspace(0.0, degrees, n_angle))
    z = np.linspace(-height / 2, height / 2, n_z)
    aa, zz = np.meshgrid(a, z)
    return np.column_stack([radius * np.cos(aa.ravel()), radius * np.sin(aa.ravel()),
                            zz.ravel()])


# --------------------------------------------------------------------------- distances
def test_surface_distance_of_each_shape_by_hand():
    box = Primitive(1, "cuboid", np.array([1.0, 0, 0]), EYE,
                    {"length": 0.2, "width": 0.1, "height": 0.06}, 0, 0.0)
    pts = np.array([[1.0, 0, 0.05],      # 2 cm above the top face (z half 0.03)
                    [1.0, 0, 0.0],       # the centre: 3 cm inside (nearest: top/bottom)
                    [1.13, 0.07, 0.0],   # beyond an edge: 3 cm and 2 cm out -> sqrt(13) cm
                    [1.05, -0.05, 0.01]])  # on the y = -0.05 face
    assert surface_distance(box, pts) == pytest.approx([0.02, 0.03, math.sqrt(13) * 0.01, 0.0])
    cyl = _cylinder()
    pts = np.array([[0.05, 0, 0], [0, 0, 0.07], [0.0, 0.0, 0.0], [0.05, 0, 0.06]])
    # 1 cm outside the side; 2 cm above the top cap; the centre (4 cm from the side, 5 cm
    # from the caps); 1 cm out and 1 cm up from the rim -> sqrt(2) cm.
    assert surface_distance(cyl, pts) == pytest.approx([0.01, 0.02, 0.04, math.sqrt(2) * 0.01])
    # Cone: base radius 3 cm at z = -5 cm, apex at z = +5 cm.
    cone = Primitive(1, "cone", np.zeros(3), EYE, {"radius": 0.03, "height": 0.1}, 0, 0.0)
    slant = np.array([0.015, 0.0, 0.0])  # half-way up the side (radius halves)
    assert surface_distance(cone, np.array([[0, 0, 0.05], [0, 0, -0.05], slant])) == \
        pytest.approx([0, 0, 0], abs=1e-12)
    sphere = Primitive(1, "sphere", np.array([0, 0, 1.0]), EYE, {"radius": 0.05}, 0, 0.0)
    assert surface_distance(sphere, np.array([[0, 0.08, 1.0], [0, 0, 1.0]])) == \
        pytest.approx([0.03, 0.05])
    plane = Primitive(1, "plane", np.zeros(3), EYE, {"length": 1.0, "width": 1.0}, 0, 0.0)
    assert surface_distance(plane, np.array([[3.0, 2.0, -0.01]])) == pytest.approx([0.01])
    unknown = Primitive(1, "unknown", np.zeros(3), EYE, {}, 0, 0.0)
    assert surface_distance(unknown, pts) is None


# --------------------------------------------------------------------------- coverage
def test_quarter_arc_covers_half_of_what_a_half_arc_covers():
    cyl = _cylinder()
    quarter = coverage(cyl, _arc(0.04, 90.0, 0.1), NOISE)
    half = coverage(cyl, _arc(0.04, 180.0, 0.1), NOISE)
    # 90 and 180 degrees of 360, sampled every 0.25 / 0.5 degrees.
    assert quarter == pytest.approx(0.25, abs=1e-9)
    assert half == pytest.approx(0.5, abs=1e-9)
    cq = estimate_confidence(cyl, _arc(0.04, 90.0, 0.1), NOISE)
    ch = estimate_confidence(cyl, _arc(0.04, 180.0, 0.1), NOISE)
    assert cq.value == pytest.approx(0.5, abs=1e-6)  # coverage term 0.25 / VIEW_COVERAGE
    assert ch.value == pytest.approx(1.0, abs=1e-6)
    assert cq.value < ch.value


def test_cap_points_do_not_count_towards_a_cylinders_arc():
    # A lid covers every direction round the axis; the side's 90-degree arc is what counts.
    cyl = _cylinder()
    r = np.linspace(0.0, 0.039, 20)
    a = np.radians(np.arange(0, 360, 2.0))
    rr, aa = np.meshgrid(r, a)
    lid = np.column_stack([rr.ravel() * np.cos(aa.ravel()), rr.ravel() * np.sin(aa.ravel()),
                           np.full(rr.size, 0.05)])
    pts = np.vstack([_arc(0.04, 90.0, 0.1), lid])
    assert coverage(cyl, pts, NOISE) == pytest.approx(0.25, abs=1e-9)


def test_sphere_coverage_is_the_share_of_its_surface_seen():
    # Area-uniform points on the hemisphere z >= 0: cos(theta) uniform in [0, 1], so the
    # 98th percentile of theta has cos = 0.02 and the cap covers (1 - 0.02) / 2 = 0.49.
    rng = np.random.default_rng(0)
    n = 200000
    cos_t = rng.uniform(0.0, 1.0, n)
    phi = rng.uniform(0.0, 2 * math.pi, n)
    sin_t = np.sqrt(1 - cos_t ** 2)
    pts = 0.05 * np.column_stack([sin_t * np.cos(phi), sin_t * np.sin(phi), cos_t])
    sphere = Primitive(1, "sphere", np.zeros(3), EYE, {"radius": 0.05}, 0, 0.0)
    assert coverage(sphere, pts, NOISE) == pytest.approx(0.49, abs=0.005)
    # A cap of 60 degrees: (1 - cos 60) / 2 = 0.25 (the 98th percentile of theta for
    # area-uniform points on it: cos = 1 - 0.98 * 0.5).
    cap = pts[pts[:, 2] >= 0.05 * 0.5]
    assert coverage(sphere, cap, NOISE) == pytest.approx(0.98 * 0.25, abs=0.005)


# --------------------------------------------------------------------------- the value
def test_confidence_value_is_monotone_in_each_term_and_within_0_and_1():
    ratios = np.linspace(0.0, 1.0, 11)
    rmses = np.linspace(0.0, 5.0, 11)
    covers = [None] + list(np.linspace(0.0, 1.0, 11))
    for c in covers:
        for r in rmses:
            v = [confidence_value(i, r, c) for i in ratios]
            assert np.all(np.diff(v) >= 0) and 0.0 <= min(v) and max(v) <= 1.0
        for i in ratios:
            v = [confidence_value(i, r, c) for r in rmses]
            assert np.all(np.diff(v) <= 0)
    for i in ratios:
        v = [confidence_value(i, 0.5, c) for c in covers[1:]]
        assert np.all(np.diff(v) >= 0)
    # The documented formula at hand-picked terms.
    assert confidence_value(0.9, 1.0, None) == pytest.approx(0.45)
    assert confidence_value(1.0, 0.0, 0.2) == pytest.approx(0.2 / VIEW_COVERAGE)
    assert confidence_value(1.0, 0.0, 0.5) == 1.0


def test_clean_fit_scores_higher_than_the_same_shape_with_heavy_noise_and_outliers():
    cyl = _cylinder()
    clean = _arc(0.04, 180.0, 0.1)
    rng = np.random.default_rng(7)
    noisy = clean + rng.normal(0.0, NOISE, clean.shape)
    # 20 % outliers spread through a 20 cm cube round the object.
    outliers = rng.uniform(-0.1, 0.1, (len(clean) // 4, 3))
    dirty = np.vstack([noisy, outliers])
    c_clean = estimate_confidence(cyl, clean, NOISE)
    c_dirty = estimate_confidence(cyl, dirty, NOISE)
    assert c_clean.inlier_ratio == 1.0 and c_clean.rmse_ratio == pytest.approx(0.0, abs=1e-12)
    # Gaussian noise of one noise scale keeps erf(1 / sqrt 2) = 68 % within it; of the
    # outliers a few per cent fall near the surface.
    expected = 0.8 * math.erf(1 / math.sqrt(2))
    assert c_dirty.inlier_ratio == pytest.approx(expected, abs=0.03)
    assert c_dirty.value < 0.7 * c_clean.value


def test_unknown_and_surfaceless_objects_get_zero():
    unknown = Primitive(1, "unknown", np.zeros(3), EYE, {}, 10, 0.0)
    got = estimate_confidence(unknown, np.zeros((10, 3)), NOISE)
    assert got == Confidence() and got.value == 0.0
    assert estimate_confidence(_cylinder(), np.zeros((0, 3)), NOISE).value == 0.0
    with pytest.raises(ValueError, match="noise scale"):
        estimate_confidence(_cylinder(), _arc(0.04, 90, 0.1), 0.0)


# --------------------------------------------------------------------------- the modeling
def test_modeling_sets_confidence_lower_under_noise_and_zero_for_unknown():
    clean = render_scene("tiny_shapes")
    noisy = render_scene("tiny_shapes", noise=SENSOR_NOISE, rng=3)
    # One noise scale for both (fixed): with the per-frame estimate (auto) the noisy
    # frame's scale grows with its noise, which is what its rmse is measured against.
    fixed = ModelingParams(noise_model="fixed")
    r_clean = model_objects(clean.points, clean.labels, fixed)
    r_noisy = model_objects(noisy.points, noisy.labels, fixed)
    for o in r_clean.objects + r_noisy.objects:
        assert o.confidence is not None and 0.0 <= o.confidence.value <= 1.0
        if o.type == "unknown":
            assert o.confidence.value == 0.0
    fitted = {o.id: o for o in r_clean.objects if o.type != "unknown"}
    assert len(fitted) >= 4
    for o in r_noisy.objects:
        if o.id in fitted and o.type == fitted[o.id].type:
            assert o.confidence.value <= fitted[o.id].confidence.value, o.type
    # The torus fits no shape: unknown, confidence 0.
    torus = [o for o in r_clean.objects if o.id == 5]
    assert torus and torus[0].type == "unknown" and torus[0].confidence.value == 0.0
    # JSON carries the value and its terms.
    d = json.loads(json.dumps(r_clean.to_dict()))
    for o in d["objects"]:
        assert 0.0 <= o["confidence"] <= 1.0
        assert set(o["confidence_terms"]) == {"inlier_ratio", "rmse_ratio", "coverage"}
        round_shape = o["type"] in ("cylinder", "cone", "sphere")
        assert (o["confidence_terms"]["coverage"] is not None) == round_shape


def test_primitive_without_estimate_serialises_null_confidence():
    p = _cylinder()
    d = p.to_dict()
    assert d["confidence"] is None and d["confidence_terms"] is None and d["completed"] == []


def test_objects_message_carries_the_confidence_and_nan_when_not_estimated():
    from std_msgs.msg import Header

    from msg_adapters.objects import primitives_to_objects

    header = Header(frame_id="camera_optical")
    scored = Primitive(1, "sphere", np.array([0, 0, 1.0]), EYE, {"radius": 0.05}, 100, 0.001,
                       confidence=Confidence(0.75, 1.0, 0.0, 0.375))
    unknown = Primitive(2, "unknown", np.array([0, 0, 1.0]), EYE, {}, 10, 0.0,
                        confidence=Confidence())
    bare = Primitive(3, "sphere", np.array([0, 0, 1.0]), EYE, {"radius": 0.05}, 100, 0.001)
    got = [m.confidence for m in primitives_to_objects([scored, unknown, bare],
                                                       header).primitives]
    assert got[:2] == [0.75, 0.0] and math.isnan(got[2])
