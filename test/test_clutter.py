"""Cluttered tabletop scenes: the generator's geometry and the segmentation in clutter.

The generator (:mod:`geomodel_ros.tools.synth.clutter`) is checked against facts derived
from the shapes' own definitions: every labelled point lies on its object's surface, every
object rests on the desk or on its base, no two objects overlap (a separating plane found
from the analytic support functions), the same seed gives the same scene. The segmentation
is checked on hand-built layouts of the failures seen on real clutter (cans apart on a bare
table, a can lying against a tin, touching objects whose tops differ by a few millimetres)
and on what must still be joined (a cup's inner and outer wall, a box split by a nearer
pole); under the correlated noise of real frames, single objects stay whole and a sphere
against a box stays apart, while two contacts that one smooth patch grows across (a can
beside a cup, a can top 2.5 mm above a box top) are known limits.
"""

from __future__ import annotations

import functools

import numpy as np
import pytest
from scipy.optimize import minimize_scalar

from geomodel_ros.core.params import ModelingParams, load_params_file
from geomodel_ros.core.segmentation import segment_scene
from geomodel_ros.tools.evaluation import segmentation_scores
from geomodel_ros.tools.paths import CONFIG_DIR
from geomodel_ros.tools.synth import NoiseModel
from geomodel_ros.tools.synth.clutter import (KIND_BUILDERS, KINECT_CAMERA, KINECT_NOISE,
                                              OpenFrustum, Placeable, camera_pose,
                                              clutter_layout, footprints_overlap, make_box,
                                              make_can, make_container, make_lying_can,
                                              make_sphere, render_clutter, render_layout,
                                              stack_on)
from geomodel_ros.tools.synth.camera import PinholeCamera
from geomodel_ros.tools.synth.scenes import KINECT_REAL_NOISE

SEEDS = range(6)
UP = np.array([0.0, 0.0, 1.0])
#: Contact tolerance of the generator's placement [m] (touching objects are at most this
#: far apart and never overlap by more than rounding).
CONTACT = 1e-6


@functools.lru_cache(maxsize=None)
def _scene(seed: int, noisy: bool = False):
    return render_clutter(seed, KINECT_NOISE if noisy else None)


# --------------------------------------------------------------------------------------
# The generator
# --------------------------------------------------------------------------------------

def test_the_same_seed_gives_the_same_scene_and_another_seed_another():
    a, b = render_clutter(3, KINECT_NOISE), render_clutter(3, KINECT_NOISE)
    assert np.array_equal(a.organized, b.organized, equal_nan=True)
    assert np.array_equal(a.label_image, b.label_image)
    assert a.kinds == b.kinds and a.bases == b.bases
    c = render_clutter(4, KINECT_NOISE)
    assert a.kinds != c.kinds or not np.array_equal(a.label_image, c.label_image)


def test_noise_free_and_noisy_scenes_share_the_layout():
    clean, noisy = _scene(1), _scene(1, True)
    assert clean.kinds == noisy.kinds
    moved = np.isfinite(noisy.organized).all(axis=2)
    # Kinect noise moves points along their rays: same directions, different depths.
    p, q = clean.organized[moved], noisy.organized[moved]
    cos = np.einsum("ij,ij->i", p, q) / np.linalg.norm(p, axis=1) / np.linalg.norm(q, axis=1)
    assert np.all(cos > 1 - 1e-12)
    assert np.abs(np.linalg.norm(p, axis=1) - np.linalg.norm(q, axis=1)).max() > 1e-3
    assert 0.97 < moved.sum() / clean.valid_mask.sum() < 0.99  # 2 % dropout


@pytest.mark.parametrize("seed", SEEDS)
def test_scene_holds_8_to_16_objects_of_the_known_kinds(seed):
    scene = _scene(seed)
    assert scene.kinds[0] == "desk"
    assert 8 <= len(scene.kinds) - 1 <= 16
    assert set(scene.kinds[1:]) <= set(KIND_BUILDERS)
    assert [o.id for o in scene.objects] == list(range(len(scene.kinds)))
    assert scene.label_image.max() <= len(scene.kinds) - 1
    assert scene.organized.shape == (KINECT_CAMERA.height, KINECT_CAMERA.width, 3)


