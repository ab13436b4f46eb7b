"""An object of mixed or planar faces that no strategy models: every face taken as curved.

Module: core.fitting.strategies (AllFacesCurvedAfterAll, tried after every other strategy).

Far from the sensor a small patch of a round surface bends within the frame's noise and
passes for a flat end; the mixed rules' axes then follow its normal and fail. Expectations
from the scenes' construction: the suite's ball has radius 40 mm; its torus (set_b) is no
primitive and must stay ``unknown``.
"""
from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest

from geomodel_ros.core.fitting.strategies import STRATEGIES, AllFacesCurvedAfterAll
from geomodel_ros.core.model_graph import GraphDecision
from geomodel_ros.core.modeling import model_scene
from geomodel_ros.core.params import ModelingParams
from geomodel_ros.core.primitives import PrimitiveType
from geomodel_ros.tools.bench_office import OFFICE_NAMES, office_scene
from geomodel_ros.tools.synth.clutter import KINECT_NOISE, render_clutter
from geomodel_ros.tools.synth.scenes import KINECT_REAL_NOISE
from geomodel_ros.tools.synth.suite import SuiteCase, render_case

MM = 1e-3


def _slab(thickness, n=400, seed=0):
    """Points (n, 3) [m] of a 200 x 160 mm patch tilted in space, ``thickness`` [m] deep."""
    rng = np.random.default_rng(seed)
    local = rng.uniform(-0.5, 0.5, (n, 3)) * [0.2, 0.16, thickness]
    local[:2, 2] = [-0.5 * thickness, 0.5 * thickness]  # the extent is exactly reached
    c, s = np.cos(0.6), np.sin(0.6)
    rot = np.array([[1, 0, 0], [0, c, -s], [0, s, c]]) @ np.array([[c, 0, s], [0, 1, 0],
                                                                    [-s, 0, c]])
    return local @ rot.T + [0.1, -0.2, 0.9]


def situation(category, sizes, noise_model="auto", thickness=0.05, threshold=0.01):
    """Return the parts of a Situation the test reads; faces as (planar, size) pairs.

    The object's working points are a slab ``thickness`` [m] deep, its RANSAC threshold
    ``threshold`` [m].
    """
    faces = [SimpleNamespace(info=SimpleNamespace(planar=p, size=s)) for p, s in sizes]
    params = ModelingParams(noise_model=noise_model, ransac_threshold=threshold)
    return SimpleNamespace(decision=GraphDecision(category, (), 0, (), ""),
                           cloud=SimpleNamespace(faces=faces, params=params,
                                                 wc=SimpleNamespace(points=_slab(thickness))))


def test_it_applies_to_mixed_objects_and_to_planar_ones():
    s = AllFacesCurvedAfterAll()
    # The ball at 1.5 m: curved faces of 95 and 119 working points, a 48-point patch.
    assert s.applies(situation("mixed", [(False, 95), (True, 48), (False, 119)]))
    # Whatever share the planar faces hold (a lying can whose larger side facet passed as
    # planar); the round model then meets the box of the flat cores.
    assert s.applies(situation("mixed", [(False, 100), (True, 100)]))
    assert s.applies(situation("mixed", [(False, 40), (True, 200)]))
    # Objects of planar faces only (facets of a small round body, or one face whose
    # plane was rejected) apply too; curved ones had their curved candidates already.
    assert s.applies(situation("planar", [(True, 10), (True, 10)]))
    assert s.applies(situation("planar", [(True, 60)]))
    assert not s.applies(situation("curved", [(False, 10)]))
    # Only with the measured noise model.
    assert not s.applies(situation("mixed", [(False, 95), (True, 48)], noise_model="fixed"))
    assert not s.applies(situation("planar", [(True, 10), (True, 10)], noise_model="fixed"))


def test_planar_faces_within_one_inlier_band_are_not_taken_as_curved():
    # What must not happen: points that one plane's band holds taken for a bend (the
    # office scene's far object, 107 mm deep under a 210 mm band, became a cone of
    # r 327 mm). The band reaches a threshold either side of the plane: 50 mm deep is
    # curved under a 20 mm threshold, not under a 30 mm one.
    s = AllFacesCurvedAfterAll()
    faces = [(True, 200), (True, 200)]
    assert s.applies(situation("planar", faces, thickness=0.05, threshold=0.02))
    assert not s.applies(situation("planar", faces, thickness=0.05, threshold=0.03))
    assert not s.applies(situation("planar", [(True, 400)], thickness=0.107, threshold=0.21))
    # The band does not restrict mixed objects (their curved faces showed).
    assert s.applies(situation("mixed", [(False, 95), (True, 48), (False, 119)],
                               thickness=0.02, threshold=0.03))


