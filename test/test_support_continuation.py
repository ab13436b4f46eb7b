"""A support surface that bends beyond its plane's band stays one support.

A depth camera's range error grows towards the image border and with range, so a desk or
floor bends away from its best plane at the image corners and far away; the part beyond
the support's band must join the support (:func:`geomodel_ros.core.support.
continued_supports`), not be reported as an object. What must NOT join: a flat piece
standing off the support by more than the band, a piece that is not linked to it, and a
piece that is in the band but not parallel to it.

The rule is tested directly on hand-made working clouds, and end to end on the paper's
desk rendered with a radial range error (the desk's ground truth from the renderer).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from geomodel_ros.core.noise import K_SUPPORT
from geomodel_ros.core.params import ModelingParams
from geomodel_ros.core.ransac import fit_plane_svd
from geomodel_ros.core.segmentation import segment_scene
from geomodel_ros.core.support import (CONTINUATION_MIN_SHARE, SUPPORT_LINK_VOXELS,
                                       continued_supports)
from geomodel_ros.tools.synth import Box, apply_noise
from geomodel_ros.tools.synth.clutter import KINECT_NOISE
from geomodel_ros.tools.synth.scenes import (SEGMENTATION_CAMERA, _desk, _rest_on_desk,
                                             _standing)

MM = 1e-3
#: Working-point spacing of the hand-made clouds [m].
SPACING = 4 * MM


class _ConstantNoise:
    """Depth noise of the same sigma [m] at every range."""

    def __init__(self, sigma: float) -> None:
        self.value = sigma

    def sigma(self, z):
        return np.full(np.shape(z), self.value)


def _grid(x0: float, x1: float, y0: float, y1: float) -> np.ndarray:
    """Points of the plane z = 1 m on a SPACING grid over [x0, x1) x [y0, y1) [m]."""
    x, y = np.meshgrid(np.arange(x0, x1, SPACING), np.arange(y0, y1, SPACING), indexing="ij")
    return np.stack([x.ravel(), y.ravel(), np.ones(x.size)], axis=1)


def _continue(support: np.ndarray, piece: np.ndarray, noise=None,
              params: ModelingParams | None = None) -> bool:
    """Run the rule on a support and one segment; return whether the segment joined."""
    from scipy.spatial import cKDTree

    params = params or ModelingParams()
    wp = np.concatenate([support, piece])
    n_s = len(support)
    comp = np.full(len(wp), -1, dtype=np.int64)
    comp[n_s:] = 0
    comp_ok = comp >= 0
    wlabel = np.where(comp_ok, -1, 0)
    supports = [np.arange(n_s)]
    sqdist, nbrs = cKDTree(wp).query(wp, k=9)
    taken = continued_supports(wp, np.ones(len(wp), dtype=np.int64), comp, comp_ok, wlabel,
                               supports, (nbrs, np.square(sqdist)),
                               SUPPORT_LINK_VOXELS * SPACING, noise, params)
    joined = len(taken) == len(piece)
    assert joined == (not comp_ok.any()) == bool((wlabel[n_s:] == 0).all())
    assert len(taken) in (0, len(piece))
    return joined


def _bent(piece: np.ndarray, depth: float) -> np.ndarray:
    """Bend ``piece`` (x from 0.2 m on) away from z = 1 by up to ``depth`` [m], quadratically."""
    out = piece.copy()
    t = (out[:, 0] - out[:, 0].min()) / np.ptp(out[:, 0])
    out[:, 2] += depth * t * t
    return out


def test_a_bend_within_the_band_joins_the_support():
    # Default band 4 mm (no noise known); the piece bends 3 mm away over 80 mm.
    support, piece = _grid(0.0, 0.2, 0.0, 0.2), _grid(0.2, 0.28, 0.0, 0.2)
    assert _continue(support, _bent(piece, 3 * MM))


def test_a_piece_off_the_support_by_more_than_its_band_stays_apart():
    # A flat board 12 mm (three bands) above the support, linked to it by its edge.
    support, piece = _grid(0.0, 0.2, 0.0, 0.2), _grid(0.2, 0.28, 0.0, 0.2)
    raised = piece.copy()
    raised[:, 2] -= 12 * MM  # towards the sensor at the origin
    assert not _continue(support, raised)
    # Half of it within the band is not enough either.
    half = piece.copy()
    half[half[:, 0] >= 0.24, 2] -= 12 * MM
    assert not _continue(support, half)


def test_a_piece_not_linked_to_the_support_stays_apart():
    # In the support's plane but 20 mm (5 spacings) away: a depth hole between them.
    support, piece = _grid(0.0, 0.2, 0.0, 0.2), _grid(0.22, 0.30, 0.0, 0.2)
    assert not _continue(support, piece)


@pytest.mark.parametrize("tilt_deg, joins", [(10.0, True), (45.0, False)])
def test_a_piece_within_the_band_must_also_be_parallel(tilt_deg, joins):
    # Far away (sigma 5 mm: band 20 mm) a narrow strip tilted about the support's edge
    # stays within the band either way (at most 16 mm * sin(tilt) off); only its normal
    # tells a surface that turns (45 deg > seg_plane_normal_angle, 28.6 deg) from one
    # that continues.
    params = ModelingParams()
    assert math.radians(10.0) < params.seg_plane_normal_angle < math.radians(45.0)
    support, piece = _grid(0.0, 0.2, 0.0, 0.2), _grid(0.2, 0.22, 0.0, 0.2)
    t = math.radians(tilt_deg)
    d = piece[:, 0] - 0.2 + SPACING  # the strip starts one spacing from the support's edge
    piece = np.stack([0.2 - SPACING + d * math.cos(t), piece[:, 1], 1.0 - d * math.sin(t)],
                     axis=1)
    cos_ray = piece[:, 2] / np.linalg.norm(piece, axis=1)  # the support's normal is z
    assert (np.abs(piece[:, 2] - 1.0) < K_SUPPORT * 5 * MM * cos_ray).all()  # in the band
    assert _continue(support, piece, noise=_ConstantNoise(5 * MM), params=params) is joins


def test_the_share_in_the_band_is_the_documented_one():
    # 3 % of the piece far off (flying pixels) still joins; 10 % does not.
    support, piece = _grid(0.0, 0.2, 0.0, 0.2), _grid(0.2, 0.28, 0.0, 0.2)
    n_out = [int(0.03 * len(piece)), int(0.10 * len(piece))]
    assert n_out[0] / len(piece) < 1 - CONTINUATION_MIN_SHARE < n_out[1] / len(piece)
    rng = np.random.default_rng(0)
    for n, joins in zip(n_out, (True, False)):
        p = piece.copy()
        p[rng.choice(len(p), n, replace=False), 2] -= 12 * MM
        assert _continue(support, p) is joins


# --- End to end: the paper's desk with a radial range error --------------------------------

#: Range error at the desk's farthest pixel from the image centre [m]. A Kinect's depth
#: bends towards its image corners (osd_learn's tables at 0.8 m: 7-10 mm beyond their
#: plane); the paper's desk at 0.5 m fills only the middle of the image, so its bend is
#: taken larger, to put a few percent of it beyond the band.
CORNER_BEND = 20 * MM


def _bent_desk(shapes: list) -> tuple[np.ndarray, np.ndarray]:
    """Render the desk and ``shapes``, every ray lengthened by CORNER_BEND * rho^2.

    rho is the pixel's distance from the image centre over the desk's farthest; Kinect-class noise
    (:data:`KINECT_NOISE`) on top. Returns the organized cloud and ground truth (desk 0).
    """
    cam = SEGMENTATION_CAMERA
    organized, gt = cam.render([_desk(), *shapes], ids=list(range(len(shapes) + 1)))
    v, u = np.mgrid[0:cam.height, 0:cam.width]
    rho2 = np.square(u - cam.cx) + np.square(v - cam.cy)
    rho2 = rho2 / rho2[gt == 0].max()
    rng_ = np.linalg.norm(organized, axis=2, keepdims=True)
    organized = organized * (1.0 + CORNER_BEND * rho2[..., None] / rng_)
    return apply_noise(organized, gt, KINECT_NOISE, rng=0)


def _desk_beyond_band(organized: np.ndarray, gt: np.ndarray, band: float) -> float:
    """Share of the desk's points farther than ``band`` [m] from the desk's best plane."""
    desk = organized.reshape(-1, 3)[gt.ravel() == 0]
    desk = desk[np.isfinite(desk).all(axis=1)]
    plane = fit_plane_svd(desk)
    return float(np.mean(np.abs(desk @ plane.normal + plane.d) > band))


def test_a_bent_desk_is_one_support_and_no_object():
    organized, gt = _bent_desk([])
    params = ModelingParams()
    # The scene is what the test is for: part of the desk lies beyond the support band
    # (at least the configured 4 mm) of its best plane.
    assert _desk_beyond_band(organized, gt, params.seg_plane_threshold) > 0.02
    seg = segment_scene(organized, params)
    labels = seg.labels
    desk = gt.ravel() == 0
    labelled = desk & (labels >= 0)
    in_support = np.isin(labels, seg.support_ids)
    assert in_support[labelled].mean() >= 0.99
    others = [i for i in seg.object_ids if i not in seg.support_ids]
    assert others == []


def test_a_low_box_on_the_bent_desk_stays_an_object():
    # A box lying flat in the bent corner: its top is 20 mm (five bands) off the desk, so
    # it is no continuation of the desk, whatever the bend.
    box = _rest_on_desk(Box(*(np.array([90, 70, 20]) * MM), **_standing(140, 130, 20)))
    organized, gt = _bent_desk([box])
    seg = segment_scene(organized, ModelingParams())
    labels = seg.labels
    own = (gt.ravel() == 1) & (labels >= 0)
    assert own.sum() > 500
    main = np.bincount(labels[own]).argmax()
    assert main not in seg.support_ids
    seg_pts = labels == main
    iou = (seg_pts & (gt.ravel() == 1)).sum() / (seg_pts | (gt.ravel() == 1)).sum()
    assert iou >= 0.8


# --- What the contact rims leave of an object ------------------------------------------------

def test_objects_left_smaller_than_a_cluster_are_noise():
    from geomodel_ros.core.segmentation import _drop_small_objects

    # Supports 0, 1; objects 2 (5 points), 3 (2 points), 5 (3 points); minimum 3.
    labels = np.array([0, 0, 1, 2, 2, 2, 2, 2, 3, 3, -1, 5, 5, 5, 1])
    _drop_small_objects(labels, 2, 3)
    assert labels.tolist() == [0, 0, 1, 2, 2, 2, 2, 2, -1, -1, -1, 5, 5, 5, 1]
    # A support is never dropped, however small.
    labels = np.array([0, 1, 2, 2, 2])
    _drop_small_objects(labels, 2, 3)
    assert labels.tolist() == [0, 1, 2, 2, 2]


@pytest.mark.parametrize("seed", [5, 18])
def test_no_segment_reported_below_the_cluster_size(seed):
    # kinect-real clutter scenes in which the desk's contact rims left desk pieces of 71
    # and 105 points, reported as planes.
    from geomodel_ros.tools.synth.clutter import render_clutter
    from geomodel_ros.tools.synth.scenes import KINECT_REAL_NOISE

    scene = render_clutter(seed, KINECT_REAL_NOISE)
    params = ModelingParams()
    seg = segment_scene(scene.organized, params)
    objects = [i for i in seg.object_ids if i not in seg.support_ids]
    sizes = np.bincount(seg.labels[seg.labels >= 0])
    assert objects and all(sizes[i] >= params.seg_min_cluster_points for i in objects)
