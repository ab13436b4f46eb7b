"""A support plane is modeled as one flat face, without a neighbour search.

The segmentation finds a support (desk, floor) as the points in the band of one plane; the
modeling takes such an object's working points as one face when they lie flat
(``cloud.build_flat_face``) instead of estimating normals and growing faces over them.
These tests check that shortcut against the plain path (``cloud.build_faces`` and
``model_object`` without it) and against geometry worked out by hand: a rectangle of known
pose and size seen from the origin.
"""

import math

import numpy as np
import pytest

from geomodel_ros.core.faces import build_working_cloud
from geomodel_ros.core.fitting.cloud import build_faces, build_flat_face
from geomodel_ros.core.modeling import model_object
from geomodel_ros.core.params import ModelingParams
from geomodel_ros.core.primitives import PrimitiveType

#: The rectangle: 400 x 300 mm, centre 0.8 m in front of the sensor, its normal tilted
#: 40 deg from the viewing axis about x (as a desk seen from above), sampled every 2 mm.
CENTER = np.array([0.02, -0.05, 0.8])
TILT = math.radians(40.0)
LENGTH, WIDTH, STEP = 0.4, 0.3, 0.002
#: Depth noise along the normal [m] (well inside the default 2 mm RANSAC threshold).
SIGMA = 0.0003


def _frame():
    """Rectangle axes: u along x, v and the normal n in the y-z plane (n towards the origin)."""
    u = np.array([1.0, 0.0, 0.0])
    n = np.array([0.0, math.sin(TILT), -math.cos(TILT)])
    v = np.cross(n, u)
    return u, v, n


def _rectangle(seed=0, gap=0.0):
    """Points (N, 3) [m] of the rectangle; ``gap`` [m] cuts a strip across its middle."""
    u, v, n = _frame()
    # Samples at the centres of STEP x STEP cells: the edge lies STEP / 2 beyond the last.
    a = np.arange(-LENGTH / 2 + STEP / 2, LENGTH / 2, STEP)
    b = np.arange(-WIDTH / 2 + STEP / 2, WIDTH / 2, STEP)
    aa, bb = (g.ravel() for g in np.meshgrid(a, b))
    keep = np.abs(aa) >= gap / 2 if gap else np.ones(aa.size, dtype=bool)
    aa, bb = aa[keep], bb[keep]
    h = np.random.default_rng(seed).normal(0.0, SIGMA, aa.size)
    return CENTER + aa[:, None] * u + bb[:, None] * v + h[:, None] * n


def _box_corner():
    """Points of two perpendicular 200 x 150 mm faces meeting at an edge (not flat)."""
    u, v, n = _frame()
    a = np.arange(0.0, 0.2, STEP)
    b = np.arange(-0.075, 0.075, STEP)
    aa, bb = (g.ravel() for g in np.meshgrid(a, b))
    top = CENTER + aa[:, None] * u + bb[:, None] * v
    side = CENTER + bb[:, None] * v - aa[:, None] * n
    return np.vstack([top, side])


def test_flat_support_has_the_plain_working_points_as_one_face():
    pts, params = _rectangle(), ModelingParams()
    built = build_flat_face(pts, params)
    assert built is not None
    wc, faces, adjacency = built
    plain = build_working_cloud(pts, params.voxel_size, params.normal_neighbors, None,
                                params.max_working_points)
    assert np.array_equal(wc.points, plain.points)
    assert np.array_equal(wc.counts, plain.counts)
    assert np.array_equal(wc.point_to_working, plain.point_to_working)
    assert len(faces) == 1 and adjacency.shape == (1, 1) and not adjacency.any()
    face = faces[0]
    assert np.array_equal(face.working, np.arange(len(wc.points)))
    assert np.array_equal(face.points, np.arange(len(pts)))
    # The face's normal is the rectangle's, towards the sensor (within the noise).
    _, _, n = _frame()
    assert face.info.planar
    assert math.degrees(math.acos(min(1.0, float(face.info.normal @ n)))) < 0.1
    assert np.allclose(wc.normals, face.info.normal)


def test_flat_face_is_described_as_the_plain_path_describes_it():
    pts, params = _rectangle(seed=3), ModelingParams()
    _, faces, _ = build_flat_face(pts, params)
    _, plain, adjacency = build_faces(pts, params, None)
    assert len(plain) == 1 and adjacency.shape == (1, 1)
    got, want = faces[0], plain[0]
    assert got.summary.surface == want.summary.surface == "planar"
    assert got.summary.cf == want.summary.cf
    assert got.summary.point_count == want.summary.point_count == len(pts)
    assert np.array_equal(got.info.normal, want.info.normal)
    assert got.info.offset == want.info.offset
    assert np.array_equal(got.info.center, want.info.center)


