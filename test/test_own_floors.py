"""An open container keeps its own floor where it lies in the support's band.

Under a real sensor's noise the support's band is 10-14 mm thick and a container's floor,
a few millimetres above the desk, lies in it. When the floor stayed with the container's
segment (linked to its wall, not to the desk), the contact rims' claim used to take it at
the end of the segmentation (kinect-real clutter: a cup or bowl lost its whole floor,
20-40 % of its points). :func:`geomodel_ros.core.joins.own_floors` finds such a floor by
the container's own wall: its low points seen through the wall's opening. Hand-built
geometry (the bowls of ``test_container_floor``) for the function, the desk joined at a
contact and a closed can as the negative cases, and rendered clutter scenes for the
whole segmentation.
"""

from __future__ import annotations

import numpy as np
import pytest

from geomodel_ros.core.joins import own_floors
from geomodel_ros.core.params import ModelingParams
from geomodel_ros.core.ransac import PlaneModel
from geomodel_ros.core.segmentation import segment_scene
from geomodel_ros.tools.synth.clutter import render_clutter
from geomodel_ros.tools.synth.scenes import KINECT_REAL_NOISE
from test_container_floor import BAND, STEP, _bowl_scene, _can_sides, _grid, _ray_at

DESK = 0.8
PLANE = PlaneModel(np.array([0.0, 0.0, 1.0]), DESK)


def _own(points, normals, seg):
    return own_floors(points, normals, seg, seg >= 0, PLANE, BAND + STEP)


def _contact_ring(center, inner, outer):
    """Desk points (z = -DESK) between ``inner`` and ``outer`` [m] from ``center`` (x, y)."""
    xy = _grid(center - outer, center + outer)
    r = np.linalg.norm(xy - center, axis=1)
    xy = xy[(r > inner) & (r < outer)]
    return np.column_stack([xy, np.full(len(xy), -DESK)])


@pytest.mark.parametrize("at", [(0.0, 0.45), (0.2, 0.3), (-0.15, 0.6)])
def test_a_bowls_own_floor_is_found_and_the_desk_it_holds_is_not(at):
    center = np.array(at)
    points, normals, seg, floor = _bowl_scene([center])
    desk = np.flatnonzero(seg < 0)
    # The 300 desk points seen nearest the bowl, joined to it (a contact's blended normals).
    joined = desk[np.argsort(np.linalg.norm(points[desk, :2] - center, axis=1))[:300]]
    seg[joined] = 0
    got = _own(points, normals, seg)
    assert not np.isin(got, desk).any()
    assert np.isin(np.flatnonzero(floor), got).mean() >= 0.9
    # Nothing but the floor and the bowl's own wall inside, up to the band.
    assert (points[got, 2] + DESK <= BAND + STEP).all()


def test_a_closed_can_has_no_own_floor():
    # A can 30 mm in radius, 100 mm high, with its lid, and the desk around its foot
    # joined to it: the lid closes the top, no low point is seen through its circle.
    center, radius, height = np.array([0.05, 0.45]), 0.03, 0.10
    pts, nrm, _ = _can_sides([center], radius, height, DESK)
    xy = _grid(center - radius, center + radius)
    xy = xy[np.linalg.norm(xy - center, axis=1) < radius]
    lid = np.column_stack([xy, np.full(len(xy), -DESK + height)])
    ring = _contact_ring(center, radius + 0.5 * STEP, radius + 4 * STEP)
    hidden = np.zeros(len(ring), dtype=bool)
    for h in np.linspace(0.0, height, 25):
        hidden |= np.linalg.norm(_ray_at(ring, h, DESK)[:, :2] - center, axis=1) < radius
    ring = ring[~hidden]
    points = np.vstack([pts, lid, ring])
    normals = np.vstack([nrm, np.tile([0.0, 0.0, 1.0], (len(lid) + len(ring), 1))])
    seg = np.zeros(len(points), dtype=np.int64)
    assert len(ring) > 50
    assert len(_own(points, normals, seg)) == 0


def _support_share(scene, seg, gt_id):
    labels = seg.labels.reshape(scene.label_image.shape)
    return float(np.isin(labels[scene.label_image == gt_id], seg.support_ids).mean())


@pytest.mark.parametrize("seed, gt_id", [(48, 5), (47, 1)])
def test_a_cluttered_containers_floor_stays_the_containers(seed, gt_id):
    # kinect-real clutter: a cup (seed 48, 56 mm at its foot, 82 mm high, 0.8 m away) and
    # a bowl (seed 47, 1.3 m away) whose floors the desk took before, 21 and 24 % of
    # their points.
    scene = render_clutter(seed, KINECT_REAL_NOISE)
    assert scene.kinds[gt_id] in ("cup", "bowl")
    seg = segment_scene(scene.organized, ModelingParams())
    assert _support_share(scene, seg, gt_id) < 0.08
