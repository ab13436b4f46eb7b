"""How the modeling runs in parallel: one BLAS thread, kept worker threads, blocked filters.

These mechanisms only change where and when the work runs; every test checks that the
results stay exactly the same (bit for bit) and that the mechanism does what it says.
"""

from __future__ import annotations

import multiprocessing
import threading

import numpy as np
import pytest
import threadpoolctl

from geomodel_ros.core import fastmath, modeling, obb
from geomodel_ros.core.params import ModelingParams


def _blas_counts() -> list[int]:
    """Thread count of every BLAS library loaded, as threadpoolctl reports it afresh."""
    import scipy.linalg  # noqa: F401  (scipy's own OpenBLAS, as the limiter loads it)
    return [lib["num_threads"] for lib in threadpoolctl.threadpool_info()
            if lib["user_api"] == "blas"]


def _two_boxes() -> tuple[np.ndarray, np.ndarray]:
    """Two boxes' visible faces 0.6-0.7 m in front of the sensor, labels 0 and 1."""
    rng = np.random.default_rng(3)
    parts, labels = [], []
    for label, (cx, size) in enumerate(((-0.12, 0.08), (0.12, 0.06))):
        u = rng.uniform(-size / 2, size / 2, (3000, 2))
        front = np.column_stack([cx + u[:, 0], u[:, 1], np.full(3000, 0.6)])
        top = np.column_stack([cx + u[:, 0], np.full(3000, -size / 2), 0.6 + size / 2 + u[:, 1]])
        parts += [front, top]
        labels += [np.full(6000, label)]
    return np.vstack(parts), np.concatenate(labels)


def test_single_threaded_blas_sets_one_thread_and_restores_the_count_when_nested():
    if not _blas_counts():
        pytest.skip("no BLAS library found: the limiter is a no-op")
    before = _blas_counts()
    with fastmath.single_threaded_blas():
        assert _blas_counts() == [1] * len(before)
        with fastmath.single_threaded_blas():
            assert _blas_counts() == [1] * len(before)
        assert _blas_counts() == [1] * len(before)  # the outer block still runs
    assert _blas_counts() == before


def test_single_threaded_blas_restores_a_count_set_before_it():
    if not _blas_counts():
        pytest.skip("no BLAS library found: the limiter is a no-op")
    with threadpoolctl.threadpool_limits(limits=2, user_api="blas"):
        assert _blas_counts() == [2] * len(_blas_counts())
        with fastmath.single_threaded_blas():
            assert _blas_counts() == [1] * len(_blas_counts())
        assert _blas_counts() == [2] * len(_blas_counts())


def test_single_threaded_blas_holds_until_the_last_of_two_threads_leaves():
    if not _blas_counts():
        pytest.skip("no BLAS library found: the limiter is a no-op")
    before = _blas_counts()
    entered, release, left = threading.Event(), threading.Event(), threading.Event()
    inside: list[list[int]] = []

    def other() -> None:
        with fastmath.single_threaded_blas():
            entered.set()
            release.wait(10)
            inside.append(_blas_counts())
        left.set()

    worker = threading.Thread(target=other)
    with fastmath.single_threaded_blas():    # this thread sets the count
        worker.start()
        assert entered.wait(10)
    assert _blas_counts() == [1] * len(before)   # the other thread is still inside
    release.set()
    assert left.wait(10)                         # ... and restores it, last out
    worker.join(10)
    assert inside == [[1] * len(before)]
    assert _blas_counts() == before


def test_single_threaded_blas_works_from_a_second_thread_after_the_first():
    if not _blas_counts():
        pytest.skip("no BLAS library found: the limiter is a no-op")
    before = _blas_counts()
    with fastmath.single_threaded_blas():    # the main thread used it first
        pass
    seen: list[list[int]] = []

    def other() -> None:
        with fastmath.single_threaded_blas():
            seen.append(_blas_counts())
        seen.append(_blas_counts())

    worker = threading.Thread(target=other)
    worker.start()
    worker.join(10)
    assert seen == [[1] * len(before), before]


def test_single_threaded_blas_restores_the_count_after_an_exception():
    before = _blas_counts()
    with pytest.raises(RuntimeError, match="inside"):
        with fastmath.single_threaded_blas():
            raise RuntimeError("inside")
    assert _blas_counts() == before


def test_products_over_three_coordinates_are_the_same_bits_with_one_blas_thread():
    rng = np.random.default_rng(7)
    p = rng.normal(size=(300_000, 3)) + [0.2, -0.1, 0.9]
    rot = np.linalg.qr(rng.normal(size=(3, 3)))[0]
    v = rng.normal(size=3)
    threaded = (p @ v, rot.T @ p.T, p @ rot)
    with fastmath.single_threaded_blas():
        single = (p @ v, rot.T @ p.T, p @ rot)
    for a, b in zip(threaded, single):
        np.testing.assert_array_equal(a, b)


