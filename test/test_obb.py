"""Bounding-box helpers (geomodel_ros.core.obb) and the fast reductions they use.

The reductions are those of geomodel_ros.core.fastmath.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial import ConvexHull

from geomodel_ros.core import fastmath, obb


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(3, 3000),
       shape=st.sampled_from(["square", "disc", "gauss", "line-ish"]))
def test_hull_candidates_keep_every_hull_vertex(seed, n, shape):
    rng = np.random.default_rng(seed)
    if shape == "square":
        xy = rng.uniform(-1, 1, size=(n, 2))
    elif shape == "disc":
        r, a = np.sqrt(rng.uniform(0, 1, n)), rng.uniform(0, 2 * np.pi, n)
        xy = np.column_stack([r * np.cos(a), r * np.sin(a)])
    elif shape == "gauss":
        xy = rng.normal(size=(n, 2)) * [3.0, 0.2]
    else:
        xy = np.column_stack([rng.uniform(0, 1, n), 1e-3 * rng.normal(size=n)])
    xy = xy * 0.4 + rng.uniform(-2, 2, size=2)
    cand = obb.hull_candidates(xy)
    hull_all = {tuple(p) for p in xy[ConvexHull(xy).vertices]}
    kept = {tuple(p) for p in cand}
    assert hull_all <= kept
    assert len(cand) <= len(xy)


def test_hull_candidates_drop_the_interior_of_a_dense_rectangle():
    rng = np.random.default_rng(0)
    xy = rng.uniform([0, 0], [0.4, 0.3], size=(200_000, 2))
    cand = obb.hull_candidates(xy)
    assert len(cand) < 0.05 * len(xy)


@pytest.mark.parametrize("angle", [0.0, 0.3, 1.0, 2.5])
def test_min_area_rectangle_finds_the_rotation_of_a_sampled_rectangle(angle):
    rng = np.random.default_rng(1)
    local = rng.uniform([-0.2, -0.1], [0.2, 0.1], size=(50_000, 2))
    c, s = math.cos(angle), math.sin(angle)
    xy = local @ np.array([[c, s], [-s, c]])
    direction, area = obb.min_area_rectangle(xy)
    # The first side is parallel to one of the rectangle's sides.
    found = math.atan2(direction[1], direction[0]) % (math.pi / 2)
    assert min(abs(found - angle % (math.pi / 2)),
               math.pi / 2 - abs(found - angle % (math.pi / 2))) < 1e-3
    assert area == pytest.approx(0.4 * 0.2, rel=0.01)


def test_ray_to_plane_moves_noisy_points_onto_the_plane_along_their_rays():
    rng = np.random.default_rng(2)
    n = np.array([0.0, -0.766, -0.643])
    n /= np.linalg.norm(n)
    on = rng.uniform(-0.1, 0.1, size=(1000, 3)) + [0, 0, 0.5]
    on -= np.outer(on @ n - (-0.3), n)  # n . x = -0.3 -> d = 0.3
    noisy = on * (1 + rng.normal(scale=0.002, size=(1000, 1)))
    far = on[:5] * 1.5  # another surface: must not move
    moved = obb.ray_to_plane(np.vstack([noisy, far]), n, 0.3, max_shift=0.01)
    np.testing.assert_allclose(moved[:1000] @ n + 0.3, 0.0, atol=1e-12)
    # Along the ray: the moved point is a multiple of the original.
    cross = np.cross(moved[:1000], noisy)
    assert np.abs(cross).max() < 1e-12
    np.testing.assert_array_equal(moved[1000:], far)


def test_fast_reductions_match_numpy():
    rng = np.random.default_rng(3)
    p = rng.normal(size=(1001, 3))
    np.testing.assert_allclose(fastmath.row_norms(p), np.linalg.norm(p, axis=1))
    np.testing.assert_allclose(fastmath.centroid(p), p.mean(axis=0))
    np.testing.assert_array_equal(fastmath.centroid(np.zeros((0, 3))), np.zeros(3))
    q = p.copy()
    q[5, 1], q[9, 2], q[11, 0] = np.nan, np.inf, -np.inf
    np.testing.assert_array_equal(fastmath.rows_finite(q), np.all(np.isfinite(q), axis=1))


def test_take_rows_matches_fancy_and_boolean_indexing():
    rng = np.random.default_rng(4)
    p = rng.normal(size=(500, 3))
    idx = rng.integers(-500, 500, size=300)
    mask = rng.random(500) < 0.3
    np.testing.assert_array_equal(fastmath.take_rows(p, idx), p[idx])
    np.testing.assert_array_equal(fastmath.take_rows(p, mask), p[mask])
    np.testing.assert_array_equal(fastmath.take_rows(p, np.zeros(0, dtype=np.int64)), p[:0])
    with pytest.raises(IndexError):
        fastmath.take_rows(p, np.array([500]))


def test_retain_freed_memory_stops_the_page_faults_of_repeated_large_arrays():
    # In a fresh interpreter (the setting is process-wide): 20 rounds of three 16 MB
    # arrays alive at once, then freed (a frame's temporaries); glibc returns the
    # freed heap top to the system and maps fresh pages every round unless freed
    # memory is kept.
    code = (
        "import resource, sys, numpy as np\n"
        "from geomodel_ros.core.fastmath import retain_freed_memory\n"
        "ok = retain_freed_memory() if sys.argv[1] == '1' else True\n"
        "def frame():\n"
        "    a, b, c = np.ones(2_000_000), np.ones(2_000_000), np.ones(2_000_000)\n"
        "    return float((a + b + c).sum())\n"
        "frame()\n"
        "before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt\n"
        "for _ in range(20):\n"
        "    frame()\n"
        "print(int(ok), resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before)\n")
    root = __import__("pathlib").Path(__file__).resolve().parents[1]
    faults = {}
    for flag in ("0", "1"):
        out = __import__("subprocess").run([__import__("sys").executable, "-c", code, flag],
                                           cwd=root, capture_output=True, text=True, timeout=60)
        assert out.returncode == 0, out.stderr
        ok, n = map(int, out.stdout.split())
        assert ok == 1
        faults[flag] = n
    one_array = 16e6 / 4096
    assert faults["0"] > 5 * one_array  # pages mapped afresh round after round
    assert faults["1"] < one_array  # the first round's pages are reused
