"""Boxes typed plane under a real sensor's noise: a plane folded over two of a box's sides.

Far from the sensor the crease between two sides of a small box blurs under kinect-real
noise, the face segmentation keeps both as one planar face, and a plane verifies through
them. The measured normals still gather on the sides: the box of their modes, fitted when
most of the normals face its sides, replaces the plane when it holds the points closer
beyond the noise (:func:`~geomodel_ros.core.fitting.strategies.box_of_plane`). Expected
sizes are the rendered shapes'; every positive case was a plane before.
"""

from __future__ import annotations

import math
import re

import pytest

from geomodel_ros.core import modeling
from geomodel_ros.core.fitting import strategies
from geomodel_ros.tools.synth.clutter import camera_pose, make_box, render_clutter, \
    render_layout
from geomodel_ros.tools.synth.scenes import KINECT_REAL_NOISE
from suite_helpers import best_object, box_sizes

MM = 1e-3
#: Student quantile of paired_cost.lower_beyond_noise at its level 0.025 over 16 blocks
#: (15 degrees of freedom): the least statistic of a box that replaces the plane.
T_16_BLOCKS = 2.131
#: The comparison box_of_plane adds to the reasons: the box's mean truncated cost, the
#: share of the normals on its sides, the verdict, the plane's cost and the paired statistic.
BOX_NOTE = re.compile(r"box of the point normals' modes \(sides along axes [^)]*\); cuboid \(cost "
                      r"([0-9.]+), ([0-9]+)% of the normals on its sides\) (replaces|does not "
                      r"replace) plane \(cost ([0-9.]+), t = ([-0-9.]+)\)")


def _replaced(reason: str) -> None:
    found = BOX_NOTE.search(reason)
    assert found and found.group(3) == "replaces", reason
    box_cost, share, _, plane_cost, stat = found.groups()
    assert float(box_cost) < float(plane_cost)
    assert int(share) >= 50  # most of the normals face a side of the box
    assert float(stat) >= T_16_BLOCKS


def test_a_small_box_far_away_seen_as_one_folded_face_is_a_box():
    # A box 50 x 40 x 100 mm at 1.2 m, two sides seen as one planar face (a plane of
    # 108 x 48 mm before): the box of the normals' modes, each size within the range's
    # error over a side at that distance (4-5 mm of noise per pixel, slow errors).
    dims = (0.05, 0.04, 0.10)
    scene = render_layout([make_box(*dims, yaw=0.5)], [0],
                          camera_pose(1.2, math.radians(35.0), 0.3),
                          noise=KINECT_REAL_NOISE, rng=7)
    obj = best_object(scene, 1)
    assert obj.type == "cuboid", obj.reason
    assert "single planar face; plane verified" in obj.reason
    _replaced(obj.reason)
    assert box_sizes(obj) == pytest.approx(sorted(dims), abs=6.0 * MM)


@pytest.mark.parametrize("seed, gt_id, sized", [(17, 8, False), (22, 11, True), (39, 13, True)])
def test_clutter_boxes_seen_as_one_folded_face_are_boxes(seed, gt_id, sized):
    # kinect-real clutter boxes at 0.68-0.93 m, each a plane through two of its sides
    # before. Boxes 22:11 (55 x 109 x 37 mm) and 39:13 (63 x 46 x 41 mm) have their sizes
    # within 6 mm; 17:8 (50 x 60 x 31 mm) shows too little of its third side (one size
    # 33 for 50 mm was measured), so only its type is asked.
    scene = render_clutter(seed, KINECT_REAL_NOISE)
    assert scene.kinds[gt_id] == "box"
    obj = best_object(scene, gt_id)
    assert obj.type == "cuboid", obj.reason
    _replaced(obj.reason)
    if sized:
        truth = scene.objects[gt_id].dimensions
        assert box_sizes(obj) == pytest.approx(sorted(truth.values()), abs=6.0 * MM)


def test_a_cans_top_whose_space_below_is_hidden_stays_the_cans_top():
    # kinect-real clutter seed 6 seen from 15-25 deg: can 10 (r 39, h 147 mm at 1.2 m) shows
    # its lid with a strip of its side as one planar face parallel to the desk, the space
    # below hidden; its normals give a box of three sides that would lie across the can
    # (a cuboid 148 x 77 x 72 mm was measured when the box was asked first). The solid
    # below the top face comes first: the cylinder down to the desk.
    scene = render_clutter(6, KINECT_REAL_NOISE, elevation=(math.radians(15), math.radians(25)))
    assert scene.kinds[10] == "can"
    obj = best_object(scene, 10)
    assert obj.type == "cylinder", obj.reason
    assert "a top face alone" in obj.reason
    assert "box of the point normals' modes" not in obj.reason
    truth = scene.objects[10].dimensions
    assert obj.dimensions["radius"] == pytest.approx(truth["radius"], abs=2.0 * MM)


@pytest.fixture
def asked(monkeypatch) -> list:
    """Return the list of what each call of box_of_plane returns (the rule still runs)."""
    got_list = []

    def spy(situation, plane, reasons, _real=strategies.box_of_plane):
        got = _real(situation, plane, reasons)
        got_list.append(got)
        return got

    monkeypatch.setattr(modeling, "box_of_plane", spy)
    return got_list


@pytest.mark.parametrize("distance, elevation_deg", [(0.8, 30.0), (1.1, 45.0)])
def test_a_thin_panel_standing_on_the_desk_stays_a_plane(asked, distance, elevation_deg):
    # A panel 300 x 12 x 200 mm standing on the desk under kinect-real noise: its front
    # is one planar face and a plane; its 12 mm edges give no box the plane gives way to
    # (box_of_plane is asked and refuses), and the plane keeps the front's sizes.
    scene = render_layout([make_box(0.30, 0.012, 0.20, yaw=0.3)], [0],
                          camera_pose(distance, math.radians(elevation_deg), 0.2),
                          noise=KINECT_REAL_NOISE, rng=7)
    obj = best_object(scene, 1)
    assert obj.type == "plane", obj.reason
    assert asked and all(got is None for got in asked)
    assert sorted(obj.dimensions.values()) == pytest.approx([0.20, 0.30], abs=8.0 * MM)


def test_a_balls_normals_give_no_box(asked):
    # kinect-real clutter seed 39 seen from 15-25 deg: ball 11 (r 36.5 mm at 0.8 m) passes
    # as one planar face; its normals give two perpendicular modes, but most of them
    # (72 %) face neither: the box is not fitted (it was a cuboid of 33 x 61 x
    # 53 mm while the rule asked only for normals closer than the plane's on average).
    scene = render_clutter(39, KINECT_REAL_NOISE, elevation=(math.radians(15), math.radians(25)))
    assert scene.kinds[11] == "sphere"
    obj = best_object(scene, 11)
    assert obj.type != "cuboid", obj.reason
    assert asked and all(got is None for got in asked)
