"""The container join judges a concave patch on its own, built by hand and rendered.

A cup's inner back wall ends at its back rim; an object standing against the cup's back is
seen just beyond that rim, a wall's thickness behind it and with about the same normal, so
the border votes may join the inner wall to that object before the container join. Then
the segment holding the inner wall lies mostly outside the cup and the join refuses it.
:func:`geomodel_ros.core.joins.join_contained_parts` with ``patches`` (the smooth patch of
every point and a test that tells which patches are seen concave) moves a concave patch
that lies inside a round wall, within its heights, to the wall's segment; the rest of its
segment stays. The desk
is z = 0, heights are z, the sensor looks from -y.
"""

from __future__ import annotations

import numpy as np
import pytest

from geomodel_ros.core.joins import CONTAINED_MIN_POINTS, join_contained_parts
from geomodel_ros.core.ransac import PlaneModel

from container_helpers import concave_oracle, labels_of_parts, stacked_parts

DESK = PlaneModel(np.array([0.0, 0.0, 1.0]), 0.0)
#: A straight cup: radius 40 mm, rim 90 mm above the desk, walls 3 mm thick.
CUP_R, CUP_H, WALL = 0.040, 0.090, 0.003
#: A can of radius 33 mm and 120 mm standing against the cup's back.
CAN_R, CAN_H = 0.033, 0.120
OUTER, INNER, CAN, OTHER = 2, 5, 5, 8  # segment ids (the inner wall joined the can: 5)


def _wall(rng, center, radius, deg, h, n, inward=False):
    """Return points on a vertical cylinder's wall (azimuths ``deg``, heights ``h``), normals."""
    ang = np.radians(rng.uniform(*deg, n))
    radial = np.column_stack([np.cos(ang), np.sin(ang), np.zeros(n)])
    pts = np.r_[center, 0.0] + radius * radial
    pts[:, 2] = rng.uniform(*h, n)
    return pts, (-radial if inward else radial)


def _cup_and_can(rng, can_points=600):
    """Return the cup's outer front wall, its inner back wall and a can touching its back."""
    outer = _wall(rng, (0.0, 0.0), CUP_R, (200.0, 340.0), (0.0, CUP_H), 500)
    inner = _wall(rng, (0.0, 0.0), CUP_R - WALL, (20.0, 160.0), (0.02, CUP_H), 300,
                  inward=True)
    can = _wall(rng, (0.0, CUP_R + CAN_R), CAN_R, (200.0, 340.0), (0.0, CAN_H), can_points)
    return outer, inner, can


def _run(parts, segs, concave_flags, asked=None):
    """Join with each part a patch of its own, ``concave_flags`` telling which are concave.

    Return the labels of each part's points with and without the patches; the patch ids
    the concavity test was asked about go to ``asked``.
    """
    points, normals, comp, labels, bounds = stacked_parts(parts, segs)
    valid = np.ones(len(comp), dtype=bool)
    out = join_contained_parts(points, normals, comp, valid, DESK, None,
                               (labels, concave_oracle(concave_flags, asked)))
    bare = join_contained_parts(points, normals, comp, valid, DESK)
    return labels_of_parts(out, bounds), labels_of_parts(bare, bounds)


def test_an_inner_wall_joined_to_a_can_behind_goes_to_its_cup():
    outer, inner, can = _cup_and_can(np.random.default_rng(1))
    asked = []
    got, bare = _run([outer, inner, can], [OUTER, INNER, CAN], [False, True, False], asked)
    # Only the patch inside the wall and in another segment is tested for concavity.
    assert asked == [1]
    # As a segment the inner wall and the can lie 1/3 inside the cup: refused.
    assert bare == [{OUTER}, {INNER}, {CAN}]
    # Its concave patch lies inside: it joins the cup, the can stays apart.
    assert got[0] == got[1] == {OUTER}
    assert got[2] == {CAN}


@pytest.mark.parametrize("seed", [2, 3, 4])
def test_the_join_holds_for_other_samples(seed):
    outer, inner, can = _cup_and_can(np.random.default_rng(seed))
    got, _ = _run([outer, inner, can], [OUTER, INNER, CAN], [False, True, False])
    assert got == [{OUTER}, {OUTER}, {CAN}]