@pytest.mark.parametrize("seed", SEEDS)
def test_every_labelled_point_lies_on_its_objects_surface(seed):
    scene = _scene(seed)
    pts = scene.organized.reshape(-1, 3)
    lab = scene.label_image.ravel()
    finite = np.isfinite(pts).all(axis=1)
    assert np.array_equal(finite, lab >= 0)  # a label exactly where a point is
    for i, shape in enumerate(scene.shapes):
        mine = lab == i
        if mine.any():
            assert shape.surface_distance(pts[mine]).max() < 1e-9, (seed, i, scene.kinds[i])
    # The desk is the plane through its centre with the desk normal.
    desk = pts[lab == 0]
    assert np.abs((desk - scene.shapes[0].center) @ scene.desk_normal).max() < 1e-9


def _lowest(shape, up) -> float:
    return -shape.support(-up)


@pytest.mark.parametrize("seed", range(20))
def test_objects_rest_on_the_desk_or_exactly_on_their_box(seed):
    items, bases, _ = clutter_layout(seed)
    for it, base in zip(items, bases):
        if base == 0:
            assert abs(_lowest(it.shape, UP)) < 1e-12, it.kind
        else:
            below = items[base - 1]
            assert below.kind == "box"
            assert abs(_lowest(it.shape, UP) - below.shape.support(UP)) < 1e-12
            # It stands on the top face: its footprint's corners or disc inside the top.
            fp, top = it.footprint, below.footprint
            pts = fp.corners() if fp.half is not None else fp.center[None, :]
            margin = 0.0 if fp.half is not None else fp.radius
            local = np.abs((pts - top.center) @ top.axes().T)
            assert np.all(local <= top.half - margin + 1e-12)


def _separation(a, b) -> float:
    """Largest gap [m] between two convex shapes over all separating directions.

    gap(u) = min over b of p . u - max over a of p . u, from the analytic support
    functions; positive when a plane with normal u lies between them. Horizontal
    directions (where shapes standing side by side separate) are scanned at 1 degree
    and the best refined; the vertical (a shape on top of another) is tried as well.
    """
    def gap(theta: float) -> float:
        u = np.array([np.cos(theta), np.sin(theta), 0.0])
        return -b.support(-u) - a.support(u)

    thetas = np.radians(np.arange(0.0, 360.0, 1.0))
    best = thetas[int(np.argmax([gap(t) for t in thetas]))]
    step = np.radians(1.0)
    res = minimize_scalar(lambda t: -gap(t), bounds=(best - step, best + step),
                          method="bounded", options={"xatol": 1e-12})
    vertical = max(-b.support(-UP) - a.support(UP), -a.support(-UP) - b.support(UP))
    return max(-res.fun, gap(best), vertical)


@functools.lru_cache(maxsize=None)
def _pair_gaps(seed: int) -> dict[tuple[int, int], float]:
    """Separation of every pair of objects (ids from 1) of clutter scene ``seed``."""
    items, _, _ = clutter_layout(seed)
    return {(x + 1, y + 1): _separation(items[x].shape, items[y].shape)
            for x in range(len(items)) for y in range(x + 1, len(items))}


@pytest.mark.parametrize("seed", SEEDS)
def test_no_two_objects_overlap(seed):
    gaps = _pair_gaps(seed)
    kinds = _scene(seed).kinds
    for (x, y), g in gaps.items():
        assert g >= -CONTACT, (seed, x, y, kinds[x], kinds[y], g)


def test_scenes_hold_touching_stacked_and_cut_off_objects():
    stacked = sum(b > 0 for seed in SEEDS for b in clutter_layout(seed)[1])
    touching = sum(g < 2 * CONTACT for seed in SEEDS for g in _pair_gaps(seed).values())
    cut = 0
    for seed in SEEDS:
        img = _scene(seed).label_image
        border = np.concatenate([img[0], img[-1], img[:, 0], img[:, -1]])
        cut += len(set(border[border > 0].tolist()))
    assert stacked >= 2 and touching >= 10 and cut >= 3, (stacked, touching, cut)


