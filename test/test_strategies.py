"""The fallback strategies of the modeling (geomodel_ros.core.fitting.strategies), each alone.

Each strategy is given an object and a model-graph decision built by hand, so that the
test states exactly when it must apply, what it proposes, and what it must leave alone.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from geomodel_ros.core.fitting.result import Rejected
from geomodel_ros.core.fitting.strategies import (STRATEGIES, Attempt, BoxOfFlatCores,
                                                  CurvedFacesAlone,
                                                  FlatCurvedFacesAsPlanar, ModelGraphCandidates,
                                                  Situation, UprightAboveSupport, flat_faces,
                                                  run_strategies, support_below)
from geomodel_ros.core.fitting.units import fit_first
from geomodel_ros.core.model_graph import GraphDecision
from geomodel_ros.core.primitives import PrimitiveType

from test_fitting_units import (CYL_AXIS, CYL_CENTER, CYL_H, CYL_R, PLANE_ROT, cloud_of,
                                cylinder_points, plane_points, sphere_points)

MM = 1e-3


def decision(category, candidates=(), main=-1, reason="graph"):
    return GraphDecision(category, tuple(candidates), main, (), reason)


def test_the_strategies_are_tried_in_the_documented_order():
    assert [s.name for s in STRATEGIES] == ["model graph", "curved faces alone",
                                            "flat curved faces as planar",
                                            "upright above the support",
                                            "planar patches of a curved object",
                                            "box of the flat cores",
                                            "planar faces without a rule",
                                            "doubly curved as a sphere",
                                            "nothing fitted, all faces curved"]


def test_model_graph_candidates_apply_only_when_the_graph_proposed_a_type():
    cloud = cloud_of(plane_points())
    strategy = ModelGraphCandidates()
    proposed = Situation(cloud, decision("planar", ["plane"], 0))
    assert strategy.applies(proposed)
    assert strategy.attempt(proposed) == Attempt(cloud, proposed.decision)
    assert not strategy.applies(Situation(cloud, decision("planar")))


def test_curved_faces_alone_judge_a_mixed_object_by_its_curvatures():
    cloud = cloud_of(cylinder_points())
    strategy = CurvedFacesAlone()
    situation = Situation(cloud, decision("mixed", (), 0, "curved normals at varying angles"))
    assert strategy.applies(situation)
    attempt = strategy.attempt(situation)
    # An all-curved decision: no main face, so no axis prior from a plane.
    assert (attempt.decision.category, attempt.decision.main_face) == ("curved", -1)
    assert attempt.decision.candidates[0] == "cylinder"  # k2 ~ 0, k1 constant
    assert attempt.note == f"curved faces alone: {attempt.decision.reason}"
    assert attempt.axis_prior is None and attempt.prefix == ""
    # Not when the graph proposed something, nor for planar or curved objects.
    for other in (decision("mixed", ["cylinder"], 0), decision("planar"), decision("curved")):
        assert not strategy.applies(Situation(cloud, other))


def _plane_typed_curved():
    """Return a flat rectangle whose only face the surface-type test misjudged as curved."""
    cloud = cloud_of(plane_points())
    (face,) = cloud.faces
    bent = dataclasses.replace(face, info=dataclasses.replace(face.info, planar=False))
    return dataclasses.replace(cloud, faces=[bent])


def test_flat_curved_faces_are_taken_as_planes():
    cloud = _plane_typed_curved()
    assert flat_faces(cloud) == [0]
    strategy = FlatCurvedFacesAsPlanar()
    situation = Situation(cloud, decision("curved", ["cylinder", "cone"]))
    assert strategy.applies(situation)
    attempt = strategy.attempt(situation)
    assert attempt.decision.candidates == ("plane",)
    assert attempt.note.startswith("faces [0] taken as planar (their normals turn less than "
                                   "20 deg): ")
    (face,) = attempt.cloud.faces
    assert face.info.planar and face.summary.surface == "planar"
    assert abs(face.info.normal @ PLANE_ROT[:, 2]) > math.cos(math.radians(0.01))
    assert face.info.normal @ face.info.center < 0  # towards the sensor
    assert situation.cloud.faces[0].info.planar is False  # the object itself is unchanged
    prim, reasons = fit_first(attempt.cloud, attempt.decision)
    assert prim.type is PrimitiveType.PLANE and reasons == ["plane verified"]


def test_a_round_face_is_not_taken_as_a_plane():
    cloud = cloud_of(cylinder_points())
    assert flat_faces(cloud) == []
    assert not FlatCurvedFacesAsPlanar().applies(Situation(cloud, decision("curved")))


def _bottom_support(offset=0.0):
    """Return the plane perpendicular to the cylinder's axis at its bottom end (+ offset)."""
    bottom = CYL_CENTER - (CYL_H / 2 - offset) * CYL_AXIS
    return (CYL_AXIS.copy(), -float(CYL_AXIS @ bottom))


def test_a_cylinder_standing_on_a_support_is_fitted_upright_and_closed_by_it():
    support = _bottom_support()
    cloud = cloud_of(cylinder_points(), supports=(support,))
    np.testing.assert_array_equal(support_below(cloud), support[0])
    strategy = UprightAboveSupport()
    situation = Situation(cloud, decision("curved", ["sphere", "cylinder", "cone"]))
    assert strategy.applies(situation)
    attempt = strategy.attempt(situation)
    assert attempt.decision.candidates == ("cylinder", "cone")
    np.testing.assert_array_equal(attempt.axis_prior, support[0])
    assert attempt.prefix == "upright above the support: "
    prim, _ = fit_first(attempt.cloud, attempt.decision, attempt.axis_prior)
    assert prim.type == "cylinder"
    assert prim.dimensions["radius"] == pytest.approx(CYL_R, abs=0.001 * MM)
    assert prim.dimensions["height"] == pytest.approx(CYL_H, abs=0.1 * MM)