def test_points_that_do_not_lie_flat_get_no_shortcut():
    assert build_flat_face(_box_corner(), ModelingParams()) is None


def _model(pts, support, seed=7, params=None):
    params = params or ModelingParams()
    return model_object(pts, 0, params, np.random.default_rng(seed), STEP, support=support)


def _same(a, b):
    """Whether two primitives are the same to the last bit (their whole output)."""
    return a.to_dict() == b.to_dict()


def test_a_flat_support_gives_the_plain_plane():
    pts = _rectangle(seed=1)
    fast, plain = _model(pts, True), _model(pts, False)
    assert _same(fast, plain)
    assert fast.type is PrimitiveType.PLANE
    # Size and pose of the rectangle (sizes from all points, edge-corrected).
    assert fast.dimensions["length"] == pytest.approx(LENGTH, abs=0.0005)
    assert fast.dimensions["width"] == pytest.approx(WIDTH, abs=0.0005)
    assert np.linalg.norm(fast.center - CENTER) < 0.0005


def test_a_support_that_is_no_plane_is_modeled_as_any_other_object():
    pts = _box_corner()
    fast, plain = _model(pts, True), _model(pts, False)
    assert _same(fast, plain)
    assert fast.type is not PrimitiveType.PLANE


def test_a_support_in_two_pieces_is_one_face_of_the_same_plane():
    # A 60 mm strip cut across the middle: region growing finds two faces, which the
    # model graph merges into one plane; the shortcut takes one face from the start.
    pts = _rectangle(seed=2, gap=0.06)
    _, plain_faces, _ = build_faces(pts, ModelingParams(), None)
    assert len(plain_faces) == 2
    fast, plain = _model(pts, True), _model(pts, False)
    assert fast.type is plain.type is PrimitiveType.PLANE
    assert len(fast.faces) == 1 and len(plain.faces) == 2
    _, _, n = _frame()
    for prim in (fast, plain):
        assert abs(float(prim.rotation[:, 2] @ n)) > math.cos(math.radians(0.1))
        assert prim.dimensions["length"] == pytest.approx(LENGTH, abs=0.0005)
        assert prim.dimensions["width"] == pytest.approx(WIDTH, abs=0.0005)


def test_a_failed_shortcut_leaves_the_object_stream_as_it_was(monkeypatch):
    # A shortcut fit that draws from the stream and verifies no plane: the object is then
    # modeled as without the shortcut, from the stream's state on entry.
    from geomodel_ros.core import modeling

    plain_fit = modeling._fitted
    calls = []

    def first_fails(points, oid, params, rng, built, setting, **options):
        calls.append(len(built[1]))
        if len(calls) == 1:
            rng.random(1000)
            return modeling._unknown(oid, points, "shortcut rejected")
        return plain_fit(points, oid, params, rng, built, setting, **options)

    pts = _rectangle(seed=4)
    plain = _model(pts, False)
    monkeypatch.setattr(modeling, "_fitted", first_fails)
    fast = _model(pts, True)
    assert len(calls) == 2
    assert _same(fast, plain)


def _bent_rectangle(radius):
    """Return the rectangle bent along its length round an axis ``radius`` [m] off, no noise."""
    u, v, n = _frame()
    a = np.arange(-LENGTH / 2 + STEP / 2, LENGTH / 2, STEP)
    b = np.arange(-WIDTH / 2 + STEP / 2, WIDTH / 2, STEP)
    aa, bb = (g.ravel() for g in np.meshgrid(a, b))
    h = -aa * aa / (2.0 * radius)  # sagitta LENGTH^2 / (8 radius): 1 mm at 20 m
    return CENTER + aa[:, None] * u + bb[:, None] * v + (h - h.mean())[:, None] * n


def test_a_flat_face_the_surface_test_calls_curved_gets_no_shortcut():
    # Bent by 1 mm over 400 mm: within the flat spread, but with every face's CF below
    # cf_threshold = 1 and no least arc (min_arc = 0) its significant bend makes it
    # curved; a curved face's tests need the point normals the shortcut does not estimate.
    params = ModelingParams(min_arc=0.0, cf_threshold=1.0)
    pts = _bent_rectangle(20.0)
    _, plain, _ = build_faces(pts, params, None)
    assert [f.info.planar for f in plain] == [False]
    assert build_flat_face(pts, params) is None
    assert _same(_model(pts, True, params=params), _model(pts, False, params=params))
    # With the defaults the same surface is one planar face, and the shortcut takes it.
    assert build_flat_face(pts, ModelingParams()) is not None
