"""A tall can seen from above: its length judged by its side's points, not its lid's.

A round body longer than 1.5 times the bulk of its points along its axis (+ 2 cm) is
refused: strays on the side's extended surface must not stretch it. Seen from 83-85 deg
above the desk, a tall can shows its lid whole (90-94 % of its points, all at one place
along the axis) and a strip of its side down to the desk: the bulk of all its points is
then the lid's few millimetres, while the side's points run the can's length. The bulk
of the side's own points counts too. Expected sizes are the rendered shapes'
(:mod:`geomodel_ros.tools.synth.clutter`).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from geomodel_ros.core.fitting.measure import bulk_extent, side_bulk
from geomodel_ros.tools.synth.clutter import KINECT_NOISE, render_clutter
from suite_helpers import can_cylinder

MM = 1e-3
Z = np.array([0.0, 0.0, 1.0])


def _lid_and_side(lid_points: int = 9000, side_points: int = 150, strays: int = 0):
    """Return a lid at z = 0 (r 45 mm) and a side strip from z = -150 mm to 0, and the side."""
    rng = np.random.default_rng(4)
    phi = rng.uniform(0.0, 2.0 * math.pi, lid_points)
    rho = 0.045 * np.sqrt(rng.uniform(0.0, 1.0, lid_points))
    lid = np.column_stack([rho * np.cos(phi), rho * np.sin(phi), np.zeros(lid_points)])
    a = rng.uniform(-0.3, 0.3, side_points)
    side = np.column_stack([0.045 * np.cos(a), 0.045 * np.sin(a),
                            rng.uniform(-0.15, 0.0, side_points)])
    if strays:  # on the side's surface, 0.5-0.6 m below the lid
        side[:strays, 2] = rng.uniform(-0.6, -0.5, strays)
    return np.vstack([lid, side]), side


def test_the_side_bulk_is_the_longer_of_the_objects_and_the_sides():
    points, side = _lid_and_side()
    assert bulk_extent(points, Z) < 0.01              # the lid's place: 98 % of the points
    # The side's 2nd-98th percentile of a uniform 150 mm: 144 mm.
    assert side_bulk(points, side, Z) == pytest.approx(0.144, abs=0.006)
    # Without side points, or with a side no longer than the object's bulk: the object's.
    assert side_bulk(points, side[:0], Z) == bulk_extent(points, Z)
    flat = side * np.array([1.0, 1.0, 0.0])
    assert side_bulk(points, flat, Z) == bulk_extent(points, Z)


def test_a_few_strays_on_the_sides_surface_stay_outside_its_bulk():
    # 2 of the side's 150 points 0.5-0.6 m away along the axis: the bulk stays the side's.
    points, side = _lid_and_side(strays=2)
    assert side_bulk(points, side, Z) == pytest.approx(0.144, abs=0.01)


@pytest.mark.parametrize("noise, seed, gt_id", [(None, 37, 8), (KINECT_NOISE, 37, 8),
                                                (None, 39, 9), (KINECT_NOISE, 39, 9)])
def test_a_tall_can_seen_by_its_lid_and_a_strip_of_side_is_a_cylinder_of_its_size(
        noise, seed, gt_id):
    # Cans r 45.2 mm, h 156.5 mm at 0.53 m and r 25.5 mm, h 76.4 mm at 0.66 m, seen from
    # 83 and 85 deg above the desk: `unknown` ("the object's points span 32 mm along its
    # axis") or not reported before.
    tol = 0.3 * MM if noise is None else 2.0 * MM
    can_cylinder(render_clutter(seed, noise), gt_id, tol, 2 * tol)
