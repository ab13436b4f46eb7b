"""Mixed pixels at depth edges: the rendered degradation and the opt-in filter.

Modules: core.mixed_pixels (mixed_pixels, mixed_rows), core.segmentation
(``mixed_pixel_filter``), tools.synth.scenes (``NoiseModel.mixed_edges``,
``mixed_pixel_share``).

The range images below are built by hand: a near surface at 1.0 m beside a far one at
1.5 m (a 50 cm jump), so every expectation follows from the definitions (a run of one or
two pixels strictly between the sides by more than a quarter of the jump, flat sides).
"""

from __future__ import annotations

import numpy as np
import pytest

from geomodel_ros.core.mixed_pixels import MAX_RUN, SIDE_SHARE, mixed_pixels
from geomodel_ros.core.params import ModelingParams
from geomodel_ros.core.segmentation import segment_scene
from geomodel_ros.tools.synth.clutter import render_clutter
from geomodel_ros.tools.synth.scenes import (MIXED_EDGE_MIN_JUMP, NoiseModel, apply_noise,
                                             mixed_pixel_share)

NEAR, FAR = 1.0, 1.5
JUMP = np.full((8, 12), 0.02)


def edge_image(middle=()):
    """8 x 12 ranges: columns 0-5 near, 6-11 far; ``middle`` replaces columns from 6 on."""
    r = np.full((8, 12), FAR)
    r[:, :6] = NEAR
    for k, value in enumerate(middle):
        r[:, 6 + k] = value
    return r


def test_one_and_two_pixel_runs_between_the_surfaces_are_mixed():
    r = edge_image()
    r[1, 6] = 1.25                      # one pixel half way
    r[3, 6], r[3, 7] = 1.2, 1.35        # two pixels between
    r[5, 6] = 1.0 + 0.5 * SIDE_SHARE + 0.01  # just past a quarter of the jump
    mixed, runs, edges = mixed_pixels(r, JUMP)
    expected = np.zeros(r.shape, dtype=bool)
    expected[1, 6] = expected[3, 6] = expected[3, 7] = expected[5, 6] = True
    np.testing.assert_array_equal(mixed, expected)
    assert runs == 3  # rows 1 and 5 (one-pixel runs), row 3 (one two-pixel run) ... and
    assert edges > runs  # ... the clean edges of the other rows count as edges only


def test_a_clean_silhouette_and_a_pixel_near_one_side_are_not_mixed():
    r = edge_image()
    r[2, 6] = 1.0 + 0.5 * SIDE_SHARE - 0.01  # within a quarter of the jump of the near side
    r[4, 6] = FAR - 0.05
    mixed, runs, _ = mixed_pixels(r, JUMP)
    assert not mixed.any() and runs == 0


def test_a_steep_surface_and_a_small_step_are_not_mixed():
    # A surface seen at a grazing angle: the range grows 3 cm per pixel, steadily.
    steep = np.tile(1.0 + 0.03 * np.arange(12), (8, 1))
    assert not mixed_pixels(steep, JUMP)[0].any()
    # Two surfaces 1 cm apart with a pixel between: below the 2 cm jump.
    small = edge_image((1.005,))
    small[:, 7:] = 1.01
    assert not mixed_pixels(small, JUMP)[0].any()


def test_a_run_longer_than_two_pixels_is_a_surface():
    r = edge_image([1.2, 1.25, 1.3][:MAX_RUN + 1])
    assert not mixed_pixels(r, JUMP)[0].any()


def test_no_return_on_either_side_decides_nothing():
    r = edge_image((1.25,))
    r[:, 5] = np.nan
    assert not mixed_pixels(r, JUMP)[0].any()


