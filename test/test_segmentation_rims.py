"""A container's inside touching another object at its rim stays apart from it.

Seen from above, a flared bowl shows only its inside (its outer wall faces down), a
surface seen concave from the sensor. Where its rim touches another object's face, the
inside bends away from that face like the far side of a ridge, so the links across their
border vote convex and the border votes join them (clutter seed 46: a bowl of top radius
101 mm against a box 84 mm tall). Two solids do not interpenetrate: the container join
parts from the inside what lies outside its wall and touches it over its rim
(:func:`geomodel_ros.core.joins._part_at_rims`). Rendered geometry, ground truth from the
generator; the negative cases (a cup's walls, a box's faces, a can's side and top) are in
test_clutter and test_container_rims.
"""

from __future__ import annotations

import numpy as np
import pytest

from geomodel_ros.core.params import ModelingParams
from geomodel_ros.core.segmentation import segment_scene
from geomodel_ros.tools.evaluation import segmentation_scores
from geomodel_ros.tools.synth.clutter import (KINECT_NOISE, camera_pose, clutter_layout,
                                              make_box, make_can, make_container,
                                              render_layout)
from geomodel_ros.tools.synth.scenes import KINECT_REAL_NOISE

TOP, BOTTOM, DEPTH = 0.101, 0.053, 0.055
#: Cameras of seed 46's kind: about 1 m away, 50-60 degrees above the desk.
CAMERAS = [camera_pose(0.9, np.radians(55.0), az) for az in (-np.pi / 2, -np.pi / 3, -2.0)]


def _scores(items, camera, noisy):
    noise = KINECT_REAL_NOISE if noisy == "real" else KINECT_NOISE if noisy else None
    scene = render_layout(items, [0] * len(items), camera, noise=noise, rng=3)
    seg = segment_scene(scene.organized, ModelingParams())
    ids = list(range(1, len(items) + 1))
    return {s.gt_id: (round(s.iou, 3), s.under)
            for s in segmentation_scores(seg.labels, scene.label_image.ravel(), ids)}


@pytest.mark.parametrize("camera", range(len(CAMERAS)))
@pytest.mark.parametrize("shift", [0.0, 0.02])
def test_a_bowl_whose_rim_touches_a_taller_box_face_stays_apart(camera, shift):
    bowl = make_container(BOTTOM, TOP, DEPTH, kind="bowl")
    # The box's +x face on the bowl's rim (touching), the box taller than the bowl.
    box = make_box(0.096, 0.05, 0.084).at(np.array([-(TOP + 0.048 + 1e-4), shift]))
    scores = _scores([bowl, box], CAMERAS[camera], False)
    assert all(iou >= 0.8 and not under for iou, under in scores.values()), scores


@pytest.mark.parametrize("camera", range(len(CAMERAS)))
def test_a_bowl_beside_a_can_at_its_rim_stays_apart(camera):
    bowl = make_container(BOTTOM, TOP, DEPTH, kind="bowl")
    can = make_can(0.035, 0.07).at(np.array([0.0, -(TOP + 0.035 + 1e-4)]))
    scores = _scores([bowl, can], CAMERAS[camera], False)
    assert all(iou >= 0.8 and not under for iou, under in scores.values()), scores


@pytest.mark.parametrize("camera", range(len(CAMERAS)))
def test_a_lone_bowl_and_a_lone_box_stay_whole(camera):
    # The bowl's inside stays one object with its rim; the box's faces join.
    bowl = make_container(BOTTOM, TOP, DEPTH, kind="bowl")
    box = make_box(0.096, 0.05, 0.084).at(np.array([-0.3, 0.0]))
    scores = _scores([bowl, box], CAMERAS[camera], False)
    assert all(iou >= 0.8 for iou, _ in scores.values()), scores


@pytest.mark.parametrize("noisy, seed, first, second", [
    (False, 46, 2, 6),  # a bowl's rim on a box's side face, the box taller
    (False, 25, 9, 2),  # a bowl's rim 3 mm below a box's top edge
    (False, 48, 2, 1),  # a lying can against a bowl's near rim
    ("real", 46, 2, 6),
    ("real", 57, 2, 5),  # a bowl and a box
])
def test_bowls_of_the_clutter_generator_stay_apart_from_what_touches_their_rim(
        noisy, seed, first, second):
    # The two objects alone, as the generator placed them and its camera saw them (the
    # pairs the border votes joined in those scenes).
    items, _, pose = clutter_layout(seed)
    scores = _scores([items[first - 1], items[second - 1]], pose, noisy)
    assert all(iou >= 0.8 and not under for iou, under in scores.values()), scores

