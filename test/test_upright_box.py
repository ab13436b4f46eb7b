"""A box standing on a support whose faces the noise turned beyond every rule.

:class:`UprightBoxOnSupport` takes the support's normal as the box's axis 2 and the side
faces' directions about it as axes 0 and 1 (:func:`obb.upright_axes`), and asks that frame
to hold every face within the RANSAC threshold. Expectations come from the geometry of the
patches (a patch of half-width w turned by a from its frame plane strays w sin(a) from
it) and from the rendered scenes' ground truth, not from the code.
"""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest

from geomodel_ros.core import obb
from geomodel_ros.core.fitting import strategies
from geomodel_ros.core.fitting.strategies import (LAST_STRATEGIES, STRATEGIES, OuterWallAfterAll,
                                                   Situation, UprightBoxOnSupport)
from geomodel_ros.core.model_graph import FaceInfo, GraphDecision
from geomodel_ros.core.modeling import model_scene
from geomodel_ros.core.params import ModelingParams
from geomodel_ros.tools.bench_clutter import OPTIONAL_NOISE
from geomodel_ros.tools.synth.clutter import render_clutter
from suite_helpers import best_object_and_labels, scene_iou

MM = 1e-3
THRESHOLD = 5 * MM
TOLERANCE = math.radians(10.0)
DEPTH = 0.7
NEITHER = "planar faces neither perpendicular nor parallel to the main face"


def _rotation(axis, angle):
    """Rotation matrix (3, 3) by ``angle`` [rad] about the unit ``axis``."""
    axis = np.asarray(axis, dtype=float) / np.linalg.norm(axis)
    k = np.array([[0.0, -axis[2], axis[1]], [axis[2], 0.0, -axis[0]], [-axis[1], axis[0], 0.0]])
    return np.eye(3) + math.sin(angle) * k + (1.0 - math.cos(angle)) * k @ k


#: A desk seen from 40 deg above: its normal (towards the sensor) and a box frame on it,
#: turned 25 deg about that normal.
UP = _rotation([1.0, 0.0, 0.0], math.radians(-40.0)) @ np.array([0.0, 0.0, -1.0])
FRAME = _rotation(UP, math.radians(25.0)) @ _rotation([1.0, 0.0, 0.0], math.radians(-40.0)) \
    @ np.diag([1.0, -1.0, -1.0])


def _angle(a, b):
    """Return the angle [rad] between the lines of ``a`` and ``b`` (sign free)."""
    return math.atan2(float(np.linalg.norm(np.cross(a, b))), abs(float(a @ b)))


def test_the_frame_is_upright_and_follows_the_sides_about_the_normal():
    assert _angle(FRAME[:, 2], UP) < 1e-12
    x, y = FRAME[:, 0], FRAME[:, 1]
    # Two sides, one per axis across the normal, with signs either way.
    rot = obb.upright_axes(UP, np.array([-x, y]), np.array([1.0, 3.0]), np.array([0, 1]))
    assert np.allclose(rot.T @ rot, np.eye(3), atol=1e-12)
    assert np.linalg.det(rot) == pytest.approx(1.0, abs=1e-12)
    assert _angle(rot[:, 2], UP) < 1e-12 and rot[:, 2] @ UP > 0
    assert _angle(rot[:, 0], x) < 1e-9 and _angle(rot[:, 1], y) < 1e-9


def test_a_side_tilted_towards_the_normal_turns_no_axis():
    # A strip whose fitted normal leans 48 deg towards the top still points across the
    # box along x: only its component across the normal counts.
    x = FRAME[:, 0]
    leaning = math.cos(math.radians(48.0)) * UP + math.sin(math.radians(48.0)) * x
    rot = obb.upright_axes(UP, np.array([leaning]), np.array([1.0]), np.array([0]))
    assert _angle(rot[:, 0], x) < 1e-9