def _clutter_object(seed, gt, noise=KINECT_REAL_NOISE):
    """Model clutter scene ``seed`` (kinect-real noise unless ``noise``); the model of ``gt``.

    The model holding most of object ``gt``, and the share of ``gt``'s pixels in that
    model's segment.
    """
    scene = render_clutter(seed, noise)
    truth = scene.label_image.ravel()
    labels, result = model_scene(scene.organized.reshape(-1, 3), ModelingParams(),
                                 organized_shape=scene.label_image.shape)
    own = labels[truth == gt]
    assert np.any(own >= 0), "the object was dropped"
    best = int(np.bincount(own[own >= 0]).argmax())
    return {o.id: o for o in result.objects}[best], float(np.mean(own == best))


@pytest.mark.parametrize("seed, gt, radius, height", [(46, 5, 0.0399, 0.1004),
                                                     (55, 4, 0.0374, 0.0802)])
def test_kinect_real_cones_seen_as_facets_are_cones(seed, gt, radius, height):
    # Cones at about 1 m whose side came as two planar facets meeting at no right angle:
    # no rule, no box; left `unknown` they were dropped as fragments (about 600 pixels).
    # Truth from the scenes' construction.
    cone, share = _clutter_object(seed, gt)
    assert share > 0.9
    assert cone.type == PrimitiveType.CONE
    assert cone.dimensions["radius"] == pytest.approx(radius, abs=4 * MM)
    assert cone.dimensions["height"] == pytest.approx(height, abs=6 * MM)


def test_a_lying_can_whose_side_facet_passed_as_planar_is_a_cylinder():
    # Kinect-class clutter seed 47's lying can: a curved face and a side facet that
    # passed as planar; the mixed rules made the round fits' axis follow the facet's
    # normal, as a cap's, and every fit failed (`unknown`). Truth from the scene.
    can, share = _clutter_object(47, 5, KINECT_NOISE)
    assert share > 0.9
    true = render_clutter(47).objects[5]
    assert can.type == PrimitiveType.CYLINDER
    assert can.dimensions["radius"] == pytest.approx(true.dimensions["radius"], abs=2 * MM)
    axis_error = math.degrees(math.acos(min(1.0, abs(float(
        can.rotation[:, 2] @ true.rotation[:, 2])))))
    assert axis_error < 3.0


@pytest.mark.parametrize("distance, yaw", [(3.5, 0.0), (4.0, 20.0)])
def test_pieces_of_a_far_wall_are_not_taken_for_round_bodies(distance, yaw):
    # What must not happen: the kinect-real office (bench_office, seed 2) at 3.5-4 m.
    # Pieces of the walls 1.1-1.4 thresholds thick came out as a cone (r 254 mm) and a
    # cylinder (r 80 mm). No round object may hold mostly wall points.
    scene = office_scene(distance, yaw, KINECT_REAL_NOISE, rng=2)
    truth = scene.label_image.ravel()
    labels, result = model_scene(scene.organized.reshape(-1, 3), ModelingParams(),
                                 organized_shape=scene.label_image.shape)
    walls = [OFFICE_NAMES.index(name) for name in ("wall", "side wall", "door")]
    for o in result.objects:
        if o.type in (PrimitiveType.CYLINDER, PrimitiveType.CONE, PrimitiveType.FRUSTUM,
                      PrimitiveType.SPHERE):
            assert np.mean(np.isin(truth[labels == o.id], walls)) < 0.5, o


def test_it_is_tried_last():
    assert isinstance(STRATEGIES[-1], AllFacesCurvedAfterAll)


def _over(scene, labels, result, gid):
    """Return the modelled object holding most of true object ``gid``'s points, or None."""
    inside = labels[(scene.labels == gid) & (labels >= 0)]
    if not inside.size:
        return None
    oid = int(np.argmax(np.bincount(inside)))
    return next(o for o in result.objects if o.id == oid)


def test_the_ball_at_1_5_m_with_a_flat_reading_patch_is_a_sphere_of_its_radius():
    # set_a at 1.5 m, kinect-real, seed 2, moved 1 mm along camera x and y: a 48-point
    # patch of the ball's top passes as planar and bends within the frame's slow errors;
    # the cone and cylinder along its normal fail and the ball was dropped as a fragment.
    scene = render_case(SuiteCase("set_a", 1.5, "kinect-real", 2))
    assert scene.objects[3].type == "sphere"
    labels, result = model_scene(scene.points + np.array([1.0, 1.0, 0.0]) * MM,
                                 ModelingParams())
    ball = _over(scene, labels, result, scene.objects[3].id)
    assert ball is not None
    assert ball.type == PrimitiveType.SPHERE
    assert ball.dimensions["radius"] == pytest.approx(0.040, abs=2 * MM)


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_the_torus_at_1_5_m_stays_unknown(seed):
    # What must not happen: an object that is no primitive typed by the curvatures' fit.
    scene = render_case(SuiteCase("set_b", 1.5, "kinect-real", seed))
    torus = next(g for g in scene.objects if g.type == "torus")
    labels, result = model_scene(scene.points, ModelingParams())
    ring = _over(scene, labels, result, torus.id)
    assert ring is None or ring.type == PrimitiveType.UNKNOWN
