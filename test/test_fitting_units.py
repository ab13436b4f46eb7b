"""Fitting units (geomodel_ros.core.fitting) called directly on seeded synthetic primitives.

Every cloud is sampled on a primitive of known size and pose, as a camera at the origin
sees it (the side facing it), without noise; each unit must recover that primitive to
what the method achieves noise-free (measured: a few micrometres), and reject clouds of
other shapes with the reason that applies.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from geomodel_ros.core.fitting.cloud import ObjectCloud, build_faces
from geomodel_ros.core.fitting.result import Fitted, FitTask, Rejected
from geomodel_ros.core.fitting.units import FITTING_UNITS
from geomodel_ros.core.geometry import frame_with_z
from geomodel_ros.core.modeling import estimate_spacing
from geomodel_ros.core.params import ModelingParams
from geomodel_ros.core.primitives import PrimitiveType

MM = 1e-3
UM = 1e-6


def cloud_of(points, params=None, face_labels=None, supports=(), seed=0) -> ObjectCloud:
    """Prepare the object as the modeling does (working cloud, faces by region growing)."""
    params = params if params is not None else ModelingParams()
    rng = np.random.default_rng(seed)
    wc, faces, adjacency = build_faces(points, params, face_labels)
    return ObjectCloud(0, points, wc, faces, adjacency, estimate_spacing(points, rng), params,
                       rng, supports)


def facing(points, normals):
    """Keep the points whose outward normal faces the camera at the origin."""
    return points[np.einsum("ij,ij->i", points, normals) < 0]


def fit(kind, cloud, **task):
    return FITTING_UNITS[PrimitiveType(kind)](FitTask(cloud, **task))


# Cylinder: radius 40 mm, height 120 mm, axis tilted towards the camera.
CYL_AXIS = np.array([0.0, -0.8, -0.6])
CYL_CENTER = np.array([0.02, 0.01, 0.6])
CYL_R, CYL_H = 0.040, 0.120


def cylinder_points(seed=0, n=60000, axis=CYL_AXIS, center=CYL_CENTER):
    rng = np.random.default_rng(seed)
    frame = frame_with_z(axis)
    phi, t = rng.uniform(0, 2 * math.pi, n), rng.uniform(-CYL_H / 2, CYL_H / 2, n)
    radial = np.outer(np.cos(phi), frame[:, 0]) + np.outer(np.sin(phi), frame[:, 1])
    return facing(center + CYL_R * radial + np.outer(t, axis), radial)


# Cone: base radius 45 mm, height 70 mm, apex above the base.
CONE_APEX = np.array([0.01, -0.08, 0.6])
CONE_AXIS = np.array([0.0, 0.8, 0.6])  # from the apex to the base
CONE_R, CONE_H = 0.045, 0.070


def cone_points(seed=0, n=60000, start=0.0):
    """Side of the cone from ``start`` (share of the height from the apex) to the base."""
    rng = np.random.default_rng(seed)
    half = math.atan(CONE_R / CONE_H)
    frame = frame_with_z(CONE_AXIS)
    t = np.sqrt(rng.uniform(start ** 2, 1.0, n)) * CONE_H  # uniform over the area
    phi = rng.uniform(0, 2 * math.pi, n)
    radial = np.outer(np.cos(phi), frame[:, 0]) + np.outer(np.sin(phi), frame[:, 1])
    pts = CONE_APEX + np.outer(t, CONE_AXIS) + (t * math.tan(half))[:, None] * radial
    return facing(pts, radial * math.cos(half) - CONE_AXIS * math.sin(half))


SPHERE_CENTER, SPHERE_R = np.array([0.03, -0.02, 0.5]), 0.030


def sphere_points(seed=0, n=40000):
    v = np.random.default_rng(seed).normal(size=(n, 3))
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    return facing(SPHERE_CENTER + SPHERE_R * v, v)


PLANE_ROT = Rotation.from_euler("xyz", [2.7, 0.2, 0.4]).as_matrix()
PLANE_CENTER = np.array([0.01, 0.0, 0.45])


def plane_points(seed=0, n=30000):
    """Sample a 120 x 80 mm rectangle, x along its long side."""
    rng = np.random.default_rng(seed)
    local = np.column_stack([rng.uniform(-0.06, 0.06, n), rng.uniform(-0.04, 0.04, n),
                             np.zeros(n)])
    return PLANE_CENTER + local @ PLANE_ROT.T


BOX_ROT = Rotation.from_euler("xyz", [2.2, 0.3, 0.5]).as_matrix()
BOX_CENTER = np.array([0.02, 0.03, 0.55])
BOX_DIMS = np.array([0.10, 0.06, 0.04])


def box_points(seed=0):
    """Sample the faces of a 100 x 60 x 40 mm box the camera sees; give each point's axis."""
    rng = np.random.default_rng(seed)
    pts, normals, axes = [], [], []
    for a in range(3):
        b, c = [i for i in range(3) if i != a]
        for side in (-1.0, 1.0):
            m = int(1e7 * BOX_DIMS[b] * BOX_DIMS[c])
            local = np.zeros((m, 3))
            local[:, b] = rng.uniform(-BOX_DIMS[b] / 2, BOX_DIMS[b] / 2, m)
            local[:, c] = rng.uniform(-BOX_DIMS[c] / 2, BOX_DIMS[c] / 2, m)
            local[:, a] = side * BOX_DIMS[a] / 2
            pts.append(BOX_CENTER + local @ BOX_ROT.T)
            normals.append(np.tile(side * BOX_ROT[:, a], (m, 1)))
            axes.append(np.full(m, a))
    pts, normals, axes = np.vstack(pts), np.vstack(normals), np.concatenate(axes)
    keep = np.einsum("ij,ij->i", pts, normals) < 0
    return pts[keep], axes[keep]