def test_separation_is_negative_for_overlapping_shapes():
    # Two cans of radius 30 mm whose centres are 50 mm apart overlap by 10 mm; 70 mm
    # apart they are 10 mm apart; a can on a box's top touches it from above.
    a, b = make_can(0.03, 0.1).shape, make_can(0.03, 0.1)
    assert _separation(a, b.at(np.array([0.05, 0.0])).shape) == pytest.approx(-0.01, abs=1e-9)
    assert _separation(a, b.at(np.array([0.0, 0.07])).shape) == pytest.approx(0.01, abs=1e-9)
    box = make_box(0.1, 0.1, 0.05)
    assert _separation(box.shape, stack_on(b, box).shape) == pytest.approx(0.0, abs=1e-12)


def test_footprints_touch_without_overlapping():
    can = make_can(0.03, 0.1).footprint
    box = make_box(0.1, 0.06, 0.05, yaw=0.3).footprint
    assert not footprints_overlap(can.moved([0.0, 0.0]), can.moved([0.06, 0.0]))
    assert footprints_overlap(can.moved([0.0, 0.0]), can.moved([0.0599, 0.0]))
    # A circle against the middle of the box's long side: centre 0.03 + 0.03 away.
    normal = np.array([-np.sin(0.3), np.cos(0.3)])
    assert not footprints_overlap(box, can.moved(0.06 * normal))
    assert footprints_overlap(box, can.moved(0.0599 * normal))
    # Two boxes turned against each other overlap only when a corner reaches in.
    other = make_box(0.1, 0.06, 0.05, yaw=0.3 + np.pi / 2).footprint
    assert footprints_overlap(box, other.moved([0.0, 0.0]))
    assert not footprints_overlap(box, other.moved(0.0801 * normal))


def test_a_container_shows_its_floor_inner_wall_and_rim():
    # A cup of outer radius 40 mm at the bottom, 50 mm at the rim, 100 mm high, 4 mm wall,
    # 8 mm floor, centred 0.5 m ahead of the camera on its axis; rays parallel to the axis.
    origin, ahead = np.zeros(3), np.array([[0.0, 0.0, 1.0]])
    cup = OpenFrustum(0.04, 0.05, 0.1, wall=0.004, floor=0.008, center=[0.0, 0.0, 0.5])
    # Bottom towards the camera (at 0.45 m): the axis ray meets the outside of the bottom.
    assert cup.intersect(origin, ahead)[0] == pytest.approx(0.45, abs=1e-12)
    turned = OpenFrustum(0.04, 0.05, 0.1, wall=0.004, floor=0.008, center=[0.0, 0.0, 0.5],
                         rotation=np.diag([1.0, -1.0, -1.0]))
    # Rim towards the camera (at 0.45 m): the axis ray passes the opening and meets the
    # floor, 8 mm above the bottom at 0.55 m.
    assert turned.intersect(origin, ahead)[0] == pytest.approx(0.542, abs=1e-12)
    # At 45 mm from the axis the ray passes the opening (inner rim radius 46 mm) and meets
    # the inner wall, whose radius shrinks by 1 mm per 10 mm of depth: 10 mm in.
    side = np.array([[0.045, 0.0, 0.0]])
    t = turned.intersect(side, ahead)[0]
    assert t == pytest.approx(0.46, abs=1e-9)
    assert turned.surface_distance(side + t * ahead)[0] < 1e-9
    # At 48 mm it meets the rim annulus (46 to 50 mm) in the rim plane.
    assert turned.intersect(np.array([[0.048, 0.0, 0.0]]), ahead)[0] == \
        pytest.approx(0.45, abs=1e-12)
    # At 52 mm it misses the rim and meets the outer wall where its radius is 52 mm...
    # which it never is (at most 50 mm): a miss.
    assert np.isinf(turned.intersect(np.array([[0.052, 0.0, 0.0]]), ahead)[0])


