"""Joins of patch groups decided on every border between the two groups.

:func:`geomodel_ros.core.joins.merge_patches` joins two patches across a border with a
convex majority; between patches whose link tests are exact (``exact``: noise below the
fixed step floor) the votes of *all* borders between the two groups must hold more than
that share too (a tie is no evidence for the join). Hand-made votes with the sums worked
out in the comments, then the clutter scene where it matters (a flared cup whose rim
touches a box).
"""

from __future__ import annotations

import numpy as np
import pytest

from geomodel_ros.core.joins import _GroupContacts, merge_patches
from geomodel_ros.core.params import ModelingParams
from geomodel_ros.core.segmentation import segment_scene
from geomodel_ros.tools.evaluation import segmentation_scores
from geomodel_ros.tools.synth.clutter import clutter_layout, render_layout

#: Object A is patches 0 and 1 (two faces, 100 convex votes of 100 along their edge),
#: object B is patch 2. Every patch has 400 points, so a border needs sqrt(400) = 20 votes
#: to join. Borders (a, b) in increasing order.
A = np.array([0, 0, 1])
B = np.array([1, 2, 2])
SIZES = np.array([400, 400, 400])


def _votes(rim_yes: float, crease_yes: float) -> tuple[np.ndarray, np.ndarray]:
    # 0-1: 100 / 100 (one object's edge); 0-2: 20 votes, the rim's contact; 1-2: 16 votes
    # (fewer than the 20 of a clear crease on its own).
    return np.array([100, 20, 16]), np.array([100.0, rim_yes, crease_yes])


def test_a_narrow_convex_border_does_not_join_groups_that_meet_at_a_crease_elsewhere():
    # 0-2 alone: 11 of 20 convex (55 %, a majority, and 20 votes: long enough). After 0
    # and 1 join (100 yes, first), A and B border along 0-2 and 1-2: 11 + 2 = 13 convex of
    # 20 + 16 = 36 votes, 36 %: no majority, they stay apart.
    votes, yes = _votes(11.0, 2.0)
    out = merge_patches(3, A, B, votes, yes, sizes=SIZES, exact=np.ones(3, dtype=bool))
    assert out.tolist() == [0, 0, 1]


def test_without_exact_patches_the_strongest_border_alone_decides():
    # The same votes where noise set the steps (or no exact flags): 0-2 joins on its own
    # 55 %, as before the summed test; 1-2 (16 votes) is no clear crease.
    votes, yes = _votes(11.0, 2.0)
    assert merge_patches(3, A, B, votes, yes, sizes=SIZES).tolist() == [0, 0, 0]
    noisy_b = np.array([True, True, False])
    assert merge_patches(3, A, B, votes, yes, sizes=SIZES, exact=noisy_b).tolist() == [0, 0, 0]


@pytest.mark.parametrize("crease_yes, joined", [(8.0, True), (7.0, False), (6.0, False)])
def test_the_groups_join_when_all_their_borders_together_hold_the_majority(crease_yes, joined):
    # One object whose second border is noisier: 11 + 8 = 19 of 36 is a majority (joins);
    # 11 + 7 = 18 of 36 is a tie, no evidence either way (apart); 17 of 36 is less.
    votes, yes = _votes(11.0, crease_yes)
    out = merge_patches(3, A, B, votes, yes, sizes=SIZES, exact=np.ones(3, dtype=bool))
    assert (out[0] == out[2]) == joined
    assert out[0] == out[1]  # the clear edge of object A always joins


def test_a_border_to_a_third_group_does_not_count_between_two_others():
    # Patch 3 borders patch 2 with 40 concave votes (0 convex); it stays its own group and
    # its border is not between A = {0, 1} and B = {2}: A and B join on 0-2 and 1-2, 11 +
    # 10 = 21 of 36 (58 %). 2-3: 40 votes, share 0 is a clear crease between B and 3.
    a, b = np.array([0, 0, 1, 2]), np.array([1, 2, 2, 3])
    votes, yes = np.array([100, 20, 16, 40]), np.array([100.0, 11.0, 10.0, 0.0])
    out = merge_patches(4, a, b, votes, yes, sizes=np.full(4, 400),
                        exact=np.ones(4, dtype=bool))
    assert out.tolist() == [0, 0, 0, 1]


def test_group_contacts_sum_the_borders_of_joined_groups():
    contact = _GroupContacts(np.array([0, 0, 1, 1]), np.array([1, 2, 2, 3]),
                             np.array([10, 20, 16, 5]), np.array([10.0, 11.0, 2.0, 5.0]))
    assert contact.share(0, 2) == pytest.approx(11 / 20)
    assert contact.share(2, 3) == 1.0  # no border: no evidence against
    contact.union(0, 1)
    # Group {0, 1} (root 0) now borders 2 along 0-2 and 1-2, and 3 along 1-3.
    assert contact.share(0, 2) == pytest.approx(13 / 36)
    assert contact.share(2, 0) == pytest.approx(13 / 36)
    assert contact.share(0, 3) == 1.0
    assert 1 not in contact.tally and 1 not in contact.tally[2]


# ------------------------------------------------------------------------ clutter scene 5
def _cup_and_box(items: list[int]):
    # Clutter scene 5 (noise-free): a flared cup (radius 39 mm at the bottom, 47 mm at the
    # rim, 73 mm high) standing in front of a box (87 x 104 x 76 mm) turned 128 degrees,
    # the cup's rim touching the box's side; the camera looks at the cup's side, the box
    # behind it. Rendered alone, exact labels.
    layout, _, pose = clutter_layout(5)
    chosen = [layout[i - 1] for i in items]
    scene = render_layout(chosen, [0] * len(chosen), pose)
    seg = segment_scene(scene.organized, ModelingParams())
    ids = list(range(1, len(chosen) + 1))
    return {s.gt_id: s for s in segmentation_scores(seg.labels, scene.label_image.ravel(), ids)}


def test_a_flared_cup_whose_rim_touches_a_box_stays_apart_from_it():
    layout, _, _ = clutter_layout(5)
    assert [layout[9].kind, layout[10].kind] == ["cup", "box"]
    scores = _cup_and_box([10, 11])
    for s in scores.values():
        assert s.iou >= 0.8 and not s.under, scores


def test_the_same_cup_alone_is_one_segment():
    # Inner and outer wall and rim of the cup stay one object (nothing to part them).
    (s,) = _cup_and_box([10]).values()
    assert s.iou >= 0.8 and not s.over
