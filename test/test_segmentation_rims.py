"""A container's inside touching another object at its rim stays apart from it.

Seen from above, a flared bowl shows only its inside (its outer wall faces down), a
surface seen concave from the sensor. Where its rim touches another object's face, the
inside bends away from that face like the far side of a ridge, so the links across their
border vote convex; a surface seen from inside is no face of a convex solid, so that
border must not join them (clutter seed 46: a bowl of top radius 101 mm against a box
84 mm tall, joined before). The geometry is hand-built from the shapes' definitions; the
negative cases (a cup's walls, a box's faces, a can's side and top) are in test_clutter.
"""

from __future__ import annotations

import numpy as np
import pytest

from geomodel_ros.core.params import ModelingParams
from geomodel_ros.core.faces import estimate_normals
from geomodel_ros.core.segmentation import BORDER_CREASE_SIGMAS, _concave_patches, segment_scene
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


def _patch(depth_of, noise: float, seed: int = 0):
    # A 12 x 12 cm patch about 0.8 m in front of the sensor on a 4 mm grid, depths from
    # ``depth_of`` (x, y), normals towards the sensor.
    rng = np.random.default_rng(seed)
    x, y = np.meshgrid(np.arange(-0.06, 0.06, 0.004), np.arange(-0.06, 0.06, 0.004))
    pts = np.column_stack([x.ravel(), y.ravel(), depth_of(x.ravel(), y.ravel())])
    pts[:, 2] += rng.normal(0.0, noise, len(pts))
    normals, _, nbrs, sqdist = estimate_normals(pts, 16, return_sqdist=True)
    return pts, normals, nbrs, sqdist


def _seen_inside(pts, normals, nbrs, sqdist):
    return _concave_patches(pts, normals, nbrs, sqdist, np.zeros(len(pts), dtype=np.int64), 1,
                            0.01, floor=np.finfo(np.float32).eps, sigmas=BORDER_CREASE_SIGMAS)[0]


@pytest.mark.parametrize("noise", [0.0, 0.001, 0.003])
def test_a_plane_is_not_seen_from_inside_and_a_bowl_is(noise):
    # A bowl of radius 0.1 m seen from above: its surface curves towards the sensor
    # (depth r - sqrt(r^2 - x^2 - y^2) nearer at the rim); a plane has no curvature, its
    # median fold is 0 within its error whatever the noise.
    plane = _patch(lambda x, y: 0.8 + 0.3 * x - 0.2 * y, noise)  # tilted
    bowl = _patch(lambda x, y: 0.8 + np.sqrt(0.1 ** 2 - x ** 2 - y ** 2) - 0.1, noise)
    assert not _seen_inside(*plane)
    if noise <= 0.001:  # 3 mm on 4 mm links hides a 0.1 m curvature in one patch this small
        assert _seen_inside(*bowl)
