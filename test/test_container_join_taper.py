"""The container join on tapered walls (flared cups, pots) built by hand.

:func:`geomodel_ros.core.joins.join_contained_parts` joins the inner wall of an open
container to its outer wall when the outer wall is round (:func:`_round_footprint`: a wall
of revolution about the support normal whose radius changes linearly with height) and the
inner wall lies inside it at its own heights. The desk is z = 0, heights are z.
"""

from __future__ import annotations

import numpy as np
import pytest

from geomodel_ros.core.joins import (CONTAINED_RADIUS_MARGIN, ROUND_MAX_SPREAD, _fit_wall,
                                     _round_footprint, join_contained_parts)
from geomodel_ros.core.ransac import PlaneModel

DESK = PlaneModel(np.array([0.0, 0.0, 1.0]), 0.0)
#: A flared cup standing on its smaller circle: radius 30 mm at the desk, 42 mm at its rim
#: 95 mm above (taper 12/95 = 0.126), as the synthetic suite's open cup.
BASE_R, TOP_R, HEIGHT = 0.030, 0.042, 0.095


def _frustum_wall(rng, center, deg, h, n, noise=0.0, inward=False, thickness=0.0,
                  r0=BASE_R, r1=TOP_R, height=HEIGHT):
    """Points and unit normals of a frustum's wall over azimuths ``deg`` and heights ``h``.

    Radius ``r0`` at the desk to ``r1`` at ``height``; ``thickness`` [m] moves an inner
    wall inwards; ``noise`` [m] is Gaussian, added to the points (not the normals).
    """
    ang = np.radians(rng.uniform(*deg, n))
    z = rng.uniform(*h, n)
    radial = np.column_stack([np.cos(ang), np.sin(ang), np.zeros(n)])
    r = r0 + (r1 - r0) * z / height - thickness
    pts = np.r_[center, 0.0] + r[:, None] * radial + np.column_stack([np.zeros((n, 2)), z])
    # The side's normal tilts down by the taper's angle (outwards, up the flare).
    tilt = np.arctan2(r1 - r0, height)
    normal = np.cos(tilt) * radial - np.sin(tilt) * np.array([0.0, 0.0, 1.0])
    pts = pts + rng.normal(0.0, noise, pts.shape) if noise else pts
    return pts, (-normal if inward else normal)


def _join(parts):
    points = np.vstack([p for p, _ in parts])
    normals = np.vstack([q for _, q in parts])
    comp = np.repeat(np.arange(len(parts)) * 3 + 2, [len(p) for p, _ in parts])
    out = join_contained_parts(points, normals, comp, np.ones(len(comp), dtype=bool), DESK)
    return [set(out[comp == i * 3 + 2].tolist()) for i in range(len(parts))]


def _circle_spread(xy):
    """Median distance from the algebraic circle over its radius (the one-circle measure)."""
    sol, *_ = np.linalg.lstsq(np.c_[xy, np.ones(len(xy))], -(xy * xy).sum(axis=1), rcond=None)
    c = -0.5 * sol[:2]
    r = np.sqrt(c @ c - sol[2])
    return np.median(np.abs(np.linalg.norm(xy - c, axis=1) - r)) / r


def test_a_tapered_walls_fit_finds_its_centre_radius_and_taper():
    rng = np.random.default_rng(3)
    pts, _ = _frustum_wall(rng, (0.2, -0.1), (180.0, 360.0), (0.0, HEIGHT), 600)
    wall = _fit_wall(pts[:, :2], pts[:, 2], tapered=True)
    assert wall is not None
    np.testing.assert_allclose(wall.center, [0.2, -0.1], atol=1e-9)
    assert wall.taper == pytest.approx((TOP_R - BASE_R) / HEIGHT, abs=1e-9)
    np.testing.assert_allclose(wall.radius_at(np.array([0.0, HEIGHT, 2 * HEIGHT])),
                               [BASE_R + (TOP_R - BASE_R) * pts[:, 2].min() / HEIGHT,
                                BASE_R + (TOP_R - BASE_R) * pts[:, 2].max() / HEIGHT,
                                BASE_R + (TOP_R - BASE_R) * pts[:, 2].max() / HEIGHT],
                               atol=1e-9)  # held at the wall's own ends beyond its heights


