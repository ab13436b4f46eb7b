"""A mostly curved object that no strategy models is fitted with every face taken as curved.

Module: core.fitting.strategies (CurvedMajorityAfterAll, tried after every other strategy).

Far from the sensor a small patch of a round surface bends within the frame's noise and
passes for a flat end; the mixed rules' axes then follow its normal and fail. Expectations
from the scenes' construction: the suite's ball has radius 40 mm; its torus (set_b) is no
primitive and must stay ``unknown``.
"""
from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from geomodel_ros.core.fitting.strategies import STRATEGIES, CurvedMajorityAfterAll
from geomodel_ros.core.model_graph import GraphDecision
from geomodel_ros.core.modeling import model_scene
from geomodel_ros.core.params import ModelingParams
from geomodel_ros.core.primitives import PrimitiveType
from geomodel_ros.tools.synth.suite import SuiteCase, render_case

MM = 1e-3


def situation(category, sizes, noise_model="auto"):
    """Return the parts of a Situation the test reads; faces as (planar, size) pairs."""
    faces = [SimpleNamespace(info=SimpleNamespace(planar=p, size=s)) for p, s in sizes]
    return SimpleNamespace(decision=GraphDecision(category, (), 0, (), ""),
                           cloud=SimpleNamespace(faces=faces,
                                                 params=ModelingParams(noise_model=noise_model)))


def test_it_applies_to_mixed_objects_whose_curved_faces_hold_most_points():
    s = CurvedMajorityAfterAll()
    # The ball at 1.5 m: curved faces of 95 and 119 working points, a 48-point patch.
    assert s.applies(situation("mixed", [(False, 95), (True, 48), (False, 119)]))
    # A can with a large flat lid, a box with a rounded edge: the planar faces hold most.
    assert not s.applies(situation("mixed", [(False, 100), (True, 100)]))
    assert not s.applies(situation("mixed", [(False, 40), (True, 200)]))
    # Only mixed objects, only with the measured noise model.
    assert not s.applies(situation("planar", [(True, 10), (True, 10)]))
    assert not s.applies(situation("curved", [(False, 10)]))
    assert not s.applies(situation("mixed", [(False, 95), (True, 48)], noise_model="fixed"))


def test_it_is_tried_last():
    assert isinstance(STRATEGIES[-1], CurvedMajorityAfterAll)


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