# --------------------------------------------------------------------------------------
# Segmentation of hand-built layouts
# --------------------------------------------------------------------------------------

#: Kinect-class noise as in the benchmark, with the parameters for it.
NOISY = pytest.param(True, id="kinect-noise")
CLEAN = pytest.param(False, id="noise-free")


def _segment(items: list[Placeable], bases: list[int], pose, noisy: bool):
    scene = render_layout(items, bases, pose, noise=KINECT_NOISE if noisy else None, rng=7)
    params = load_params_file(CONFIG_DIR / "kinect.yaml") if noisy else ModelingParams()
    seg = segment_scene(scene.organized, params)
    gt = scene.label_image.ravel()
    ids = list(range(1, len(items) + 1))
    scores = {s.gt_id: s for s in segmentation_scores(seg.labels, gt, ids)}
    report = {g: (round(s.iou, 3), s.under, s.over) for g, s in scores.items()}
    return scene, seg, scores, report


def _assert_each_object_its_own_segment(scores, report):
    for s in scores.values():
        assert s.iou >= 0.8 and not s.under, report


def _at(obj: Placeable, x: float, y: float) -> Placeable:
    return obj.at(np.array([x, y]))


#: Camera of the layouts: 0.8 m from the desk centre, 45 degrees above it, from the -y side.
FRONT = camera_pose(0.8, np.radians(45.0), -np.pi / 2)


@pytest.mark.parametrize("noisy", [CLEAN, NOISY])
@pytest.mark.parametrize("spacing", [0.10, 0.20, 0.30])
def test_cans_apart_on_a_bare_table_are_one_segment_each(spacing, noisy):
    # Three tins side by side with bare table between them (centre spacing minus the
    # radii: 2-22 cm of table), as on the real table where two came out as one segment.
    items = [_at(make_can(0.04, 0.11), x, 0.0) for x in (-spacing, 0.0, spacing)]
    scene, _, scores, report = _segment(items, [0, 0, 0], FRONT, noisy)
    gap = spacing - 0.08
    assert gap > 0.019  # table really lies between them
    assert np.bincount(scene.labels, minlength=4)[1:].min() > 2000
    _assert_each_object_its_own_segment(scores, report)


@pytest.mark.parametrize("noisy", [CLEAN, NOISY])
def test_a_can_lying_against_a_standing_tin_stays_apart(noisy):
    tin = _at(make_can(0.05, 0.09), 0.0, 0.0)
    # Lying can, axis along x, its side touching the tin's side: centres 0.05 + 0.03 apart
    # along y (the can's footprint rectangle 0.03 wide on either side of its axis).
    can = _at(make_lying_can(0.03, 0.12, yaw=0.0), 0.0, -0.08)
    assert not footprints_overlap(tin.footprint, can.footprint)
    _, _, scores, report = _segment([tin, can], [0, 0], camera_pose(
        0.7, np.radians(40.0), -np.pi / 2 + 0.4), noisy)
    _assert_each_object_its_own_segment(scores, report)


#: Steps the segmentation does not see: 3 mm is below its 4 mm working voxel (the step's
#: side is no face of its own). Measured IoU (both objects) 0.49-0.51, under-segmented.
#: (At 12 mm, noise-free, the upper box's side above the lower top joins the lower top's
#: patch, whose border to the upper top then votes 17 convex of 34: a tie, which no longer
#: joins the two groups, :func:`geomodel_ros.core.joins.merge_patches`.)
_STEP_LIMIT = pytest.mark.xfail(strict=True, reason="step not seen (see _STEP_LIMIT)")