# ---------------------------------------------------------------------------------------
# Each unit recovers its own primitive
# ---------------------------------------------------------------------------------------


def test_cylinder_unit_recovers_radius_height_and_axis():
    out = fit("cylinder", cloud_of(cylinder_points()))
    assert isinstance(out, Fitted) and out.reason == "cylinder verified"
    prim = out.primitive
    assert prim.type is PrimitiveType.CYLINDER
    assert prim.dimensions["radius"] == pytest.approx(CYL_R, abs=1 * UM)
    assert prim.dimensions["height"] == pytest.approx(CYL_H, abs=0.1 * MM)
    assert np.linalg.norm(prim.center - CYL_CENTER) < 0.01 * MM
    assert abs(prim.rotation[:, 2] @ CYL_AXIS) > math.cos(math.radians(0.01))
    assert prim.rotation[:, 2] @ prim.center < 0  # the axis points towards the sensor
    np.testing.assert_allclose(prim.rotation.T @ prim.rotation, np.eye(3), atol=1e-12)


def test_cone_unit_recovers_size_and_puts_the_apex_on_z():
    out = fit("cone", cloud_of(cone_points()))
    assert isinstance(out, Fitted) and out.reason == "cone verified"
    prim = out.primitive
    assert prim.dimensions["radius"] == pytest.approx(CONE_R, abs=0.02 * MM)
    assert prim.dimensions["height"] == pytest.approx(CONE_H, abs=0.02 * MM)
    # z points from the base to the apex, which lies at centre + height / 2 * z.
    assert prim.rotation[:, 2] @ -CONE_AXIS > math.cos(math.radians(0.01))
    apex = prim.center + prim.dimensions["height"] / 2 * prim.rotation[:, 2]
    assert np.linalg.norm(apex - CONE_APEX) < 1 * UM


def test_sphere_unit_recovers_centre_and_radius():
    out = fit("sphere", cloud_of(sphere_points()))
    assert isinstance(out, Fitted) and out.reason == "sphere verified"
    assert out.primitive.dimensions == {"radius": pytest.approx(SPHERE_R, abs=1 * UM)}
    assert np.linalg.norm(out.primitive.center - SPHERE_CENTER) < 1 * UM
    np.testing.assert_array_equal(out.primitive.rotation, np.eye(3))


