"""A box whose smaller faces the noise turned beyond the angle tolerance (FacesInBoxFrame).

The model graph takes planar faces for a box only when each lies within
``angle_tolerance`` of its corner's axes; the strategy asks instead whether the box frame
of all the faces holds each face's points within the RANSAC threshold. Expectations come
from the geometry of the patches (a patch of half-width w turned by a from the frame's
plane strays w sin(a) from it), not from the code.
"""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np

from data_helpers import DATA, require
from geomodel_ros.core.fitting.strategies import (LAST_STRATEGIES, STRATEGIES,
                                                   FacesInBoxFrame, NormalsBoxAfterAll,
                                                   Situation, faces_in_box_frame)
from geomodel_ros.core.model_graph import NOT_ALIGNED, FaceInfo, GraphDecision
from geomodel_ros.core.modeling import model_objects
from geomodel_ros.core.params import ModelingParams
from geomodel_ros.core.primitives import PrimitiveType
from geomodel_ros.core.segmentation import segment_scene
from geomodel_ros.tools.io import load_osd

MM = 1e-3
THRESHOLD = 5 * MM
TOLERANCE = math.radians(8.0)
DEPTH = 0.8


def _rotation(axis, angle):
    """Rotation matrix (3, 3) by ``angle`` [rad] about the unit ``axis``."""
    k = np.array([[0.0, -axis[2], axis[1]], [axis[2], 0.0, -axis[0]], [-axis[1], axis[0], 0.0]])
    return np.eye(3) + math.sin(angle) * k + (1.0 - math.cos(angle)) * k @ k


def _patch(centre, u, v, half_u, half_v, n=21):
    """Grid of n x n points spanning +-half_u along ``u`` and +-half_v along ``v``."""
    a, b = np.meshgrid(np.linspace(-half_u, half_u, n), np.linspace(-half_v, half_v, n))
    return centre + np.outer(a.ravel(), u) + np.outer(b.ravel(), v)


def _box_faces(turn, half, size=0.03, side_n=21):
    """Three faces of a box at DEPTH, the third (half-width ``half`` [m]) turned by ``turn``.

    Faces: front (normal -z, 60 x 60 mm), top (normal -y, 60 x 60 mm), and a side (normal
    -x) of half-width ``half`` along z, turned about the box's y axis by ``turn`` [rad]
    (its normal then leaves the x axis by ``turn``); front and top are 2 ``size`` [m]
    square. Front and top hold 61 x 61 points, the side ``side_n`` squared. The frame is
    that of the faces within the tolerance (front and top, exactly perpendicular): the
    side lies ``turn`` off its plane.
    """
    x, y, z = np.eye(3)
    front = _patch(np.array([0.0, 0.0, DEPTH]), x, y, size, size, n=61)
    top = _patch(np.array([0.0, -size, DEPTH + size]), x, z, size, size, n=61)
    rot = _rotation(y, turn)
    side_normal, side_u = rot @ -x, rot @ z
    side = _patch(np.array([-size, 0.0, DEPTH + half]), side_u, y, half, size, n=side_n)
    return [(front, -z), (top, -y), (side, side_normal)]


def _cloud(parts, noise_model="auto"):
    """Return the parts of an ObjectCloud the strategy reads: faces, adjacency, points."""
    pts = np.vstack([p for p, _ in parts])
    infos, faces, start = [], [], 0
    for p, normal in parts:
        rows = np.arange(start, start + len(p))
        c = p.mean(axis=0)
        info = FaceInfo(True, normal, -float(normal @ c), len(p), np.tile(normal, (len(p), 1)),
                        c)
        infos.append(info)
        faces.append(SimpleNamespace(info=info, working=rows))
        start += len(p)
    adjacency = ~np.eye(len(parts), dtype=bool)
    params = ModelingParams(noise_model=noise_model, ransac_threshold=THRESHOLD,
                            angle_tolerance=TOLERANCE)
    return SimpleNamespace(wc=SimpleNamespace(points=pts), faces=faces, adjacency=adjacency,
                           params=params)


def _held(cloud):
    """Return which faces (F,) the box frame holds (:func:`faces_in_box_frame`)."""
    return faces_in_box_frame(cloud)[1]