def test_tops_and_faces_of_no_axis_turn_nothing_and_sides_average_modulo_a_right_angle():
    x = FRAME[:, 0]
    odd = np.array([0.3, -0.5, 0.81])
    rot = obb.upright_axes(UP, np.array([x, UP, odd / np.linalg.norm(odd)]),
                           np.array([1.0, 50.0, 50.0]), np.array([0, 2, -1]))
    assert _angle(rot[:, 0], x) < 1e-9
    # Two sides 6 deg either way of x, equal weights, one of them given as the other
    # axis (a quarter turn on): the mean is x. Unequal weights 3:1 pull it towards the
    # heavier: the circular mean of the doubled angles +-12 deg, atan2(2 sin 12, 4 cos 12),
    # halved (3.03 deg; the plain weighted mean would be 3 deg).
    plus = _rotation(UP, math.radians(6.0)) @ x
    minus_as_y = _rotation(UP, math.radians(-6.0 + 90.0)) @ x
    normals = np.array([plus, minus_as_y])
    rot = obb.upright_axes(UP, normals, np.array([1.0, 1.0]), np.array([0, 1]))
    assert _angle(rot[:, 0], x) < 1e-9
    rot = obb.upright_axes(UP, normals, np.array([3.0, 1.0]), np.array([0, 1]))
    expected = math.degrees(math.atan2(2 * math.sin(math.radians(12.0)),
                                       4 * math.cos(math.radians(12.0)))) / 2
    assert math.degrees(_angle(rot[:, 0], plus)) == pytest.approx(6.0 - expected, abs=1e-9)


def _patch(centre, u, v, half_u, half_v, n=15):
    """Grid of n x n points spanning +-half_u along ``u`` and +-half_v along ``v``."""
    a, b = np.meshgrid(np.linspace(-half_u, half_u, n), np.linspace(-half_v, half_v, n))
    return centre + np.outer(a.ravel(), u) + np.outer(b.ravel(), v)


def _top_and_strip(lean_deg, strip_half, top_n=21, strip_n=15):
    """Return the top of a box 50 mm square and a strip of its side, the strip's normal leaning.

    The strip (half-height ``strip_half`` [m], 50 mm wide) lies in the side's plane; its
    face's normal (what the noise made of it) leans ``lean_deg`` from the side's towards
    the top. Returns the (points, normal) of each face.
    """
    x, y, z = FRAME[:, 0], FRAME[:, 1], FRAME[:, 2]
    centre = np.array([0.0, 0.0, DEPTH])
    top = _patch(centre, x, y, 0.025, 0.025, n=top_n)
    strip = _patch(centre - 0.025 * x - strip_half * z, y, z, 0.025, strip_half, n=strip_n)
    lean = math.radians(lean_deg)
    return [(top, z), (strip, math.cos(lean) * -x + math.sin(lean) * z)]


def _cloud(parts, noise_model="auto"):
    """Return the parts of an ObjectCloud the strategy reads: faces, points, parameters."""
    pts = np.vstack([p for p, _ in parts])
    faces, start = [], 0
    for p, normal in parts:
        rows = np.arange(start, start + len(p))
        c = p.mean(axis=0)
        info = FaceInfo(True, normal, -float(normal @ c), len(p), np.tile(normal, (len(p), 1)),
                        c)
        faces.append(SimpleNamespace(info=info, working=rows))
        start += len(p)
    params = ModelingParams(noise_model=noise_model, ransac_threshold=THRESHOLD,
                            angle_tolerance=TOLERANCE)
    return SimpleNamespace(wc=SimpleNamespace(points=pts), faces=faces, params=params)


def _below(normal):
    """Return a stand-in for :func:`support_below` that finds a support of ``normal``."""
    return lambda _cloud: normal


@pytest.fixture
def on_the_desk(monkeypatch):
    """Stand the objects on the desk of normal UP (the plane :func:`support_below` finds)."""
    monkeypatch.setattr(strategies, "support_below", _below(UP))


def _attempt(parts, noise_model="auto"):
    situation = Situation(_cloud(parts, noise_model), GraphDecision("planar", (), 0, (), NEITHER))
    strategy = UprightBoxOnSupport()
    return strategy.attempt(situation) if strategy.applies(situation) else "not applied"


@pytest.mark.usefixtures("on_the_desk")
def test_a_top_and_a_side_strip_turned_by_the_noise_are_a_box_upright_on_the_desk():
    # The strip's normal leans 48 deg, but its points lie in the side's plane: the frame
    # holds both faces (every point within the threshold, none off by more than 0).
    attempt = _attempt(_top_and_strip(48.0, 0.004))
    assert attempt.decision.candidates == ("cuboid",)
    assert attempt.decision.axis_of_face == (2, 0)
    assert _angle(attempt.axis_prior, UP) < 1e-12