def test_plane_unit_recovers_the_rectangle_with_x_along_the_long_side():
    out = fit("plane", cloud_of(plane_points()), main_face=0)
    assert isinstance(out, Fitted) and out.reason == "plane verified"
    prim = out.primitive
    assert prim.dimensions["length"] == pytest.approx(0.120, abs=0.05 * MM)
    assert prim.dimensions["width"] == pytest.approx(0.080, abs=0.05 * MM)
    assert np.linalg.norm(prim.center - PLANE_CENTER) < 0.01 * MM
    assert abs(prim.rotation[:, 2] @ PLANE_ROT[:, 2]) > math.cos(math.radians(0.01))
    assert abs(prim.rotation[:, 0] @ PLANE_ROT[:, 0]) > math.cos(math.radians(0.1))
    assert prim.rotation[:, 2] @ prim.center < 0  # the normal faces the sensor
    assert np.linalg.det(prim.rotation) == pytest.approx(1.0, abs=1e-12)


def test_cuboid_unit_recovers_the_box_from_its_visible_faces():
    pts, axis_of_point = box_points()
    cloud = cloud_of(pts, face_labels=axis_of_point)
    # Each face's box axis, told by its normal (independently of the model graph).
    axis_of_face = tuple(int(np.argmax(np.abs(BOX_ROT.T @ f.info.normal))) for f in cloud.faces)
    assert sorted(axis_of_face) == [0, 1, 2]
    out = fit("cuboid", cloud, main_face=0, axis_of_face=axis_of_face)
    assert isinstance(out, Fitted) and out.reason == "cuboid verified"
    prim = out.primitive
    dims = [prim.dimensions[k] for k in ("length", "width", "height")]
    # The box's axes in the cuboid's order (a permutation with signs).
    match = np.abs(prim.rotation.T @ BOX_ROT)
    np.testing.assert_allclose(match.max(axis=1), 1.0, atol=1e-9)
    np.testing.assert_allclose(dims, BOX_DIMS[np.argmax(match, axis=1)], atol=0.01 * MM)
    assert np.linalg.norm(prim.center - BOX_CENTER) < 0.01 * MM


# ---------------------------------------------------------------------------------------
# ... and rejects other shapes with the reason that applies
# ---------------------------------------------------------------------------------------


def test_a_frustum_is_rejected_by_the_cone_unit_for_stopping_short_of_the_apex():
    # The side from 60 % of the height: its points stop 0.6 * 70 = 42 mm from the apex.
    out = fit("cone", cloud_of(cone_points(start=0.6)))
    assert isinstance(out, Rejected) and out.type is PrimitiveType.CONE
    assert out.reason == "cone rejected: its points stop 42 mm short of the apex (a frustum)"


def test_a_cylinder_is_no_cone():
    out = fit("cone", cloud_of(cylinder_points()))
    assert isinstance(out, Rejected)
    assert out.reason.startswith("cone half-angle") and out.reason.endswith("deg too small")


@pytest.mark.parametrize(("kind", "points"), [
    ("sphere", cylinder_points), ("cylinder", sphere_points), ("cylinder", cone_points),
    ("plane", cylinder_points), ("plane", box_points)])
def test_a_unit_rejects_another_shape_for_its_inlier_ratio(kind, points):
    pts = points()
    pts = pts[0] if isinstance(pts, tuple) else pts
    out = fit(kind, cloud_of(pts), main_face=0)
    assert isinstance(out, Rejected) and out.type == kind
    assert out.reason.startswith(f"{kind} fit rejected: ") and out.reason.endswith(
        "inliers < 80%")


def test_the_cuboid_unit_rejects_a_cylinder():
    out = fit("cuboid", cloud_of(cylinder_points()), main_face=0, axis_of_face=(0,))
    assert isinstance(out, Rejected) and out.reason.startswith("cuboid fit rejected: ")