# ------------------------------------------------------------------ the rendered degradation
def test_rendered_mixed_pixels_lie_between_the_two_surfaces_of_an_edge():
    scene = render_clutter(3)
    pts, lab = apply_noise(scene.organized, scene.label_image, NoiseModel(mixed_edges=1.0), 0)
    changed = np.isfinite(pts).all(axis=2) & (lab < 0)
    assert changed.sum() > 500
    z0, z = scene.organized[..., 2], pts[..., 2]
    # Every changed pixel had a 4-neighbour of another label more than the edge jump away,
    # and its new depth lies between its own and that of some such neighbour (on its ray).
    rows, cols = np.nonzero(changed)
    ok = np.zeros(len(rows), dtype=bool)
    for dr, dc in ((0, 1), (0, -1), (1, 0), (-1, 0)):
        rr, cc = np.clip(rows + dr, 0, 479), np.clip(cols + dc, 0, 639)
        other = scene.label_image[rr, cc] != scene.label_image[rows, cols]
        far = np.abs(z0[rr, cc] - z0[rows, cols]) > MIXED_EDGE_MIN_JUMP
        lo = np.minimum(z0[rr, cc], z0[rows, cols])
        hi = np.maximum(z0[rr, cc], z0[rows, cols])
        ok |= other & far & (z[rows, cols] >= lo) & (z[rows, cols] <= hi)
    assert ok.all()
    before, after = scene.organized[rows, cols], pts[rows, cols]
    np.testing.assert_allclose(after / np.linalg.norm(after, axis=1)[:, None],
                               before / np.linalg.norm(before, axis=1)[:, None], atol=1e-12)
    # Nothing else moved.
    same = ~changed & np.isfinite(pts).all(axis=2)
    np.testing.assert_array_equal(pts[same], scene.organized[same])


def test_the_share_estimator_tells_a_mixing_camera_from_a_clean_one():
    scene = render_clutter(5)
    clean = mixed_pixel_share(scene.organized)
    mixed_cloud, _ = apply_noise(scene.organized, scene.label_image,
                                 NoiseModel(mixed_edges=0.5), 1)
    mixed = mixed_pixel_share(mixed_cloud)
    # Measured on clutter seeds 0-9: without mixing at most 1.9 %, with p = 0.5 at least 8 %.
    assert clean[0] / sum(clean) < 0.02 and mixed[0] / sum(mixed) > 0.05


@pytest.mark.parametrize("share", [-0.1, 1.5, float("nan")])
def test_mixed_edges_outside_zero_to_one_is_refused(share):
    with pytest.raises(ValueError, match="mixed_edges"):
        NoiseModel(mixed_edges=share)


# ------------------------------------------------------------------ the segmentation's filter
def test_the_filter_leaves_the_mixed_pixels_out_and_is_off_by_default():
    scene = render_clutter(2)
    pts, lab = apply_noise(scene.organized, scene.label_image, NoiseModel(mixed_edges=0.5), 2)
    mixed_truth = np.isfinite(pts).all(axis=2) & (lab < 0)
    plain = segment_scene(pts).labels.reshape(lab.shape)
    filtered = segment_scene(pts, ModelingParams(mixed_pixel_filter=True)).labels \
        .reshape(lab.shape)
    # By default mixed pixels are segmented like any other return: some join objects.
    assert (plain[mixed_truth] >= 0).sum() > 100
    # With the filter most are left out, and no object loses more than a rim.
    assert (filtered[mixed_truth] < 0).mean() > 0.7 * (plain[mixed_truth] < 0).mean() + 0.25
    kept = (plain >= 0) & ~mixed_truth
    assert (filtered[kept] >= 0).mean() > 0.97


def test_the_filter_needs_the_image_grid():
    scene = render_clutter(2)
    pts, _ = apply_noise(scene.organized, scene.label_image, NoiseModel(mixed_edges=0.5), 2)
    flat = pts.reshape(-1, 3)
    a = segment_scene(flat).labels
    b = segment_scene(flat, ModelingParams(mixed_pixel_filter=True)).labels
    np.testing.assert_array_equal(a, b)