@pytest.mark.parametrize("noisy, step_mm", [
    pytest.param(False, 3.0, marks=_STEP_LIMIT, id="3mm-noise-free"),
    pytest.param(False, 5.0, id="5mm-noise-free"),
    pytest.param(True, 5.0, id="5mm-kinect-noise"),
    pytest.param(False, 8.0, id="8mm-noise-free"),
    pytest.param(True, 8.0, id="8mm-kinect-noise"),
    pytest.param(False, 12.0, id="12mm-noise-free"),
    pytest.param(True, 12.0, id="12mm-kinect-noise"),
])
def test_touching_boxes_whose_tops_differ_by_a_step_stay_apart(step_mm, noisy):
    # Two boxes face to face (the first's +x face on the second's -x face); their tops
    # are parallel, step_mm apart in height: the faces meet at a concave crease and the
    # tops at a step.
    a = _at(make_box(0.08, 0.07, 0.08), -0.04, 0.0)
    b = _at(make_box(0.08, 0.07, 0.08 + step_mm * 1e-3), 0.04, 0.01)
    assert not footprints_overlap(a.footprint, b.footprint)
    _, _, scores, report = _segment([a, b], [0, 0], FRONT, noisy)
    _assert_each_object_its_own_segment(scores, report)


@pytest.mark.parametrize("noisy", [CLEAN, NOISY])
def test_a_can_against_a_box_of_nearly_its_height_stays_apart(noisy):
    # The can's top is 6 mm above the box's, their sides touch along a line: the two
    # tops look like one plane with a step (one segment before steps were told apart).
    box = _at(make_box(0.1, 0.08, 0.1), 0.0, 0.0)
    can = _at(make_can(0.035, 0.106), 0.05 + 0.035, 0.0)
    assert not footprints_overlap(box.footprint, can.footprint)
    _, _, scores, report = _segment([box, can], [0, 0], FRONT, noisy)
    _assert_each_object_its_own_segment(scores, report)


@pytest.mark.parametrize("noisy", [CLEAN, NOISY])
def test_a_can_standing_on_a_box_stays_apart_from_it(noisy):
    box = _at(make_box(0.14, 0.12, 0.06, yaw=0.2), 0.0, 0.0)
    can = stack_on(make_can(0.03, 0.09), box)
    _, _, scores, report = _segment([box, can], [0, 1], FRONT, noisy)
    _assert_each_object_its_own_segment(scores, report)


@pytest.mark.parametrize("noisy", [CLEAN, NOISY])
def test_a_cups_inner_and_outer_wall_are_one_segment(noisy):
    # Seen from 55 degrees above, the cup shows its outer front wall, its rim and its
    # inner back wall; they meet only over the hidden back rim.
    cup = _at(make_container(0.04, 0.05, 0.1), 0.0, 0.0)
    scene, seg, scores, report = _segment([cup], [0], camera_pose(
        0.7, np.radians(55.0), -np.pi / 2), noisy)
    assert scores[1].iou >= 0.8 and not scores[1].over, report
    # Both walls are in view: points of the cup with normals facing away from its axis
    # (outer) and towards it (inner back wall), i.e. the scene is what it says.
    pts = scene.organized[scene.label_image == 1]
    axis_point = scene.shapes[1].center
    radial = pts - axis_point - np.outer((pts - axis_point) @ scene.desk_normal,
                                         scene.desk_normal)
    assert (np.linalg.norm(radial, axis=1) < 0.04).mean() > 0.1  # inner wall and floor


@pytest.mark.parametrize("noisy", [CLEAN, NOISY])
def test_a_box_split_by_a_nearer_pole_is_one_segment(noisy):
    # A wide box behind a thin pole standing 15 cm in front of it: the pole cuts the box
    # into two visible parts; no table is seen between the parts (the pole hides it).
    wide = _at(make_box(0.24, 0.06, 0.12), 0.0, 0.10)
    pole = _at(make_box(0.025, 0.025, 0.25), 0.0, -0.05)
    scene, _, scores, report = _segment([wide, pole], [0, 0], FRONT, noisy)
    # The pole really splits the box's image into two parts.
    from scipy import ndimage
    _, parts = ndimage.label(scene.label_image == 1)
    assert parts == 2
    assert scores[1].iou >= 0.8 and not scores[1].over, report
    assert not scores[2].under, report