def test_a_flared_cups_wall_is_as_round_as_a_cylinders():
    # Its footprint is a ring 30-42 mm from the axis: about one circle it spreads beyond
    # the bound (the case the taper is for); about the fitted taper only by its noise.
    rng = np.random.default_rng(4)
    pts, normals = _frustum_wall(rng, (0.0, 0.0), (190.0, 350.0), (0.0, HEIGHT), 600,
                                 noise=0.0005)
    assert _circle_spread(pts[:, :2]) > ROUND_MAX_SPREAD
    wall = _round_footprint(pts[:, :2], normals[:, :2], pts[:, 2])
    assert wall is not None
    assert wall.taper == pytest.approx(0.126, abs=0.01)
    cylinder, c_normals = _frustum_wall(rng, (0.0, 0.0), (190.0, 350.0), (0.0, HEIGHT), 600,
                                        noise=0.0005, r0=0.036, r1=0.036)
    straight = _round_footprint(cylinder[:, :2], c_normals[:, :2], cylinder[:, 2])
    assert straight is not None and straight.taper == 0.0  # the circle holds: kept


def test_a_can_with_its_lids_edge_keeps_its_circle():
    # A can's side (radius 35 mm, 0-80 mm high) with the lid's rounded edge in its segment
    # (radius 28-33 mm at 76-84 mm): round as a circle, so no taper is fitted (a free one
    # would follow the edge's points off the straight side).
    rng = np.random.default_rng(12)
    side, side_n = _frustum_wall(rng, (0.0, 0.0), (190.0, 350.0), (0.0, 0.080), 600,
                                 noise=0.0005, r0=0.035, r1=0.035, height=0.080)
    edge, edge_n = _frustum_wall(rng, (0.0, 0.0), (190.0, 350.0), (0.076, 0.084), 150,
                                 noise=0.0005, r0=0.0805, r1=0.028, height=0.084)
    pts, normals = np.vstack([side, edge]), np.vstack([side_n, edge_n])
    wall = _round_footprint(pts[:, :2], normals[:, :2], pts[:, 2])
    assert wall is not None and wall.taper == 0.0
    assert wall.radius == pytest.approx(0.034, abs=0.002)


@pytest.mark.parametrize("thickness", [0.0, 0.003])
def test_a_flared_cups_inner_wall_joins_its_outer_wall(thickness):
    # Seen from above: the outer front wall (azimuths 190-350 deg, the whole height) and,
    # over the rim, the inner back wall (10-170 deg, 40-95 mm high; a zero-thickness wall
    # as the synthetic suite's cup, or 3 mm thick). The outer wall's footprint is a ring
    # no one circle holds within the bound; a zero-thickness inner wall lies 35-42 mm from
    # the axis, mostly beyond 1.05 times the radius of one circle through the outer wall
    # (about 36 mm), but inside the outer wall at its own heights.
    rng = np.random.default_rng(5)
    outer = _frustum_wall(rng, (0.0, 0.0), (190.0, 350.0), (0.0, HEIGHT), 700, noise=0.0005)
    inner = _frustum_wall(rng, (0.0, 0.0), (10.0, 170.0), (0.040, HEIGHT), 300, noise=0.0005,
                          inward=True, thickness=thickness)
    assert _circle_spread(outer[0][:, :2]) > ROUND_MAX_SPREAD
    if thickness == 0.0:
        one_circle = np.median(np.linalg.norm(outer[0][:, :2], axis=1))
        assert np.mean(np.linalg.norm(inner[0][:, :2], axis=1)
                       <= CONTAINED_RADIUS_MARGIN * one_circle) < 0.5
    labels = _join([outer, inner])
    assert labels[0] == labels[1] == {2}


