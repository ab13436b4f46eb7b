"""Scene modeling in worker processes: several frames at once on a multi-core computer.

A frame's modeling is mostly many small numpy calls that hold the interpreter lock, so two
threads of one process do not model two frames at once (measured: the core's own object
threads gain nothing); two processes do. :class:`ProcessModeler` is a
:class:`~geomodel_ros.ros.processing.SceneModeler` that runs the core's ``model_scene`` in a
pool of worker processes: the node's ``workers`` parameter starts that many, and as many
node threads hand frames to them (:mod:`geomodel_ros.ros.node`). A frame's result is the
one the node's own process would compute (same parameters, same seed: identical labels and
objects); what changes is how many frames are modeled per second, not how long one takes.

The workers are started by a fork server, not forked from the node: the node's process runs
DDS and executor threads, and a fork copies none of them but may copy their locks held.
The server imports the core once; each worker is forked from it and so starts in well under
a second. Nothing here imports ``rclpy``.

A worker that dies (killed, out of memory) fails its frame with a :class:`RuntimeError`
naming what happened; the pool is replaced, so the next frame is modeled again.
"""

from __future__ import annotations

import multiprocessing
import threading
from concurrent.futures import ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool

import numpy as np

from geomodel_ros.core.fastmath import retain_freed_memory
from geomodel_ros.core.modeling import model_scene as core_model_scene
from geomodel_ros.core.params import ModelingParams
from geomodel_ros.core.primitives import ModelingResult

__all__ = ["ProcessModeler", "MAX_WORKERS"]

#: Largest accepted number of worker processes (the node's ``workers`` parameter).
MAX_WORKERS = 64
#: Modules the fork server imports once, so that forked workers start warm.
PRELOAD = ("numpy", "scipy.spatial", "geomodel_ros.core.modeling")


def _start_worker() -> None:
    """Set up a worker process: keep freed memory for the next frame, as the node does."""
    retain_freed_memory()


def _model_in_worker(points: np.ndarray, params: ModelingParams,
                     organized_shape: tuple[int, int] | None
                     ) -> tuple[np.ndarray, ModelingResult]:
    """Run the core's ``model_scene`` (in a worker process)."""
    return core_model_scene(points, params, organized_shape=organized_shape)


def _context() -> multiprocessing.context.BaseContext:
    """Return the fork-server start method where the platform has it, else spawn."""
    if "forkserver" in multiprocessing.get_all_start_methods():
        ctx = multiprocessing.get_context("forkserver")
        ctx.set_forkserver_preload(list(PRELOAD))
        return ctx
    return multiprocessing.get_context("spawn")


class ProcessModeler:
    """Model scenes in ``workers`` processes; call it like the core's ``model_scene``.

    Parameters
    ----------
    workers : int
        Worker processes (1 to :data:`MAX_WORKERS`); started on the first call or by
        :meth:`start`.

    Raises
    ------
    ValueError
        If ``workers`` is out of range.
    """

    def __init__(self, workers: int) -> None:
        if not 1 <= int(workers) <= MAX_WORKERS:
            raise ValueError(f"workers must be in [1, {MAX_WORKERS}], got {workers}")
        self.workers = int(workers)
        self._lock = threading.Lock()
        self._pool: ProcessPoolExecutor | None = None
        self._closed = False

    def start(self) -> None:
        """Start the worker processes now (otherwise the first frame starts them)."""
        futures = [self._current_pool().submit(_start_worker) for _ in range(self.workers)]
        for future in futures:
            future.result()

    def __call__(self, points: np.ndarray, params: ModelingParams, *,
                 organized_shape: tuple[int, int] | None = None
                 ) -> tuple[np.ndarray, ModelingResult]:
        """Model one scene in a worker process (blocks until it is done).

        Raises
        ------
        RuntimeError
            If the worker died (the pool is replaced for the next call) or the modeler
            is closed; whatever the core raised for the frame otherwise.
        """
        pool = self._current_pool()
        try:
            return pool.submit(_model_in_worker, points, params, organized_shape).result()
        except BrokenProcessPool as exc:
            self._replace(pool)
            raise RuntimeError(f"a modeling worker process died ({exc}); the workers were "
                               "restarted") from exc

    def close(self) -> None:
        """Stop the workers (frames in progress are abandoned); later calls raise."""
        with self._lock:
            self._closed = True
            pool, self._pool = self._pool, None
        if pool is not None:
            pool.shutdown(wait=False, cancel_futures=True)

    def _current_pool(self) -> ProcessPoolExecutor:
        with self._lock:
            if self._closed:
                raise RuntimeError("the modeling workers are closed")
            if self._pool is None:
                self._pool = ProcessPoolExecutor(self.workers, mp_context=_context(),
                                                 initializer=_start_worker)
            return self._pool

    def _replace(self, broken: ProcessPoolExecutor) -> None:
        """Drop ``broken`` (if it is still the current pool); the next call starts anew."""
        with self._lock:
            if self._pool is broken:
                self._pool = None
        broken.shutdown(wait=False, cancel_futures=True)
