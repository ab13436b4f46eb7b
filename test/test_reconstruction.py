"""Reconstruction (geomodel_ros.core.reconstruction): samples lie on the modeled surface.

Every expectation comes from the primitive's definition (see
:class:`~geomodel_ros.core.primitives.Primitive`): a cuboid of the given dimensions
centred at ``center`` with axes ``rotation``; a cone whose apex is at
``center + height / 2 * z`` and whose base (radius ``radius``) at ``center - height / 2 * z``.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from geomodel_ros.core.primitives import Primitive
from geomodel_ros.core.reconstruction import reconstruct, sample_primitive, surface_area

ROT = Rotation.from_euler("zyx", [0.7, -0.4, 1.9]).as_matrix()
CENTER = np.array([0.1, -0.05, 0.8])
SPACING = 0.002
EXACT = 1e-12  # [m] round-off of a rotation and a translation


def prim(kind, dims, rotation=ROT, center=CENTER, oid=3):
    return Primitive(oid, kind, center, rotation, dims, 100, 0.0)


def local(points, rotation=ROT, center=CENTER):
    """Express samples in the primitive's own frame."""
    return (points - center) @ rotation


def test_a_cuboid_is_sampled_on_its_box_surface_and_nowhere_else():
    half = np.array([0.10, 0.06, 0.04]) / 2
    box = prim("cuboid", {"length": 0.10, "width": 0.06, "height": 0.04})
    q = local(sample_primitive(box, SPACING))
    # Inside the box, on one of its faces ...
    assert np.all(np.abs(q) <= half + EXACT)
    on_face = np.isclose(np.abs(q), half, rtol=0, atol=EXACT)
    assert np.all(on_face.any(axis=1))
    # ... all six faces, reaching every edge: extents are exactly the dimensions.
    np.testing.assert_allclose(q.max(axis=0), half, atol=EXACT)
    np.testing.assert_allclose(q.min(axis=0), -half, atol=EXACT)
    for a in range(3):
        for side in (-1, 1):
            face = q[np.isclose(q[:, a], side * half[a], rtol=0, atol=EXACT)]
            others = [i for i in range(3) if i != a]
            # Face sampled at about the spacing: its area / spacing^2 samples or more.
            area = 4 * half[others[0]] * half[others[1]]
            assert len(face) >= area / SPACING ** 2


def test_a_cone_narrows_towards_its_apex_on_z():
    r, h = 0.03, 0.05
    cone = prim("cone", {"radius": r, "height": h})
    q = local(sample_primitive(cone, SPACING / 2))
    rho = np.hypot(q[:, 0], q[:, 1])
    assert np.all(np.abs(q[:, 2]) <= h / 2 + EXACT)
    base = np.isclose(q[:, 2], -h / 2, rtol=0, atol=EXACT)
    assert np.all(rho[base] <= r + EXACT) and rho[base].max() == pytest.approx(r, abs=EXACT)
    # The side: radius r at the base, shrinking linearly to 0 at z = +h/2 (the apex).
    side = ~base
    np.testing.assert_allclose(rho[side], r * (h / 2 - q[side, 2]) / h, atol=EXACT)
    assert q[side, 2].max() > h / 2 - 0.1 * h
    # In the world frame the apex is at centre + h/2 * z: the sample farthest along z.
    apex = CENTER + h / 2 * ROT[:, 2]
    world = sample_primitive(cone, SPACING / 2)
    top = world[np.argmax((world - CENTER) @ ROT[:, 2])]
    assert np.linalg.norm(top - apex) < 0.1 * r


def test_a_cylinder_has_its_side_at_the_radius_and_two_caps():
    r, h = 0.04, 0.12
    q = local(sample_primitive(prim("cylinder", {"radius": r, "height": h}), SPACING))
    rho = np.hypot(q[:, 0], q[:, 1])
    caps = np.isclose(np.abs(q[:, 2]), h / 2, rtol=0, atol=EXACT)
    np.testing.assert_allclose(rho[~caps], r, atol=EXACT)
    assert np.all(rho[caps] <= r + EXACT)
    assert np.any(q[caps, 2] > 0) and np.any(q[caps, 2] < 0)
    assert q[:, 2].max() == pytest.approx(h / 2, abs=EXACT)
    assert q[:, 2].min() == pytest.approx(-h / 2, abs=EXACT)


def test_a_sphere_is_sampled_at_its_radius_all_round():
    q = local(sample_primitive(prim("sphere", {"radius": 0.025}, rotation=np.eye(3)), SPACING),
              rotation=np.eye(3))
    np.testing.assert_allclose(np.linalg.norm(q, axis=1), 0.025, atol=EXACT)
    # All round: every octant holds samples.
    octants = {tuple(row) for row in (q > 0).astype(int)}
    assert len(octants) == 8


def test_a_plane_is_its_rectangle():
    q = local(sample_primitive(prim("plane", {"length": 0.4, "width": 0.3}), SPACING))
    np.testing.assert_allclose(q[:, 2], 0.0, atol=EXACT)
    np.testing.assert_allclose(q[:, :2].max(axis=0), [0.2, 0.15], atol=EXACT)
    np.testing.assert_allclose(q[:, :2].min(axis=0), [-0.2, -0.15], atol=EXACT)


def test_samples_are_about_spacing_apart():
    from scipy.spatial import cKDTree

    box = prim("cuboid", {"length": 0.1, "width": 0.06, "height": 0.04})
    pts = sample_primitive(box, SPACING)
    d, _ = cKDTree(pts).query(pts, k=2)
    assert np.median(d[:, 1]) == pytest.approx(SPACING, rel=0.1)


def test_an_unknown_object_has_no_samples():
    assert sample_primitive(prim("unknown", {}), SPACING).shape == (0, 3)
    assert surface_area(prim("unknown", {})) == 0.0


@pytest.mark.parametrize(("kind", "dims", "area"), [
    ("plane", {"length": 0.4, "width": 0.3}, 0.12),
    ("cuboid", {"length": 0.1, "width": 0.06, "height": 0.04}, 2 * (0.006 + 0.004 + 0.0024)),
    ("cylinder", {"radius": 0.04, "height": 0.12}, 2 * math.pi * 0.04 * 0.16),
    ("cone", {"radius": 0.03, "height": 0.04}, math.pi * 0.03 * (0.03 + 0.05)),
    ("sphere", {"radius": 0.025}, 4 * math.pi * 0.025 ** 2),
])
def test_surface_areas(kind, dims, area):
    assert surface_area(prim(kind, dims)) == pytest.approx(area, rel=1e-12)


def test_reconstruct_labels_every_sample_with_its_object_and_keeps_the_budget():
    objs = [prim("sphere", {"radius": 0.02}, oid=4),
            prim("plane", {"length": 10.0, "width": 10.0}, oid=9)]
    pts, ids = reconstruct(objs, SPACING, max_points_per_object=50_000)
    assert pts.shape == (len(ids), 3) and ids.dtype == np.int32
    assert set(np.unique(ids)) == {4, 9}
    sphere = pts[ids == 4]
    np.testing.assert_allclose(np.linalg.norm(sphere - CENTER, axis=1), 0.02, atol=EXACT)
    np.testing.assert_array_equal(sphere, sample_primitive(objs[0], SPACING))
    assert 0 < np.count_nonzero(ids == 9) <= 50_000
    empty_pts, empty_ids = reconstruct([], SPACING)
    assert empty_pts.shape == (0, 3) and empty_ids.shape == (0,)
