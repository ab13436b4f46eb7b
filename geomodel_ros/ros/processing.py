"""One frame through the whole chain: PointCloud2 -> core -> MarkerArray, objects and clouds.

:func:`process_cloud` is the single definition of what the ``modeler`` node does with a
frame; the node (:mod:`geomodel_ros.ros.node`) and the offline bag tool
(:mod:`geomodel_ros.ros.bags`) both call it, so that a bag processed offline gives the same
outputs as the node would publish for it.

Messages are read and built only through :mod:`msg_adapters`; nothing here needs
``rclpy``: no ``rclpy.init``, no node, no executor.  With an :class:`ObjectTracking` (the
node's default) object ids are stable across frames and the markers are per-id ADD and
DELETE; without one, ids are the frame's segment labels and the markers start with
DELETEALL.  The scene-modeling function is passed
in (:class:`SceneModeler`, default the core's
:func:`~geomodel_ros.core.modeling.model_scene`), so that tests and benchmarks can give a
stand-in without patching module globals.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any, Callable, Protocol

import numpy as np
from numpy.typing import NDArray

from geomodel_ros.core.modeling import model_scene as core_model_scene
from geomodel_ros.core.params import ModelingParams
from geomodel_ros.core.primitives import ModelingResult
from geomodel_ros.core.primitives import Primitive
from geomodel_ros.core.reconstruction import reconstruct
from geomodel_ros.core.tracking import Tracker, TrackerConfig
from geomodel_ros.core.viewpoint import SensorPose

from msg_adapters.diagnostics import noise_values, sensor_values
from msg_adapters.interfaces import MarkerArray, PointCloud2
from msg_adapters.markers import (primitives_to_markers, reconstruction_cloud, segments_cloud,
                                  tracked_markers)
from msg_adapters.objects import PrimitiveArray, primitives_to_objects
from msg_adapters.pointcloud2 import PointCloud2Error, ScenePoints, cloud_to_scene

__all__ = ["FrameResult", "ModeledFrame", "ModelingError", "ObjectTracking", "PointCloud2Error",
           "SceneModeler", "finish_frame", "model_frame", "process_cloud"]


class SceneModeler(Protocol):
    """What :func:`process_cloud` calls to model a scene (the core's ``model_scene``).

    Takes ``points`` ((N, 3) float64 [m], NaN rows allowed), the parameters and the
    ``organized_shape`` ((H, W) or None); returns ``(labels, result)`` with ``labels`` an
    (N,) integer array (-1 = no object) and ``result`` a :class:`ModelingResult`.
    """

    def __call__(self, points: np.ndarray, params: ModelingParams, *,
                 organized_shape: tuple[int, int] | None = None
                 ) -> tuple[np.ndarray, ModelingResult]: ...


class ModelingError(RuntimeError):
    """The core failed on a (well-formed) frame.

    The message names the original exception (``"RuntimeError: ..."``), which is also
    chained as ``__cause__``; ``valid_points`` is the number of finite points of the frame.
    """

    def __init__(self, message: str, valid_points: int) -> None:
        super().__init__(message)
        self.valid_points = valid_points


class ObjectTracking:
    """State of one stream's tracked outputs: the tracker and the markers shown.

    Parameters
    ----------
    config : TrackerConfig, optional
        The tracker's parameters (defaults when omitted); :attr:`tracker` ``.config`` may be
        replaced between frames.
    """

    def __init__(self, config: TrackerConfig | None = None) -> None:
        self.tracker = Tracker(config)
        self.shown: dict[int, str] = {}
        self.clear = True  # the first frame starts with DELETEALL

    def reset(self) -> None:
        """Retire every track; the next frame's markers start with DELETEALL again."""
        self.tracker.reset()
        self.shown = {}
        self.clear = True

    def step(self, objects: list[Primitive], header) -> tuple[list[Primitive], MarkerArray,
                                                               tuple[int, ...]]:
        """Track one frame's objects; return them with stable ids, the markers, retired ids."""
        tracked = self.tracker.update(objects)
        markers, self.shown = tracked_markers(tracked.objects, header,
                                              deleted_ids=tracked.deleted_ids,
                                              previous=self.shown, clear=self.clear)
        self.clear = False
        return tracked.objects, markers, tracked.deleted_ids


@dataclass(frozen=True)
class FrameResult:
    """Outputs of one frame (every message carries the input's ``frame_id`` and ``stamp``).

    Attributes
    ----------
    markers : visualization_msgs.msg.MarkerArray
        Without tracking: DELETEALL, then a shape and a label per object.  With tracking:
        DELETEALL only in the first frame, DELETE for the retired ids, then per object
        (stable id) its shape and label.
    segments : sensor_msgs.msg.PointCloud2 or None
        The input's points (organized layout kept) with ``object_id`` and ``rgb``; None when
        not requested.
    reconstruction : sensor_msgs.msg.PointCloud2 or None
        Surface samples of the modeled objects; None when not requested.
    result : ModelingResult
        The core's objects and stage times (empty when the frame had no finite point).
    labels : (N,) int64 array
        Object id per input point in row-major order (-1 = none); N = height * width.
    valid_points : int
        Number of points with finite x, y, z.
    timing : dict[str, float]
        Stage times [s]: ``convert_s``, ``model_s``, ``markers_s`` (with tracking: tracking
        and markers), ``objects_s``, ``first_out_s`` (only with ``on_objects``: its call),
        ``segments_s``, ``reconstruction_s``, plus the core's own stages as
        ``core_<name>``.
    objects : geomodel_msgs.msg.PrimitiveArray or None
        The typed objects (ids stable with tracking; the segment labels without).
    tracked : list[Primitive]
        The objects as published (with tracking: stable ids, smoothed when configured).
    deleted_ids : tuple[int, ...]
        Ids the tracker retired in this frame (empty without tracking).
    diagnostics : dict[str, str]
        The frame's noise estimate and fragment count as ``/diagnostics`` key/values
        (:func:`msg_adapters.diagnostics.noise_values`), and the camera's centre when it
        was recovered from the cloud's grid (:func:`msg_adapters.diagnostics.sensor_values`).
    """

    markers: MarkerArray
    segments: PointCloud2 | None
    reconstruction: PointCloud2 | None
    result: ModelingResult
    labels: np.ndarray
    valid_points: int
    timing: dict[str, float] = field(default_factory=dict)
    objects: PrimitiveArray | None = None
    tracked: list[Primitive] = field(default_factory=list)
    deleted_ids: tuple[int, ...] = ()
    diagnostics: dict[str, str] = field(default_factory=dict)


def _model(points: np.ndarray, organized: tuple[int, int] | None, n_valid: int,
           params: ModelingParams, model_scene: SceneModeler
           ) -> tuple[np.ndarray, ModelingResult]:
    """Run ``model_scene`` and check its labels; any failure as :class:`ModelingError`."""
    try:
        labels, result = model_scene(points, params, organized_shape=organized)
        labels = np.asarray(labels)
        if labels.shape != (len(points),) or labels.dtype.kind not in "ui":
            raise ValueError(f"model_scene returned {labels.dtype} labels of shape "
                             f"{labels.shape} for {len(points)} points")
    except Exception as exc:  # noqa: BLE001 - reported as one typed error
        raise ModelingError(f"{type(exc).__name__}: {exc}", n_valid) from exc
    return labels, result


def process_cloud(msg: PointCloud2, params: ModelingParams, *, segments: bool = True,
                  reconstruction: bool = True,
                  model_scene: SceneModeler = core_model_scene,
                  tracking: ObjectTracking | None = None,
                  to_scene: Callable[[Any], ScenePoints] = cloud_to_scene,
                  on_objects: Callable[[MarkerArray, PrimitiveArray], None] | None = None,
                  sensor: SensorPose | None = None) -> FrameResult:
    """Model one point cloud and build the node's output messages.

    Parameters
    ----------
    msg : sensor_msgs.msg.PointCloud2
        The scene, any layout ``msg_adapters.pointcloud2`` reads (organized or not, NaN
        rows for missing returns, padded, float64, big-endian); also messages deserialized
        by ``rosbags`` [m].  The modeling takes the sensor at the frame's origin unless
        ``sensor`` or an organized cloud's grid says otherwise.  Not modified.
    params : ModelingParams
        Modeling and segmentation parameters (deterministic for a given ``params.seed``).
    segments, reconstruction : bool
        Build :attr:`FrameResult.segments` / :attr:`FrameResult.reconstruction`.
    model_scene : SceneModeler
        The scene modeling (default: the core's ``model_scene``).
    tracking : ObjectTracking, optional
        Give the objects stable ids (updates its state) and build per-id markers.
    to_scene : callable
        Reads ``msg`` into points, grid and header (default: the PointCloud2 reader;
        the node passes the depth-image reader for ``input: depth``).
    on_objects : callable, optional
        Called with the frame's markers and typed objects as soon as they are built, before
        the segments and reconstruction clouds (the node publishes them there, so that a
        planner does not wait for the clouds: 30-40 ms on a Kinect frame).
    sensor : SensorPose, optional
        The sensor's pose in ``msg``'s frame (the node's ``sensor_frame``, from tf2): the
        points are modeled in the sensor's optical frame and every output is in ``msg``'s
        frame. Without it an organized cloud gives its camera itself (``params.viewpoint``)
        and an unorganized one is taken as seen from its frame's origin.

    Returns
    -------
    FrameResult
        A cloud without any finite point gives no objects (markers: DELETEALL only, which
        clears RViz) without calling the core.

    Raises
    ------
    PointCloud2Error
        If the message is malformed (inconsistent sizes, no float x/y/z, ...).
    ModelingError
        If the core fails on the frame.
    Exception
        Whatever ``to_scene`` raises for a malformed message (e.g. ``DepthImageError``).
    """
    return finish_frame(model_frame(msg, params, model_scene=model_scene, to_scene=to_scene,
                                    sensor=sensor),
                        params, segments=segments, reconstruction=reconstruction, tracking=tracking,
                        on_objects=on_objects)


@dataclass(frozen=True)
class ModeledFrame:
    """A frame read and modeled by :func:`model_frame`, before tracking and messages.

    Attributes
    ----------
    points : (N, 3) float array
        Every row of the input, NaN rows included [m].
    organized : (H, W) or None
        Image shape of an organized input.
    header : std_msgs.msg.Header
        The input's header (frame and stamp of every output).
    labels : (N,) int64 array
        Object id per row (-1 = none).
    result : ModelingResult
        The core's objects and stage times.
    valid_points : int
        Rows with finite x, y and z.
    timing : dict[str, float]
        ``convert_s``, ``model_s`` and the core's stages as ``core_<name>`` [s].
    """

    points: np.ndarray
    organized: tuple[int, int] | None
    header: Any
    labels: np.ndarray
    result: ModelingResult
    valid_points: int
    timing: dict[str, float]


def model_frame(msg: Any, params: ModelingParams, *,
                model_scene: SceneModeler = core_model_scene,
                to_scene: Callable[[Any], ScenePoints] = cloud_to_scene,
                sensor: SensorPose | None = None) -> ModeledFrame:
    """Read ``msg`` and model its scene: the first half of :func:`process_cloud`.

    Frames modeled concurrently (the node's ``workers``) are finished one at a time, in
    the order they arrived, by :func:`finish_frame`, which holds the per-stream state.

    Raises
    ------
    PointCloud2Error, ModelingError
        As :func:`process_cloud`.
    """
    timing: dict[str, float] = {}
    lap = _Laps(timing)
    # Every row, NaNs included: labels stay aligned with the input's points (and pixels,
    # for an organized cloud).
    points, organized, header = to_scene(msg)
    n_valid = _count_finite(points)
    lap("convert_s")
    if sensor is None:
        labels, result = _model_or_nothing(points, organized, n_valid, params, model_scene)
    else:  # modeled in the sensor's frame, whatever ``model_scene`` runs in
        labels, result = _model_or_nothing(sensor.to_sensor(points), organized, n_valid,
                                           params, model_scene)
        result = sensor.result_to_input(result)
    lap("model_s")
    timing.update({f"core_{k}": float(v) for k, v in result.timing.items()})
    return ModeledFrame(points, organized, header, labels.astype(np.int64, copy=False), result,
                        n_valid, timing)


def finish_frame(frame: ModeledFrame, params: ModelingParams, *, segments: bool = True,
                 reconstruction: bool = True, tracking: ObjectTracking | None = None,
                 on_objects: Callable[[MarkerArray, PrimitiveArray], None] | None = None
                 ) -> FrameResult:
    """Track a :class:`ModeledFrame`'s objects and build its messages.

    The second half of :func:`process_cloud` (same arguments; ``params`` are those the
    frame was modeled with).
    """
    timing = dict(frame.timing)
    lap = _Laps(timing)
    result, header = frame.result, frame.header
    objects = list(result.objects)
    deleted: tuple[int, ...] = ()
    if tracking is None:
        shown, markers = objects, primitives_to_markers(objects, header)
    else:
        shown, markers, deleted = tracking.step(objects, header)
    lap("markers_s")
    objects_msg = primitives_to_objects(shown, header, **_supports_by_id(result, objects, shown))
    lap("objects_s")
    if on_objects is not None:
        on_objects(markers, objects_msg)
        lap("first_out_s")
    segments_msg = segments_cloud(frame.points, frame.labels, header,
                                  organized_shape=frame.organized) if segments else None
    lap("segments_s")
    recon_msg = reconstruction_cloud(*reconstruct(objects, params.reconstruction_spacing), header) \
        if reconstruction else None
    lap("reconstruction_s")
    return FrameResult(markers=markers, segments=segments_msg, reconstruction=recon_msg,
                       result=result, labels=frame.labels, valid_points=frame.valid_points,
                       timing=timing, objects=objects_msg, tracked=list(shown),
                       deleted_ids=deleted,
                       diagnostics=noise_values(result.noise, result.fragments)
                       | sensor_values(result.sensor))


def _count_finite(points: NDArray[np.floating]) -> int:
    """Count the rows of ``points`` (N, 3) whose x, y and z are all finite."""
    # Per column: a reduction along the short axis of an (N, 3) array is ~10x slower.
    finite = np.isfinite(points[:, 0])
    finite &= np.isfinite(points[:, 1])
    finite &= np.isfinite(points[:, 2])
    return int(np.count_nonzero(finite))


class _Laps:
    """Record the time since the previous lap under a stage name [s]."""

    def __init__(self, timing: dict[str, float]) -> None:
        self._timing, self._last = timing, time.perf_counter()

    def __call__(self, stage: str) -> None:
        now = time.perf_counter()
        self._timing[stage] = now - self._last
        self._last = now


def _model_or_nothing(points: NDArray[np.float64], organized: tuple[int, int] | None,
                      n_valid: int, params: ModelingParams, model_scene: SceneModeler
                      ) -> tuple[NDArray[np.int64], ModelingResult]:
    """Run the core, or give no objects (every label -1) when no point is finite."""
    if n_valid:
        return _model(points, organized, n_valid, params, model_scene)
    return np.full(len(points), -1, dtype=np.int64), ModelingResult(objects=[], timing={})


def _supports_by_id(result: ModelingResult, objects: list, shown: list) -> dict:
    """Re-key support planes and the objects resting on them to the published ids.

    Returns ``supports`` and ``supported`` of ``primitives_to_objects``, keyed by the
    published (tracked) ids instead of the segment labels.
    """
    published_id = {p.id: q.id for p, q in zip(objects, shown)}
    supports = {published_id[k]: v for k, v in getattr(result, "supports", {}).items()
                if k in published_id}
    supported = {published_id[k]: [published_id[i] for i in ids if i in published_id]
                 for k, ids in getattr(result, "supported", {}).items() if k in published_id}
    return {"supports": supports, "supported": supported}