def _plane_along_the_axis():
    """Return a plane containing the cylinder's axis that splits its visible half in two."""
    normal = np.array([1.0, 0.0, 0.0])  # perpendicular to the axis and to the view
    return (normal, -float(normal @ CYL_CENTER))


@pytest.mark.parametrize("support", [_bottom_support(CYL_H / 2), _plane_along_the_axis()])
def test_no_upright_fit_without_a_support_below(support):
    # A plane through the middle of the object: the object does not stand on it.
    cloud = cloud_of(cylinder_points(), supports=(support,))
    assert support_below(cloud) is None
    situation = Situation(cloud, decision("curved", ["cylinder"]))
    assert UprightAboveSupport().attempt(situation) is None
    assert UprightAboveSupport().attempt(Situation(cloud_of(cylinder_points()),
                                                   decision("curved", ["cylinder"]))) is None


def test_no_upright_fit_for_a_sphere():
    cloud = cloud_of(sphere_points(), supports=(_bottom_support(),))
    assert not UprightAboveSupport().applies(Situation(cloud, decision("curved", ["sphere"])))


class _Fixed:
    """A strategy that always proposes one decision (for the runner's test)."""

    name = "fixed"

    def __init__(self, candidates, note=None):
        self.candidates, self.note = candidates, note

    def applies(self, _situation):
        return True

    def attempt(self, situation):
        return Attempt(situation.cloud, decision("planar", self.candidates, 0, "fixed"),
                       note=self.note, prefix="fixed: ")


def test_the_runner_stops_at_the_first_strategy_that_fits_and_keeps_every_reason():
    cloud = cloud_of(plane_points())
    situation = Situation(cloud, decision("planar", ["sphere"], 0, "graph reason"))
    never = _Fixed(["cylinder"], note="never tried")
    prim, summaries, reasons = run_strategies(
        situation, (ModelGraphCandidates(), _Fixed(["cylinder", "plane"], "second"), never))
    assert prim.type == "plane"
    assert summaries == tuple(f.summary for f in cloud.faces)
    assert reasons == ["graph reason", "sphere: no curved face", "second",
                       "fixed: cylinder: no curved face", "fixed: plane verified"]


def test_the_runner_returns_nothing_but_reasons_when_no_strategy_fits():
    cloud = cloud_of(plane_points())
    situation = Situation(cloud, decision("planar", ["cone"], 0, "graph reason"))
    prim, summaries, reasons = run_strategies(situation)
    assert prim is None and summaries == tuple(f.summary for f in cloud.faces)
    assert reasons == ["graph reason", "cone: no curved face"]


def test_the_last_strategies_run_only_when_nothing_else_fits():
    cloud = cloud_of(plane_points())
    # No curved face for the cone: the last strategy is tried, and fits.
    situation = Situation(cloud, decision("planar", ["cone"], 0, "graph reason"))
    prim, _, reasons = run_strategies(situation, (ModelGraphCandidates(),),
                                      (_Fixed(["plane"], "last"),))
    assert prim.type == "plane"
    assert reasons == ["graph reason", "cone: no curved face", "last", "fixed: plane verified"]
    # The plane fits first: the last strategy is never tried.
    situation = Situation(cloud, decision("planar", ["plane"], 0, "graph reason"))
    prim, _, reasons = run_strategies(situation, (ModelGraphCandidates(),),
                                      (_Fixed(["cylinder"], "never"),))
    assert prim.type == "plane" and "never" not in reasons


def test_the_runner_records_every_rejection_for_later_strategies():
    cloud = cloud_of(plane_points())
    situation = Situation(cloud, decision("planar", ["cone", "sphere"], 0, "graph reason"))
    run_strategies(situation, (ModelGraphCandidates(),))
    assert [r.type for r in situation.rejected] == [PrimitiveType.CONE, PrimitiveType.SPHERE]
    # No curved face: no round model was found that could misfit the points.
    assert not situation.round_misfit


def test_the_box_of_flat_cores_needs_a_round_model_that_does_not_explain_the_points():
    # A flat plate has no box rival at all, and a rejection for another cause than a
    # misfit (or of a non-round type) never calls for the box either.
    cloud = cloud_of(plane_points())
    for rejected in ([], [Rejected(PrimitiveType.CYLINDER, "axis not aligned")],
                     [Rejected(PrimitiveType.CUBOID, "scatter", misfit=True)]):
        situation = Situation(cloud, decision("planar", [], 0), rejected=list(rejected))
        assert not situation.round_misfit
        assert not BoxOfFlatCores().applies(situation)
    scattered = Situation(cloud, decision("planar", [], 0), rejected=[
        Rejected(PrimitiveType.CONE, "scatter", misfit=True)])
    assert scattered.round_misfit
    assert scattered.box_rival is None and not BoxOfFlatCores().applies(scattered)


def test_the_box_of_flat_cores_is_tried_when_the_curvatures_fit_no_round_shape():
    # No round shape at all (the curved faces' curvatures fit no primitive) counts like a
    # round model that does not explain the points; candidates left to try, or an object
    # judged by its planar faces alone, do not.
    cloud = cloud_of(plane_points())
    assert Situation(cloud, decision("curved", [])).no_round_shape
    assert not Situation(cloud, decision("curved", ["cylinder"])).no_round_shape
    assert not Situation(cloud, decision("planar", [], 0)).no_round_shape
    # The flat plate has no box rival: the strategy still needs one.
    assert not BoxOfFlatCores().applies(Situation(cloud, decision("curved", [])))
