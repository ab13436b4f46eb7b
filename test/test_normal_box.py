"""A box rival from the modes of the point normals, judged on the normals against a round fit.

Modules: core.fitting.normal_box, core.confidence.surface_normals and
core.fitting.strategies (normal_box_rival, prefer_box_of_normals).

By hand: a normal at half the tolerance from the model's costs (1/2)^2 = 1/4, one beyond
the tolerance 1, whichever way either points; a cylinder's surface normal at a point is
the point's radial direction from the axis, a cap's is the axis, a box's is the axis of
the face the point lies on.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.ndimage import gaussian_filter
from scipy.spatial.transform import Rotation

from geomodel_ros.core.confidence import surface_normals
from geomodel_ros.core.fitting import strategies
from geomodel_ros.core.fitting.normal_box import (MIN_SIDE_NORMALS, axis_costs, box_axes,
                                                  normal_costs, side_labels)
from geomodel_ros.core.fitting.strategies import (Situation, box_rival, normal_box_rival,
                                                  prefer_box_of_normals)
from geomodel_ros.core.geometry import frame_with_z
from geomodel_ros.core.model_graph import GraphDecision
from geomodel_ros.core.params import ModelingParams
from geomodel_ros.core.primitives import Primitive, PrimitiveType

from test_fitting_units import cloud_of, facing
from test_paired_cost import _object_over
from geomodel_ros.tools.synth.suite import SuiteCase

DEG = math.radians(1.0)
#: A box 100 x 70 x 60 mm at 1 m, turned so that three of its sides face the sensor.
BOX_ROT = Rotation.from_euler("xyz", [2.0, 0.5, 0.6]).as_matrix()
BOX_CENTER = np.array([0.05, 0.02, 1.0])
BOX_DIMS = np.array([0.10, 0.07, 0.06])


def _unit(v):
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _scattered(directions, spread, rng):
    """Return unit vectors (n, 3) about ``directions`` (n, 3), turned by about ``spread`` [rad]."""
    return _unit(directions + rng.normal(0.0, spread, directions.shape))


def _box_normals(rng, counts=(300, 200, 100), spread=5 * DEG, strays=60):
    """Return normals of three visible sides of BOX_ROT (counts per axis) and uniform strays."""
    sides = np.concatenate([np.tile(BOX_ROT[:, a], (c, 1)) for a, c in enumerate(counts)])
    return np.concatenate([_scattered(sides, spread, rng),
                           _unit(rng.normal(size=(strays, 3)))])


def _same_line(a, b, within):
    return abs(float(a @ b)) >= math.cos(within)


def test_box_axes_are_the_modes_of_a_box_s_normals():
    n = _box_normals(np.random.default_rng(1))
    axes = box_axes(n, 15 * DEG)
    assert axes is not None
    # The most populated side first, then the most populated perpendicular one.
    assert _same_line(axes[:, 0], BOX_ROT[:, 0], 1 * DEG)
    assert _same_line(axes[:, 1], BOX_ROT[:, 1], 1 * DEG)
    assert _same_line(axes[:, 2], BOX_ROT[:, 2], 1 * DEG)
    assert np.allclose(axes.T @ axes, np.eye(3), atol=1e-9)
    assert np.linalg.det(axes) == pytest.approx(1.0)


def test_one_side_s_normals_give_no_box_axes():
    # A plane's normals: a single mode; the directions across it hold no side.
    rng = np.random.default_rng(2)
    n = _scattered(np.tile(BOX_ROT[:, 0], (500, 1)), 5 * DEG, rng)
    assert box_axes(n, 15 * DEG) is None
    # A second side of fewer than MIN_SIDE_NORMALS normals is no side either.
    n2 = np.concatenate([n, np.tile(BOX_ROT[:, 1], (MIN_SIDE_NORMALS - 1, 1))])
    assert box_axes(n2, 15 * DEG) is None
    n3 = np.concatenate([n, np.tile(BOX_ROT[:, 1], (MIN_SIDE_NORMALS, 1))])
    assert box_axes(n3, 15 * DEG) is not None


def test_side_labels_name_axis_and_direction_and_leave_edges_out():
    axes = np.eye(3)
    n = _unit(np.array([[0.0, 0.0, -1.0], [0.0, 1.0, 0.05], [1.0, 1.0, 0.0],
                        [-1.0, 0.0, 0.0]]))
    # -z: side 2*2+0; +y: 2*1+1; the diagonal is 45 deg from both: an edge; -x: 0.
    assert side_labels(n, axes, 15 * DEG).tolist() == [4, 3, -1, 0]


def test_normal_costs_by_hand():
    tol = 20 * DEG
    model = np.tile([0.0, 0.0, 1.0], (4, 1))
    angles = np.array([0.0, 10.0, 30.0, 180.0 - 10.0]) * DEG  # the last: flipped, 10 deg off
    measured = np.c_[np.sin(angles), np.zeros(4), np.cos(angles)]
    assert normal_costs(model, measured, tol) == pytest.approx([0.0, 0.25, 1.0, 0.25])
    # The nearest of three axes: the same costs for the nearest axis.
    assert axis_costs(np.eye(3), measured, tol) == pytest.approx([0.0, 0.25, 1.0, 0.25])


def test_surface_normals_of_a_cylinder_and_a_box():
    axis = _unit(np.array([0.0, -0.8, -0.6]))
    rot = frame_with_z(axis)
    center = np.array([0.02, 0.01, 0.6])
    cyl = Primitive(0, PrimitiveType.CYLINDER, center, rot, {"radius": 0.04, "height": 0.12},
                    0, 0.0)
    phi = np.linspace(0.0, 2 * math.pi, 12, endpoint=False)
    radial = np.outer(np.cos(phi), rot[:, 0]) + np.outer(np.sin(phi), rot[:, 1])
    side = center + 0.041 * radial + np.outer(np.linspace(-0.05, 0.05, 12), axis)
    assert np.abs(np.einsum("ij,ij->i", surface_normals(cyl, side), radial)) == \
        pytest.approx(np.ones(12))
    # On a cap (near its centre, nearer to it than to the side) the normal is the axis.
    cap = center + 0.0601 * axis + 0.01 * radial
    assert np.abs(surface_normals(cyl, cap) @ axis) == pytest.approx(np.ones(12))
    box = Primitive(0, PrimitiveType.CUBOID, BOX_CENTER, BOX_ROT,
                    dict(zip(("length", "width", "height"), BOX_DIMS)), 0, 0.0)
    on_faces = BOX_CENTER + np.array([[0.051, 0.0, 0.01], [0.0, -0.034, 0.0],
                                      [0.01, 0.01, 0.031]]) @ BOX_ROT.T
    assert np.abs(surface_normals(box, on_faces) @ BOX_ROT) == pytest.approx(np.eye(3))


def _box_points(seed, sigma, n=20000):
    """Return the visible surface of the box, with independent noise sigma [m] along the rays."""
    rng = np.random.default_rng(seed)
    u = rng.uniform(-0.5, 0.5, (n, 3)) * BOX_DIMS
    side = rng.integers(0, 6, n)
    ax, sign = side // 2, np.where(side % 2, 1.0, -1.0)
    u[np.arange(n), ax] = sign * BOX_DIMS[ax] / 2
    normals = np.zeros((n, 3))
    normals[np.arange(n), ax] = sign
    p = facing(BOX_CENTER + u @ BOX_ROT.T, normals @ BOX_ROT.T)
    return p + rng.normal(0.0, sigma, len(p))[:, None] * _unit(p)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_box_whose_faces_each_span_two_sides_is_a_box_not_round(seed):
    # Three sides seen, the points split into two faces across the view by a plane
    # through the box's centre: each face holds parts of two sides and is curved, so no
    # box of planar faces or flat cores exists. A noise band as at 1.5 m (21 mm, 17 deg).
    params = ModelingParams(ransac_threshold=0.021, angle_tolerance=17 * DEG)
    pts = _box_points(seed, 0.004)
    across = np.cross(BOX_ROT.sum(axis=1), _unit(BOX_CENTER))
    cloud = cloud_of(pts, params, ((pts - BOX_CENTER) @ across > 0).astype(np.int64))
    assert len(cloud.faces) == 2 and not any(f.info.planar for f in cloud.faces)
    assert box_rival(cloud) is None
    # The round model: a cylinder about the box's long axis through its centre, of the
    # radius of the box's cross-section (half its diagonal 46 mm).
    cyl = Primitive(0, PrimitiveType.CYLINDER, BOX_CENTER, frame_with_z(BOX_ROT[:, 0]),
                    {"radius": 0.045, "height": 0.10}, len(pts), 0.0)
    reasons = []
    out, faces = prefer_box_of_normals(
        Situation(cloud, GraphDecision("curved", ("cylinder",), -1)), cyl, (), reasons)
    assert out.type is PrimitiveType.CUBOID
    assert "cuboid" in reasons[-1] and "replaces cylinder" in reasons[-1]
    # Its sides are the three the sensor sees, its size the box's within 3 mm.
    assert sorted(f.surface for f in faces) == ["planar"] * 3
    dims = np.array([out.dimensions[k] for k in ("length", "width", "height")])
    along = np.argmax(np.abs(out.rotation.T @ BOX_ROT), axis=0)  # box axis -> out axis
    assert dims[along] == pytest.approx(BOX_DIMS, abs=0.003)


def _lying_cylinder_points(seed, amplitude, correlation, n=30000):
    """Return the visible half of a cylinder r 30 mm, 120 mm long, lying at 0.5 m, and its truth.

    The radius is perturbed by a smooth random field of standard deviation ``amplitude``
    [m] and correlation length ``correlation`` [m] over the surface: slow depth errors
    that bend its visible half into facets.
    """
    rng = np.random.default_rng(seed)
    axis, center, r, h = np.array([1.0, 0.0, 0.0]), np.array([0.0, 0.05, 0.5]), 0.030, 0.120
    grid = 1e-3
    field = gaussian_filter(rng.normal(size=(int(2 * math.pi * r / grid), int(h / grid))),
                            correlation / grid, mode="wrap")
    field *= amplitude / field.std()
    phi, t = rng.uniform(0.0, 2 * math.pi, n), rng.uniform(-h / 2, h / 2, n)
    i = (phi * r / grid).astype(int) % field.shape[0]
    j = np.minimum(((t + h / 2) / grid).astype(int), field.shape[1] - 1)
    f = frame_with_z(axis)
    radial = np.outer(np.cos(phi), f[:, 0]) + np.outer(np.sin(phi), f[:, 1])
    pts = facing(center + (r + field[i, j])[:, None] * radial + np.outer(t, axis), radial)
    truth = Primitive(0, PrimitiveType.CYLINDER, center, f, {"radius": r, "height": h},
                      len(pts), 0.0)
    return pts, truth


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_cylinder_with_correlated_noise_keeps_its_normals_against_the_box(seed, monkeypatch):
    # 2 mm slow radial errors over 15 mm: the normals bunch into facets, and the box of
    # their modes is built, but the measured normals still agree with the cylinder's
    # beyond the noise; not even the box's axes are judged closer (nothing is fitted).
    params = ModelingParams(ransac_threshold=0.006, angle_tolerance=15 * DEG)
    pts, truth = _lying_cylinder_points(seed, 0.002, 0.015)
    cloud = cloud_of(pts, params)
    assert normal_box_rival(cloud) is not None
    fits = []
    monkeypatch.setattr(strategies, "fit_first", lambda *a, **_: fits.append(a) or (None, []))
    reasons = []
    out, _ = prefer_box_of_normals(Situation(cloud, GraphDecision("curved", ("cylinder",), -1)),
                                   truth, (), reasons)
    assert out is truth and not fits and not reasons


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_fitted_box_of_a_cylinder_s_normals_does_not_replace_it(seed, monkeypatch):
    # As above, with the first look forced to pass: the box is fitted to the sides of
    # the normals' modes, and the measured normals still agree with the cylinder's
    # beyond the noise (the verdict itself, not only the first look, keeps the cylinder).
    params = ModelingParams(ransac_threshold=0.006, angle_tolerance=15 * DEG)
    pts, truth = _lying_cylinder_points(seed, 0.002, 0.015)
    cloud = cloud_of(pts, params)
    monkeypatch.setattr(strategies, "axis_costs", lambda _axes, n, _tol: np.zeros(len(n)))
    reasons = []
    out, _ = prefer_box_of_normals(Situation(cloud, GraphDecision("curved", ("cylinder",), -1)),
                                   truth, (), reasons)
    assert out is truth
    assert len(reasons) == 1 and "cuboid" in reasons[0] and "does not replace" in reasons[0]


def test_the_box_of_normals_needs_a_round_fit_and_the_measured_noise():
    # A cuboid is not judged, and ``fixed`` keeps the previous strategies.
    pts = _box_points(0, 0.0)
    box = Primitive(0, PrimitiveType.CUBOID, BOX_CENTER, BOX_ROT,
                    dict(zip(("length", "width", "height"), BOX_DIMS)), len(pts), 0.0)
    cloud = cloud_of(pts)
    sit = Situation(cloud, GraphDecision("planar", ("cuboid",), 0))
    assert prefer_box_of_normals(sit, box, (), [])[0] is box
    fixed = cloud_of(pts, ModelingParams(noise_model="fixed"))
    cyl = Primitive(0, PrimitiveType.CYLINDER, BOX_CENTER, frame_with_z(BOX_ROT[:, 0]),
                    {"radius": 0.045, "height": 0.10}, len(pts), 0.0)
    sit = Situation(fixed, GraphDecision("curved", ("cylinder",), -1))
    assert prefer_box_of_normals(sit, cyl, (), [])[0] is cyl


@pytest.mark.xfail(strict=True, reason="the box's faces at this grid phase come out planar "
                   "(test_paired_cost._GRID_PHASE); the hand-built boxes above cover the rule")
def test_the_suite_box_far_away_is_sized_from_its_normals_box():
    # set_a's box (100 x 70 x 60 mm) at 1.5 m, kinect-real seed 2: one segment whose two
    # faces each span two sides; a cylinder (r 34 mm) explains its positions as well.
    o = _object_over(SuiteCase("set_a", 1.5, "kinect-real", 2), 1)
    assert o.type == "cuboid"
    assert "box of the point normals' modes" in o.reason
    assert "replaces cylinder" in o.reason
    assert sorted(o.dimensions.values()) == pytest.approx([0.060, 0.070, 0.100], abs=0.005)