@pytest.mark.usefixtures("on_the_desk")
def test_a_face_the_upright_frame_does_not_hold_is_no_box():
    # A chamfer: the strip's points turned with its normal, 45 deg from the side's plane.
    # Its half-height of 10 mm strays 10 sin 45 = 7.1 mm from the plane at its ends, and
    # only the middle 2 x 5 / sin 45 = 14 of its 20 mm (70 %, below the 80 % bar) lies
    # within the 5 mm threshold.
    top, _ = _top_and_strip(0.0, 0.01)[0]
    x, y, z = FRAME[:, 0], FRAME[:, 1], FRAME[:, 2]
    tilt = _rotation(y, math.radians(45.0))
    along = tilt @ z
    strip = _patch(np.array([0.0, 0.0, DEPTH]) - 0.025 * x - 0.01 * z, y, along, 0.025, 0.01)
    assert _attempt([(top, z), (strip, tilt @ -x)]) is None


@pytest.mark.usefixtures("on_the_desk")
def test_two_sides_without_a_top_are_no_upright_box():
    # A cup's side seen as two facets (horizontal normals 62 deg apart): no face lies on
    # the desk's normal, so no top tells the box's height axis from the sides.
    x, y = FRAME[:, 0], FRAME[:, 1]
    a = _rotation(UP, math.radians(31.0)) @ x
    b = _rotation(UP, math.radians(-31.0)) @ x
    centre = np.array([0.0, 0.0, DEPTH])
    parts = [(_patch(centre, np.cross(UP, a), UP, 0.02, 0.02), a),
             (_patch(centre + 0.03 * y, np.cross(UP, b), UP, 0.02, 0.02), b)]
    assert _attempt(parts) is None
    # Nor is a top with a sliver (81 of 1762 points, below 5 %).
    assert _attempt(_top_and_strip(48.0, 0.004, top_n=41, strip_n=9)) is None


def test_without_a_support_below_or_the_measured_noise_nothing_is_tried(monkeypatch):
    parts = _top_and_strip(48.0, 0.004)
    monkeypatch.setattr(strategies, "support_below", _below(None))
    assert _attempt(parts) is None
    monkeypatch.setattr(strategies, "support_below", _below(UP))
    assert _attempt(parts, noise_model="fixed") == "not applied"


def test_it_is_tried_last():
    assert UprightBoxOnSupport.name not in [s.name for s in STRATEGIES]
    names = [s.name for s in LAST_STRATEGIES]
    assert names[-1] == UprightBoxOnSupport.name
    assert names.index(OuterWallAfterAll.name) < names.index(UprightBoxOnSupport.name)


def test_kinect_real_seed_70s_small_box_seen_from_above_is_a_box():
    # Clutter seed 70 under kinect-real noise: a box 42.5 x 46.7 x 47.1 mm at 0.71 m seen
    # mostly by its top (its lower part hidden); its side's strip came as a face 47.9 deg
    # from the desk's normal, the segment stayed `unknown` and was taken out as a fragment.
    scene = render_clutter(70, OPTIONAL_NOISE["kinect-real"])
    assert scene.kinds[3] == "box"
    box, labels = best_object_and_labels(scene, 3)
    assert box.type == "cuboid", box.reason
    assert scene_iou(labels, scene, 3, box.id) > 0.9
    truth = scene.objects[3].dimensions
    # Its height axis is the desk's normal (the fitted desk's, within a degree of the true).
    desk_up = scene.objects[0].rotation[:, 2]
    angles = [_angle(box.rotation[:, k], desk_up) for k in range(3)]
    up = int(np.argmin(angles))
    assert angles[up] < math.radians(1.0)
    names = ("length", "width", "height")
    # The height within 5 mm (the top's median height above the completed bottom), the
    # footprint within the noise band there (the RANSAC threshold at 0.71 m is 11 mm).
    assert box.dimensions[names[up]] == pytest.approx(truth["height"], abs=5 * MM)
    footprint = sorted(box.dimensions[names[k]] for k in range(3) if k != up)
    assert np.all(np.abs(np.array(footprint) - np.array(sorted(
        [truth["length"], truth["width"]]))) <= 11 * MM), box.dimensions


def test_kinect_real_seed_67s_cup_seen_as_two_facets_is_no_box():
    # The same noise: a cup seen by two facets of its side 62 deg apart is no box.
    scene = render_clutter(67, OPTIONAL_NOISE["kinect-real"])
    assert scene.kinds[6] == "cup"
    labels, result = model_scene(scene.organized, ModelingParams())
    hit = labels[scene.label_image.ravel() == 6]
    objects = {o.id: o for o in result.objects}
    held = [objects[i].type for i in np.unique(hit[hit >= 0]) if i in objects
            and np.count_nonzero(hit == i) > 0.5 * len(hit)]
    assert "cuboid" not in held