# --------------------------------------------------------------------------------------
# Hand-built layouts under the correlated noise of real frames (KINECT_REAL_NOISE)
# --------------------------------------------------------------------------------------

#: Noise seeds of the layouts under ``KINECT_REAL_NOISE`` (each draws its own correlated
#: error field, dropout and holes).
REAL_NOISE_SEEDS = (0, 2)


def _segment_real(items: list[Placeable], rng: int):
    """Segment a layout on the desk under KINECT_REAL_NOISE with the defaults.

    The defaults' tolerances follow the frame's measured noise, as in the benchmark's
    kinect-real row.
    """
    scene = render_layout(items, [0] * len(items), FRONT, noise=KINECT_REAL_NOISE, rng=rng)
    seg = segment_scene(scene.organized, ModelingParams())
    ids = list(range(1, len(items) + 1))
    scores = {s.gt_id: s for s in segmentation_scores(seg.labels, scene.label_image.ravel(), ids)}
    report = {g: (round(s.iou, 3), s.under, s.over) for g, s in scores.items()}
    return scores, report


@pytest.mark.parametrize("rng", REAL_NOISE_SEEDS)
@pytest.mark.parametrize("kind", ["sphere", "box", "can"])
def test_one_object_under_real_noise_stays_whole(kind, rng):
    # One object alone on the desk: one segment holds it (IoU >= 0.8), no second segment
    # holds a fifth of it. Measured IoU 0.96-1.00 over noise seeds 0-5.
    obj = {"sphere": make_sphere(0.043), "box": make_box(0.10, 0.075, 0.054),
           "can": make_can(0.04, 0.10)}[kind]
    scores, report = _segment_real([_at(obj, 0.0, 0.0)], rng)
    assert scores[1].iou >= 0.8 and not scores[1].over, report


@pytest.mark.parametrize("rng", REAL_NOISE_SEEDS)
def test_a_sphere_against_a_box_under_real_noise_stays_apart(rng):
    # The sphere (r 43 mm) touches the box's +x face at 43 mm height, below the box's top
    # (54 mm): a concave contact seen from the front. Measured IoU 0.96-1.00 over noise
    # seeds 0-5 (the clutter benchmark's scene 5 joined such a pair through a strip of edge
    # points given to the box's face).
    box = _at(make_box(0.10, 0.075, 0.054), 0.0, 0.0)
    ball = _at(make_sphere(0.043), 0.05 + 0.043, 0.0)
    assert not footprints_overlap(box.footprint, ball.footprint)
    scores, report = _segment_real([box, ball], rng)
    _assert_each_object_its_own_segment(scores, report)


#: Contacts that one smooth patch grows across under the correlated noise (traced on the
#: clutter benchmark's kinect-real row, scenes 3, 10 and 18): the links between the two
#: objects fold or step by less than the noise of one link, so a patch of both forms
#: before any border is judged, and the border tests (:func:`_creased_borders`, the
#: votes) never see the contact. Tightening the per-link step to the noise that
#: neighbours do not share does not part them either (measured: same IoU on every seed).
#: Measured IoU of the two objects 0.30-0.58, under-segmented, on noise seeds 0-5 (the
#: tops: 5 of 6).
_SMOOTH_CONTACT = pytest.mark.xfail(strict=True, reason="one patch across the contact "
                                    "(see _SMOOTH_CONTACT)")


@pytest.mark.parametrize("rng", [pytest.param(0, marks=_SMOOTH_CONTACT),
                                 pytest.param(2, marks=_SMOOTH_CONTACT), 4])