def test_modeling_keeps_its_worker_threads_from_call_to_call():
    points, labels = _two_boxes()
    first = modeling.model_objects(points, labels, ModelingParams(), rng=5)
    workers = {t.ident for t in threading.enumerate() if t.name.startswith("geomodel-modeling")}
    second = modeling.model_objects(points, labels, ModelingParams(), rng=5)
    again = {t.ident for t in threading.enumerate() if t.name.startswith("geomodel-modeling")}
    assert again == workers  # no thread started or lost by the second call
    assert [o.to_dict() for o in first.objects] == [o.to_dict() for o in second.objects]
    assert [o.type.value for o in first.objects] == ["cuboid", "cuboid"]


def test_modeling_in_parallel_and_in_sequence_gives_the_same_bits(monkeypatch):
    points, labels = _two_boxes()
    pooled = modeling.model_objects(points, labels, ModelingParams(), rng=9)
    monkeypatch.setattr(modeling.os, "cpu_count", lambda: 1)
    serial = modeling.model_objects(points, labels, ModelingParams(), rng=9)
    assert [o.to_dict() for o in pooled.objects] == [o.to_dict() for o in serial.objects]


def _model_in_child(queue) -> None:
    points, labels = _two_boxes()
    result = modeling.model_objects(points, labels, ModelingParams(), rng=5)
    queue.put([o.to_dict() for o in result.objects])


@pytest.mark.skipif("fork" not in multiprocessing.get_all_start_methods(),
                    reason="no fork on this platform")
def test_a_forked_child_models_with_workers_of_its_own():
    # The parent's pool has threads only in the parent: a child that inherited it would
    # hand its objects to workers that do not exist and wait for ever.
    points, labels = _two_boxes()
    parent = modeling.model_objects(points, labels, ModelingParams(), rng=5)
    ctx = multiprocessing.get_context("fork")
    queue = ctx.Queue()
    child = ctx.Process(target=_model_in_child, args=(queue,))
    child.start()
    try:
        got = queue.get(timeout=120)
    finally:
        child.join(timeout=10)
        if child.is_alive():
            child.kill()
    assert got == [o.to_dict() for o in parent.objects]


def test_hull_filter_in_blocks_finds_the_first_of_equal_extremes_across_blocks():
    n = 3 * obb.HULL_CHUNK + 17
    rng = np.random.default_rng(2)
    xy = rng.uniform(-1.0, 1.0, (n, 2)) * 0.5
    # The largest x twice, in the first and the third block; the largest y twice in one.
    xy[5] = [0.9, 0.1]
    xy[2 * obb.HULL_CHUNK + 3] = [0.9, -0.2]
    xy[obb.HULL_CHUNK + 1] = [0.0, 0.8]
    xy[obb.HULL_CHUNK + 2] = [0.3, 0.8]
    dirs = np.array([[1.0, 0.0], [0.0, 1.0], [-1.0, 0.0], [0.0, -1.0]])
    index = obb._extremes(dirs, np.ascontiguousarray(xy.T))
    assert index[0] == 5 and index[1] == obb.HULL_CHUNK + 1
    np.testing.assert_array_equal(index, np.argmax(dirs @ xy.T, axis=1))


def test_hull_filter_in_blocks_keeps_the_hull_and_drops_the_interior_of_a_large_grid():
    # A 301 x 201 grid rectangle of 2 mm steps, 0.6 x 0.4 m (60,501 points, eight
    # blocks): its hull is the four corners, and the octagon of the extremes is the
    # rectangle itself, so exactly the points on its border remain.
    g = np.stack(np.meshgrid(np.arange(301), np.arange(201)), -1).reshape(-1, 2) * 0.002
    xy = np.random.default_rng(4).permutation(g) - [0.3, 0.2]
    cand = obb.hull_candidates(xy)
    kept = {tuple(np.round(p, 9)) for p in cand}
    corners = {(-0.3, -0.2), (0.3, -0.2), (-0.3, 0.2), (0.3, 0.2)}
    assert corners <= kept
    on_border = np.isclose(np.abs(xy[:, 0]), 0.3) | np.isclose(np.abs(xy[:, 1]), 0.2)
    assert len(cand) == np.count_nonzero(on_border) == 2 * 301 + 2 * 199
    assert np.all(np.isclose(np.abs(cand[:, 0]), 0.3) | np.isclose(np.abs(cand[:, 1]), 0.2))


def test_model_scene_runs_on_one_blas_thread_and_leaves_the_count_as_it_was(monkeypatch):
    if not _blas_counts():
        pytest.skip("no BLAS library found: the limiter is a no-op")
    before = _blas_counts()
    seen = []
    real = modeling.frame_noise

    def spy(*args, **kwargs):
        seen.append(_blas_counts())
        return real(*args, **kwargs)

    points, _ = _two_boxes()
    monkeypatch.setattr(modeling, "frame_noise", spy)
    modeling.model_scene(points, ModelingParams())
    assert seen == [[1] * len(before)]
    assert _blas_counts() == before