def test_an_object_under_a_flared_rim_stays_apart():
    # A flared bowl (40 mm at the desk to 90 mm at its rim 60 mm up) and a small box
    # standing against its foot, under the overhanging rim: inside the rim's circle but
    # outside the wall at the box's own heights (it cannot be inside a solid wall).
    rng = np.random.default_rng(6)
    bowl = _frustum_wall(rng, (0.0, 0.0), (190.0, 350.0), (0.0, 0.060), 700, noise=0.0005,
                         r0=0.040, r1=0.090, height=0.060)
    box = rng.uniform([-0.015, -0.072, 0.0], [0.015, -0.045, 0.025], (300, 3))
    box_normals = np.tile([0.0, -1.0, 0.0], (300, 1))
    assert np.mean(np.linalg.norm(box[:, :2], axis=1) <= 0.090) > 0.5
    assert _round_footprint(bowl[0][:, :2], bowl[1][:, :2], bowl[0][:, 2]) is not None
    labels = _join([bowl, (box, box_normals)])
    assert labels == [{2}, {5}]


def test_two_flared_cups_side_by_side_stay_apart():
    # Two cups with bare desk between them (axes 100 mm apart: a gap of 16 mm at their
    # rims, 40 mm at their feet), each seen as its outer wall and its inner wall: each
    # cup's walls join, the cups do not.
    rng = np.random.default_rng(7)
    parts = []
    for center in [(0.0, 0.0), (0.100, 0.0)]:
        parts.append(_frustum_wall(rng, center, (190.0, 350.0), (0.0, HEIGHT), 700,
                                   noise=0.0005))
        parts.append(_frustum_wall(rng, center, (10.0, 170.0), (0.040, HEIGHT), 300,
                                   noise=0.0005, inward=True, thickness=0.002))
    labels = _join(parts)
    assert labels[0] == labels[1] and labels[2] == labels[3]
    assert labels[0] != labels[2]


def test_a_box_beside_a_flared_cup_stays_apart():
    # A box touching the cup's wall, as tall as the cup: a sliver of it within the margin.
    rng = np.random.default_rng(8)
    cup = _frustum_wall(rng, (0.0, 0.0), (190.0, 350.0), (0.0, HEIGHT), 700, noise=0.0005)
    box = rng.uniform([0.036, -0.03, 0.0], [0.096, 0.03, 0.09], (600, 3))
    labels = _join([cup, (box, np.tile([0.0, -1.0, 0.0], (600, 1)))])
    assert labels == [{2}, {5}]


def test_a_tilted_flat_face_is_no_tapered_wall():
    # A flat strip 21 cm long and 12 cm high, tilted 9 degrees from the desk's normal, its
    # points 2.6 mm (median) off its plane, as a background strip of the PCL mug scene at 2
    # m: the tapered wall fitted to it (its tilt taken for a taper) lies farther from its
    # points than their plane does, so it is no wall; a flared cup's wall seen over 120
    # degrees lies closer to its points than any plane.
    from geomodel_ros.core.joins import _closer_than_plane

    rng = np.random.default_rng(5)
    n = 3000
    x, h = rng.uniform(-0.105, 0.105, n), rng.uniform(0.0, 0.12, n)
    y = 0.3 + h * np.tan(np.radians(9.0)) + rng.normal(0.0, 0.0026 / 0.6745, n)
    strip = _fit_wall(np.column_stack([x, y]), h, tapered=True)
    assert strip is not None  # a wall is fitted, so the guard decides
    assert not _closer_than_plane(strip, np.column_stack([x, y]), h)
    cup, _ = _frustum_wall(rng, (0.0, 0.0), (-60.0, 60.0), (0.0, HEIGHT), n, noise=0.001)
    wall = _fit_wall(cup[:, :2], cup[:, 2], tapered=True)
    assert wall is not None and _closer_than_plane(wall, cup[:, :2], cup[:, 2])