def test_a_can_beside_a_cup_under_real_noise_stays_apart(rng):
    # The can (r 28 mm) touches the cup's rim circle (r 46 mm); both round fronts face the
    # camera and meet at a tangential concave contact. On noise seed 4 they are apart since
    # the container join parts from a container's inside what touches its rim from outside
    # (:func:`geomodel_ros.core.joins._part_at_rims`); on seeds 0 and 2 they are one
    # segment. Seed 2 was apart while the edge test's bound never exceeded the modelled
    # noise; this frame's neighbourhoods show 1.18 times it, and with the bound on what
    # they show the pair is one patch (seeds 0-5: apart on 2 and 4 before, on 4 after;
    # over the clutter benchmark's 60 kinect-real scenes cans and cups both gained,
    # BENCHMARKS.md section 29).
    cup = _at(make_container(0.036, 0.046, 0.065), 0.0, 0.0)
    can = _at(make_can(0.028, 0.091), 0.046 + 0.028, 0.0)
    assert not footprints_overlap(cup.footprint, can.footprint)
    scores, report = _segment_real([cup, can], rng)
    _assert_each_object_its_own_segment(scores, report)


@_SMOOTH_CONTACT
@pytest.mark.parametrize("rng", REAL_NOISE_SEEDS)
def test_a_can_whose_top_is_2_5mm_above_a_touching_box_top_stays_apart(rng):
    # Two parallel tops 2.5 mm apart in height (scenes 3 and 10: 119 / 121.5 mm and
    # 91.5 / 94.1 mm), side by side: a step below the noise of one link (3.3 mm there).
    box = _at(make_box(0.10, 0.08, 0.10), 0.0, 0.0)
    can = _at(make_can(0.04, 0.1025), 0.05 + 0.04, 0.0)
    assert not footprints_overlap(box.footprint, can.footprint)
    scores, report = _segment_real([box, can], rng)
    _assert_each_object_its_own_segment(scores, report)


@pytest.mark.parametrize("seed, gt_id", [(29, 13), (41, 4)])
def test_a_box_in_clutter_under_real_noise_is_not_cut_at_a_fold_within_a_face(seed, gt_id):
    # Benchmark frames (kinect-real row) where a box was cut in two: one of its faces split
    # into patches whose normals differ by less than the 11.5 deg face angle (8.9 and 7.3
    # deg between the patches' means), their border's median fold -0.40 / -0.56 mm under
    # the frame's slowly varying error, and the border called a crease
    # (:func:`_creased_borders`), which no join may cross; measured IoU 0.77 / 0.68
    # before. A crease needs the surfaces to turn at least the face angle.
    scene = render_clutter(seed, KINECT_REAL_NOISE)
    seg = segment_scene(scene.organized, ModelingParams())
    score, = segmentation_scores(seg.labels, scene.label_image.ravel(), [gt_id])
    assert score.iou >= 0.8 and not score.over and not score.under, \
        (round(score.iou, 3), score.over, score.under)


@pytest.mark.parametrize("seed, noise, gt_ids", [(47, None, (3, 6)),
                                                 (121, KINECT_REAL_NOISE, (4, 7))])
def test_a_piece_beside_a_can_is_not_joined_to_it_across_an_occluder(seed, noise, gt_ids):
    # Benchmark frames where the occlusion join took a piece of another object 105 / 148 mm
    # beside a can (noise-free seed 47: a cup's piece, IoU 0.10, the can 0.89; kinect-real
    # seed 121: a box's piece): the can's cylinder verified on the two together while none
    # of the piece's points lie within its band. Both objects keep their own segments.
    scene = render_clutter(seed, noise)
    seg = segment_scene(scene.organized, ModelingParams())
    scores = {s.gt_id: s for s in segmentation_scores(seg.labels, scene.label_image.ravel(),
                                                       list(gt_ids))}
    report = {g: (round(s.iou, 3), s.under, s.over) for g, s in scores.items()}
    assert not any(s.under for s in scores.values()), report
    assert scores[gt_ids[0]].segment != scores[gt_ids[1]].segment, report