def test_a_small_face_turned_within_the_noise_is_held_and_a_large_one_is_not():
    # Turned 12 deg (beyond the 8 deg tolerance): a side of half-width 15 mm strays at
    # most 15 sin(12 deg) = 3.1 mm from its frame plane, within the 5 mm threshold; one of
    # half-width 60 mm strays up to 12.5 mm, and only the 2 x 24 mm of it within
    # 5 / sin(12 deg) = 24 mm of its middle, about 40 %, lies within the threshold (below
    # the 80 % bar).
    assert _held(_cloud(_box_faces(math.radians(12.0), 0.015))).tolist() == \
        [True, True, True]
    assert _held(_cloud(_box_faces(math.radians(12.0), 0.060))).tolist() == \
        [True, True, False]
    # A chamfer at 45 deg is no side, small as it is (15 sin 45 = 10.6 mm).
    assert not _held(_cloud(_box_faces(math.radians(45.0), 0.015)))[2]


def test_a_turned_face_does_not_turn_the_frame_however_many_points_it_has():
    # A side turned 15 deg, 15 mm half-width (3.9 mm off its frame plane at most), with
    # nearly the points of the 140 mm front and top (59^2 against 61^2). Had its weight
    # turned the frame by a few degrees, the front would stray beyond the 5 mm threshold
    # over much of its 70 mm half-width (5 deg: 6.1 mm at the edges, 8 deg: 9.7 mm;
    # the frame of all three faces leaves 54 % of it within the threshold).
    faces = _box_faces(math.radians(15.0), 0.015, size=0.07, side_n=59)
    assert _held(_cloud(faces)).tolist() == [True, True, True]


def test_the_attempt_is_a_cuboid_on_the_corners_axes_only_when_every_face_is_held():
    strategy = FacesInBoxFrame()
    turned = _cloud(_box_faces(math.radians(12.0), 0.015))
    situation = Situation(turned, GraphDecision("planar", (), 0, (), NOT_ALIGNED))
    assert strategy.applies(situation)
    attempt = strategy.attempt(situation)
    assert attempt.decision.candidates == ("cuboid",)
    # Front on the first axis (the largest face), top on the second; the side, beyond the
    # tolerance, turns no axis of the box (its points still size it along the third).
    assert attempt.decision.axis_of_face == (0, 1, -1)
    wide = _cloud(_box_faces(math.radians(12.0), 0.060))
    assert strategy.attempt(Situation(wide, GraphDecision("planar", (), 0, (), NOT_ALIGNED))) \
        is None


def test_the_strategy_applies_only_to_faces_not_aligned_and_with_the_measured_noise():
    strategy = FacesInBoxFrame()
    turned = _box_faces(math.radians(12.0), 0.015)
    other = GraphDecision("planar", (), 0, (), "parallel planar faces at different offsets")
    assert not strategy.applies(Situation(_cloud(turned), other))
    fixed = Situation(_cloud(turned, noise_model="fixed"),
                      GraphDecision("planar", (), 0, (), NOT_ALIGNED))
    assert not strategy.applies(fixed)


def test_it_is_tried_last_after_the_box_of_the_point_normals():
    # Last: a can whose lid and side facets pass as such faces gets the cylinder below its
    # lid first (run_strategies tries it between STRATEGIES and LAST_STRATEGIES).
    assert FacesInBoxFrame.name not in [s.name for s in STRATEGIES]
    names = [s.name for s in LAST_STRATEGIES]
    assert names.index(FacesInBoxFrame.name) == names.index(NormalsBoxAfterAll.name) + 1


def _modeled(frame, gt_id):
    """Return the object modeled from the segment overlapping label ``gt_id`` most."""
    points, gt = load_osd(require(DATA / "osd_learn" / f"learn{frame}.pcd"))
    params = ModelingParams()
    seg = segment_scene(points.reshape(480, 640, 3), params)
    result = model_objects(points, seg.labels, params, supports=seg.support_planes,
                           noise=seg.noise)
    hit = seg.labels[(gt == gt_id) & (seg.labels >= 0)]
    oid = int(np.bincount(hit).argmax())
    return next(o for o in result.objects if o.id == oid)


def test_a_real_box_under_another_seen_in_pieces_is_one_box_in_two_frames():
    # osd_learn learn17 (label 2) and learn18 (label 3): one box under another, seen in
    # pieces round it; a small face of it 10 and 14 deg off its axis left it `unknown`.
    # Both frames must now give a cuboid, and the same box: sorted sides within 15 mm of
    # each other (the frames' noise band at 0.8 m is 7-7.5 mm on each side's two ends).
    boxes = [_modeled(17, 2), _modeled(18, 3)]
    assert all(b.type == PrimitiveType.CUBOID for b in boxes)
    assert all("box frame holds" in b.reason for b in boxes)
    sides = [np.sort(list(b.dimensions.values())) for b in boxes]
    assert np.all(np.abs(sides[0] - sides[1]) <= 15 * MM)