def test_the_inner_wall_of_a_cup_beside_it_is_not_taken():
    # A second cup 100 mm to the right: its inner wall, joined to a can behind it, is
    # concave too but lies outside the first cup's wall (solids do not interpenetrate).
    rng = np.random.default_rng(5)
    outer, _, _ = _cup_and_can(rng)
    far_inner = _wall(rng, (0.10, 0.0), CUP_R - WALL, (20.0, 160.0), (0.02, CUP_H), 300,
                      inward=True)
    far_can = _wall(rng, (0.10, CUP_R + CAN_R), CAN_R, (200.0, 340.0), (0.0, CAN_H), 600)
    got, _ = _run([outer, far_inner, far_can], [OUTER, OTHER, OTHER], [False, True, False])
    assert got == [{OUTER}, {OTHER}, {OTHER}]


def test_convex_content_is_judged_as_its_segment_only():
    # The same geometry with the inner piece not concave: a fruit in the cup that
    # joined the can is no inner wall; its segment stays as the segment test decides.
    outer, inner, can = _cup_and_can(np.random.default_rng(6))
    got, bare = _run([outer, inner, can], [OUTER, INNER, CAN], [False, False, False])
    assert got == bare == [{OUTER}, {INNER}, {CAN}]


def test_a_concave_patch_above_the_rim_is_not_taken():
    # A concave surface inside the cup's circle but above its rim (a bowl's inside on a
    # lid over the cup) is no inside of the cup.
    rng = np.random.default_rng(7)
    outer, _, can = _cup_and_can(rng)
    above = _wall(rng, (0.0, 0.0), CUP_R - WALL, (20.0, 160.0), (CUP_H + 0.01, CUP_H + 0.06),
                  300, inward=True)
    got, _ = _run([outer, above, can], [OUTER, INNER, CAN], [False, True, False])
    assert got == [{OUTER}, {INNER}, {CAN}]


def test_a_concave_patch_of_too_few_points_is_not_judged():
    rng = np.random.default_rng(8)
    outer, _, can = _cup_and_can(rng)
    small = _wall(rng, (0.0, 0.0), CUP_R - WALL, (20.0, 160.0), (0.02, CUP_H),
                  CONTAINED_MIN_POINTS - 1, inward=True)
    got, _ = _run([outer, small, can], [OUTER, INNER, CAN], [False, True, False])
    assert got == [{OUTER}, {INNER}, {CAN}]


def test_rendered_cup_against_a_can_is_one_object_under_kinect_real_noise():
    # Clutter scene 4 under KINECT_REAL_NOISE: cup 4's inner wall meets can 13 behind it
    # at the cup's back rim with no depth jump (1.7 mm median seam gap) and joined it.
    from geomodel_ros.core.params import ModelingParams
    from geomodel_ros.core.segmentation import segment_scene
    from geomodel_ros.tools.synth.clutter import render_clutter
    from geomodel_ros.tools.synth.scenes import KINECT_REAL_NOISE

    scene = render_clutter(4, KINECT_REAL_NOISE)
    labels = segment_scene(scene.organized, ModelingParams()).labels.ravel()
    gt = scene.label_image.ravel()
    assert scene.kinds[4] == "cup" and scene.kinds[13] == "can"
    cup = np.bincount(labels[(gt == 4) & (labels >= 0)])
    main = int(np.argmax(cup))
    assert cup[main] >= 0.9 * (gt == 4).sum()
    can = labels[gt == 13]
    assert (can == main).mean() < 0.1  # the can is not taken with it


def test_a_concave_patch_below_the_round_walls_lowest_point_is_not_taken():
    # A round segment seen only from 50 mm up (a sphere resting on a box) and a patch of
    # the box under it, flagged concave, its footprint inside the sphere's circle: a
    # container's inside lies within its wall's heights (the two overlap by 2 mm here).
    rng = np.random.default_rng(9)
    upper = _wall(rng, (0.0, 0.0), CUP_R, (200.0, 340.0), (0.05, 0.09), 500)
    under = _wall(rng, (0.0, 0.0), CUP_R - WALL, (20.0, 160.0), (0.0, 0.052), 300,
                  inward=True)
    _, _, can = _cup_and_can(rng)
    got, _ = _run([upper, under, can], [OUTER, INNER, CAN], [False, True, False])
    assert got == [{OUTER}, {INNER}, {CAN}]