def test_a_box_and_a_cup_at_a_crease_stay_apart_although_their_patches_face_alike():
    # Clutter scene 1 at 1280 x 720 (Kinect-class noise): the cup (id 10) meets the box
    # (id 9) at a crease whose two patches' mean normals differ by less than the face
    # angle (the cup's patch is curved: its mean is not its normal at the border), while
    # near the border they turn by more. Judged by the patches' means alone the crease
    # went and the two were one segment (IoU 0.64 / 0.36); they are apart (0.99 / 1.00).
    camera = PinholeCamera(fx=1050.0, fy=1050.0, cx=639.5, cy=359.5, width=1280, height=720)
    scene = render_clutter(1, KINECT_NOISE, camera)
    seg = segment_scene(scene.organized, ModelingParams())
    scores = {s.gt_id: s for s in segmentation_scores(seg.labels, scene.label_image.ravel(),
                                                       [9, 10])}
    report = {g: (round(s.iou, 3), s.under, s.over) for g, s in scores.items()}
    _assert_each_object_its_own_segment(scores, report)


# --------------------------------------------------------------------------------------
# The clutter benchmark as a regression floor
# --------------------------------------------------------------------------------------

# Measured on seeds 0-5 (noise-free, defaults, 81 objects): 90.1 % with IoU >= 0.8, 9.9 %
# under-segmented (before steps were told apart: 82.7 % and 17.3 %). BENCHMARKS.md
# "Segmentation in clutter" has the 20-scene figures.
def test_clutter_scenes_are_mostly_segmented_one_segment_per_object():
    from geomodel_ros.tools.bench_clutter import GOOD_IOU, clutter_rows

    rows = clutter_rows(SEEDS, False, ModelingParams())
    good = np.mean([r["iou"] >= GOOD_IOU for r in rows])
    under = np.mean([r["under"] for r in rows])
    assert len(rows) >= 60
    assert good >= 0.9 and under <= 0.1, (good, under)


def test_noise_model_of_the_benchmark_is_kinect_class():
    # 2 mm at 1 m, growing with the square of the depth.
    assert isinstance(KINECT_NOISE, NoiseModel)
    assert KINECT_NOISE.sigma_at_0_5m * (1.0 / 0.5) ** 2 == pytest.approx(0.002)


def test_desk_pieces_counts_segments_mostly_desk():
    from geomodel_ros.tools.bench_clutter import desk_pieces

    # Segments: 0 support (all desk), 1 an object, 2 a desk piece (3 of 4 desk), 3 half
    # desk (not mostly), 4 points with no ground truth only (not counted).
    labels = np.array([0, 0, 0, 1, 1, 2, 2, 2, 2, 3, 3, -1, 4, 4])
    gt = np.array([0, 0, 0, 5, 5, 0, 0, 0, 6, 0, 7, 0, -1, -1])
    assert desk_pieces(labels, gt, [0]) == 1
    assert desk_pieces(labels, gt, []) == 2  # the support counts when not named one
    assert desk_pieces(np.full(4, -1), np.zeros(4, dtype=int), []) == 0


def test_elevation_range_moves_only_the_camera():
    # The same seed seen from lower: the same objects at the same places, the camera drawn
    # at an elevation within the range asked for (the angle of its position above the
    # desk, seen from its aim point, which lies on the desk in front of it).
    low = (np.radians(15.0), np.radians(25.0))
    for seed in range(5):
        items, bases, pose = clutter_layout(seed)
        items_low, bases_low, pose_low = clutter_layout(seed, low)
        assert bases_low == bases
        for a, b in zip(items, items_low):
            assert a.kind == b.kind
            assert np.array_equal(a.shape.center, b.shape.center)
        rotation, position = pose_low
        forward = rotation[2]  # the optical z axis in desk coordinates
        aim = position + forward * (-position[2] / forward[2])  # where it meets the desk
        elevation = np.arcsin(position[2] / np.linalg.norm(position - aim))
        assert low[0] - 1e-9 <= elevation <= low[1] + 1e-9
        # Distance to the aim point and azimuth are the default draw's.
        _, default_position = pose
        default_aim = default_position + pose[0][2] * (-default_position[2] / pose[0][2][2])
        assert np.linalg.norm(position - aim) == pytest.approx(
            np.linalg.norm(default_position - default_aim))
        assert aim == pytest.approx(default_aim)
