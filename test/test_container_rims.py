"""The container join parts from a container's inside what touches its rim from outside.

Built by hand: the desk is z = 0, heights are z, the sensor looks from -y. A bowl's
inside (a concave patch on a wall of revolution) joined by the border votes to a box's
face that stands on the desk beside it must come apart
(:func:`geomodel_ros.core.joins._part_at_rims`); its own outer wall (a round wall around
the inside), a handle hanging on it (not reaching the desk) and an object joined to a
patch that is not concave must stay.
"""

from __future__ import annotations

import numpy as np

from geomodel_ros.core.joins import join_contained_parts
from geomodel_ros.core.ransac import PlaneModel

from container_helpers import concave_oracle, labels_of_parts, stacked_parts

DESK = PlaneModel(np.array([0.0, 0.0, 1.0]), 0.0)
R, H, WALL = 0.050, 0.055, 0.004
#: Longest link [m], height [m] within which a segment stands on the desk.
LINK, STAND = 0.01, 0.008


def _wall(rng, radius, deg, h, n, inward=False):
    ang = np.radians(rng.uniform(*deg, n))
    radial = np.column_stack([np.cos(ang), np.sin(ang), np.zeros(n)])
    pts = radius * radial
    pts[:, 2] = rng.uniform(*h, n)
    return pts, (-radial if inward else radial)


def _bowl(rng, n, low=0.03):
    # A flared bowl's inside, its back half (azimuths 20-160 deg): radius ``low`` at 10 mm
    # above the desk to R at its rim H; normals inwards and up.
    ang = np.radians(rng.uniform(20.0, 160.0, n))
    z = rng.uniform(0.01, H, n)
    k = (R - low) / (H - 0.01)
    radial = np.column_stack([np.cos(ang), np.sin(ang), np.zeros(n)])
    pts = (low + k * (z - 0.01))[:, None] * radial
    pts[:, 2] = z
    normals = -radial + np.array([0.0, 0.0, k])
    return pts, normals / np.linalg.norm(normals, axis=1)[:, None]


def _face(rng, x, z, n, y=-0.02):
    # A vertical face in the plane y = ``y`` facing the sensor, dense enough to be linked.
    pts = np.column_stack([rng.uniform(*x, n), np.full(n, y), rng.uniform(*z, n)])
    return pts, np.tile([0.0, -1.0, 0.0], (n, 1))


def _run(parts, segs, concave_flags):
    points, normals, comp, labels, bounds = stacked_parts(parts, segs)
    out = join_contained_parts(points, normals, comp, np.ones(len(comp), dtype=bool), DESK,
                               None, (labels, concave_oracle(concave_flags)), (LINK, STAND))
    return labels_of_parts(out, bounds)


def _box_at_the_rim(rng):
    # A box's front face (plane y = 0.03) ending at the rim of the bowl's inside at
    # azimuth 143 deg (x = -0.04), 84 mm tall: it touches the inside only near the rim.
    return _face(rng, (-0.15, -0.042), (0.0, 0.084), 2000, y=0.03)


def test_a_box_face_at_a_bowls_rim_parts_from_its_inside():
    rng = np.random.default_rng(0)
    got = _run([_bowl(rng, 1500), _box_at_the_rim(rng)], [3, 3], [True, False])
    assert len(got[0]) == 1 and len(got[1]) == 1 and got[0] != got[1], got


def test_a_surface_continuing_the_inside_below_its_rim_stays():
    # The same face, but touching the inside along its lower half only (a fold of one
    # surface, not a contact over a rim): it stays.
    rng = np.random.default_rng(0)
    face = _face(rng, (-0.15, -0.028), (0.0, 0.03), 1500, y=0.02)
    got = _run([_bowl(rng, 1500), face], [3, 3], [True, False])
    assert got == [{3}, {3}], got


def test_without_a_concave_patch_nothing_parts():
    rng = np.random.default_rng(0)
    got = _run([_bowl(rng, 1500), _box_at_the_rim(rng)], [3, 3], [False, False])
    assert got[0] == got[1] == {3}, got


def test_a_cups_outer_wall_and_a_handle_stay_with_its_inside():
    rng = np.random.default_rng(1)
    inside = _wall(rng, R, (20.0, 160.0), (0.01, H), 800, inward=True)
    outer = _wall(rng, R + WALL, (200.0, 340.0), (0.0, H), 800)
    # A handle beside the wall, from 20 to 45 mm above the desk, not reaching it.
    handle = _face(rng, (R + WALL, R + 0.035), (0.02, 0.045), 300)
    got = _run([inside, outer, handle], [4, 4, 4], [True, False, False])
    assert got == [{4}, {4}, {4}], got


def test_a_handle_joined_to_the_inside_alone_stays():
    # The outer wall in another segment (the container join brings it later): the handle
    # lies outside the inside's wall but hangs 20 mm above the desk.
    rng = np.random.default_rng(2)
    inside = _wall(rng, R, (20.0, 160.0), (0.01, H), 800, inward=True)
    handle = _face(rng, (R + WALL, R + 0.035), (0.02, 0.045), 300)
    got = _run([inside, handle], [4, 4], [True, False])
    assert got == [{4}, {4}], got