def test_a_sphere_beyond_max_radius_has_no_hypothesis():
    out = fit("sphere", cloud_of(sphere_points(), ModelingParams(max_radius=0.02)))
    assert out == Rejected(PrimitiveType.SPHERE, "sphere: no valid RANSAC hypothesis")


def test_a_shallow_arc_is_rejected_by_the_cylinder_unit():
    # 25 deg of a 1 m-radius cylinder (min_arc is 45 deg); exact points, so RANSAC finds
    # the true cylinder and only the arc test can reject it.
    rng = np.random.default_rng(4)
    ang = rng.uniform(-math.radians(12.5), math.radians(12.5), 20000)
    pts = np.column_stack([np.sin(ang), rng.uniform(-0.075, 0.075, 20000), 1.8 - np.cos(ang)])
    out = fit("cylinder", cloud_of(pts))
    assert isinstance(out, Rejected)
    # Every point faces the camera: its points seen steeply span the whole arc.
    assert out.reason == ("cylinder rejected: its points seen within 70 deg of its normal "
                          "span only 25 deg around the axis")
    loose = ModelingParams(min_arc=math.radians(20.0))
    out = fit("cylinder", cloud_of(pts, loose))
    assert isinstance(out, Fitted)
    assert out.primitive.dimensions["radius"] == pytest.approx(1.0, abs=1 * MM)


def test_an_axis_prior_rejects_a_cylinder_across_it():
    # The true axis is perpendicular to the prior: no hypothesis follows it.
    across = np.cross(CYL_AXIS, [1.0, 0.0, 0.0])
    out = fit("cylinder", cloud_of(cylinder_points()), axis_prior=across / np.linalg.norm(across))
    assert out == Rejected(PrimitiveType.CYLINDER, "cylinder: no valid RANSAC hypothesis")


def test_a_round_unit_on_an_object_without_curved_faces():
    out = fit("cylinder", cloud_of(plane_points()))
    assert out == Rejected(PrimitiveType.CYLINDER, "cylinder: no curved face")


def test_a_cylinder_beside_a_larger_flat_part_is_rejected_for_coverage():
    # The side passes RANSAC on its own curved face, but a rectangle that is no cap of it
    # holds most of the object's points: the share on the model is the side's share.
    cyl = cylinder_points()
    beside = plane_points(n=40000)
    out = fit("cylinder", cloud_of(np.vstack([cyl, beside])))
    share = round(100 * len(cyl) / (len(cyl) + len(beside)))
    assert share < 50
    assert out == Rejected(PrimitiveType.CYLINDER, f"cylinder rejected: only {share}% of the "
                           "object's points lie on it", misfit=True)
    # With a smaller rectangle most points lie on the cylinder again: it is accepted.
    out = fit("cylinder", cloud_of(np.vstack([cyl, plane_points(n=20000)])))
    assert isinstance(out, Fitted)


@pytest.mark.parametrize("band_mm, is_box", [(39.0, True), (41.0, False)])
def test_a_box_thinner_than_the_inlier_band_is_no_cuboid(band_mm, is_box):
    # The box's smallest extent is 40 mm: within a wider band its opposite faces are one
    # plane's points, and the thickness the fit would report is the band's, not the box's.
    pts, axis_of_point = box_points()
    params = ModelingParams(ransac_threshold=band_mm * MM)
    cloud = cloud_of(pts, params=params, face_labels=axis_of_point)
    axis_of_face = tuple(int(np.argmax(np.abs(BOX_ROT.T @ f.info.normal))) for f in cloud.faces)
    out = fit("cuboid", cloud, main_face=0, axis_of_face=axis_of_face)
    if is_box:
        assert isinstance(out, Fitted)
        assert min(out.primitive.dimensions.values()) == pytest.approx(0.040, abs=0.01 * MM)
    else:
        assert isinstance(out, Rejected) and "inlier band" in out.reason
