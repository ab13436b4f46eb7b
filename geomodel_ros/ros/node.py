r"""ROS 2 node ``modeler``: PointCloud2 or depth image in, modeled primitives out.

Run it as::

    ros2 run geomodel_ros modeler --ros-args --params-file config/modeler.yaml \
        -r points:=/camera/depth/points
    ros2 run geomodel_ros modeler --ros-args -p input:=depth \
        -r depth/image_raw:=/camera/depth/image_rect_raw \
        -r depth/camera_info:=/camera/depth/camera_info

Topics (names relative to the node, so ``-r`` and namespaces work):

* ``points`` (sensor_msgs/PointCloud2, subscribed with ``input: points``, the default):
  the scene in any frame. The modeling works in the sensor's frame: an organized cloud
  in another frame gives its camera itself (``viewpoint``); for an unorganized one
  (filtered, cropped, voxelised) in another frame, ``sensor_frame`` names the sensor's
  optical frame, whose pose at the cloud's stamp the node looks up with tf2.
* ``depth/image_raw`` (sensor_msgs/Image, subscribed with ``input: depth``): a depth image,
  ``16UC1`` millimetres (0 = no return) or ``32FC1`` metres (NaN, inf, 0 = no return),
  rectified/registered (lens distortion is not applied); the node back-projects it into
  the organized cloud of the image's optical frame (:mod:`msg_adapters.depth_image`) and
  models that as it models ``points``.  An image is 4-8x smaller than its PointCloud2.
* ``depth/camera_info`` (sensor_msgs/CameraInfo, subscribed with ``input: depth``): the
  camera's intrinsics (``P``, else ``K``); the latest one is kept and used for every
  image.  An image before any CameraInfo, of another size than the CameraInfo, or with an
  unknown encoding is dropped with a throttled warning (counted as failed).
* Input QoS: keep last ``qos_depth``; reliability ``qos_reliability``: ``auto`` (default)
  subscribes reliable when every publisher of the topic is reliable and best effort
  otherwise, re-checked every ``INPUT_QOS_POLL_S`` s (a driver started after the node is
  picked up; :mod:`geomodel_ros.ros.input_qos`).  A reliable publisher's multi-MB clouds
  do not survive a best-effort subscription under the middleware's defaults.
* ``~/objects`` (geomodel_msgs/PrimitiveArray): the typed objects (MoveIt's SolidPrimitive
  conventions, see ``geomodel_msgs/msg/Primitive.msg``), every processed frame.
* ``~/primitives`` (visualization_msgs/MarkerArray): one marker and one label per object.
  With ``tracking`` (default) object ids are stable across frames
  (:class:`geomodel_ros.core.tracking.Tracker`, parameters ``tracking_*``) and the markers
  are per-id ADD (an object present) and DELETE (an id the tracker retired); DELETEALL
  only in the first frame after start or after ``tracking`` was switched on.  Without
  tracking, ids are the frame's segment labels and every frame starts with DELETEALL.
  A tracked frame that changes no marker publishes no MarkerArray.
* ``~/segments`` (sensor_msgs/PointCloud2): the input's points in the input's layout
  (organized clouds stay organized, NaN rows kept) with fields ``object_id`` (-1 = no
  object) and ``rgb`` (``publish_segments``).
* ``~/reconstruction`` (sensor_msgs/PointCloud2): surface samples of the modeled objects,
  hidden parts included, with ``object_id`` and ``rgb`` (``publish_reconstruction``).
* ``/diagnostics`` (diagnostic_msgs/DiagnosticArray, 1 Hz, when ``diagnostics`` is true):
  received, processed, dropped, ignored and failed frames, rate, latency and result age.
  WARN only when the processing rate (continuous mode, over a window of
  ``2 / expected_rate_min`` s) leaves [``expected_rate_min``, ``expected_rate_max``], when
  the newest result's stamp is older than ``max_result_age``, or when frames failed.
  Dropped frames alone are normal (a 30 Hz camera and a slower node) and stay OK.

Service ``~/detect`` (std_srvs/Trigger): processes the next frame that arrives and answers
with a one-line summary (objects by type, the frame's stamp); ``success`` false when no
frame was processed within ``detect_timeout``.  With ``continuous`` false the node ignores
frames (counted as ``ignored``) except those asked for this way.  The call waits for its
frame as a coroutine in its own reentrant callback group, so any executor serves it
(``main`` spins a single-threaded one) and frames keep arriving while it waits.

Every output carries the input's header (``frame_id`` and ``stamp``).  Outputs are
published reliable, keep last ``qos_depth`` (compatible with reliable and best-effort
subscribers such as RViz and planners).

The node is a thin wire: :func:`geomodel_ros.ros.processing.process_cloud`'s two halves
(:func:`~geomodel_ros.ros.processing.model_frame`: adapter -> core
:func:`geomodel_ros.core.modeling.model_scene`, or the ``model_scene`` passed in;
:func:`~geomodel_ros.ros.processing.finish_frame`: tracking -> adapters;
shared with the offline bag tool ``geomodel bag``) -> publish; every message is built and
read through :mod:`msg_adapters`.  Modeling runs in worker threads fed by a one-slot
mailbox: a frame that arrives while every worker is busy and another frame waits replaces
the waiting one (newest frame wins) and is counted as dropped.  With ``workers`` > 1 that
many frames are modeled at once, each in its own process
(:class:`geomodel_ros.ros.frame_workers.ProcessModeler`); their objects are tracked and
published one frame at a time in the order the frames arrived.  A malformed message or a frame
the core fails on is logged (throttled) and skipped; the node keeps running.  On SIGINT the
node waits up to :data:`WORKER_JOIN_TIMEOUT_S` for a frame in progress; a frame still being
modeled then is abandoned and the process exits at once with status 0, without finalizing
the interpreter under a thread that may be inside numpy or open3d.

Parameters: every entry of :data:`geomodel_ros.core.params.PARAMETERS` (changeable at run time,
used from the next frame) plus the node parameters of :data:`NODE_PARAMETERS`.
"""

from __future__ import annotations

import faulthandler
import math
import os
import sys
import threading
import time
import traceback
from dataclasses import dataclass, field, replace
from typing import Any, Callable

import rclpy
from rclpy.callback_groups import ReentrantCallbackGroup
from rclpy.exceptions import InvalidHandle, ParameterException
from rclpy.executors import ExternalShutdownException
from rclpy.executors import SingleThreadedExecutor
from rclpy.logging import get_logger
from rclpy.duration import Duration
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.time import Time as RosTime
from std_srvs.srv import Trigger

from geomodel_ros.ros.frame_workers import MAX_WORKERS, ProcessModeler
from geomodel_ros.ros.input_qos import RELIABILITY_MODES, AdaptiveSubscription
from geomodel_ros.ros.processing import (FrameResult, ModeledFrame, ModelingError,
                                         ObjectTracking, PointCloud2Error, SceneModeler,
                                         finish_frame, model_frame)

from geomodel_ros.core.fastmath import retain_freed_memory
from geomodel_ros.core.params import PARAMETERS, ModelingParams, ParameterError, ParamSpec
from geomodel_ros.core.tracking import TRACKER_PARAMETERS, TrackerConfig
from geomodel_ros.core.modeling import model_scene as core_model_scene
from geomodel_ros.core.viewpoint import SensorPose

from msg_adapters.depth_image import DepthImageError, depth_to_scene
from msg_adapters.diagnostics import diagnostics_message
from msg_adapters.header import header_of, stamp_ns, stamp_text
from msg_adapters.interfaces import CameraInfo, DiagnosticArray, Image, MarkerArray, PointCloud2
from msg_adapters.objects import PrimitiveArray
from msg_adapters.pointcloud2 import cloud_to_scene
from msg_adapters.parameters import option_descriptor, set_parameters_result, spec_descriptor

__all__ = ["ModelerNode", "NODE_PARAMETERS", "NODE_NUMERIC_PARAMETERS", "TRACKING_PARAMETERS",
           "NodeOptions", "FrameStats", "main"]

#: Seconds between two warnings of the same kind.
WARN_THROTTLE_S = 5.0
#: How long ``destroy_node`` waits for a frame in progress [s].
WORKER_JOIN_TIMEOUT_S = 5.0
#: How long ``destroy_node`` waits in all for the subscribers to acknowledge what the
#: reliable publishers sent [s] before it destroys them.
ACK_TIMEOUT_S = 2.0
#: Longest wait of a frame for its sensor's transform (``sensor_frame``) [s]: a transform
#: published at a moving sensor's rate arrives within this after the frame's stamp.
TF_TIMEOUT_S = 0.2
#: History depth of ``~/objects`` (reliable): a planner that is briefly slow still gets the
#: last few frames' objects.
OBJECTS_QOS_DEPTH = 10
#: Shortest window of the processing rate in /diagnostics [s] (the report period).
RATE_WINDOW_MIN_S = 1.0
#: Longest window of the processing rate [s] (``expected_rate_min`` near 0).
RATE_WINDOW_MAX_S = 60.0
#: Period of the publishers' QoS check of ``qos_reliability: auto`` [s]: a driver started
#: after the node is subscribed to within this time (rosbag2 polls every 0.1 s; the check
#: is a graph query, cheap, but there is no need to spend it more often).
INPUT_QOS_POLL_S = 0.5
#: Allowed values of ``input``.
INPUTS = ("points", "depth")


@dataclass(frozen=True)
class _NodeParam:
    name: str
    default: Any
    description: str
    read_only: bool = False
    constraints: str = ""
    low: int | None = None
    high: int | None = None


#: Parameters of the node itself (the modeling parameters come from PARAMETERS).
NODE_PARAMETERS: tuple[_NodeParam, ...] = (
    _NodeParam("qos_depth", 1, "History depth of the input subscription and the output "
               "publishers; read at start.", read_only=True, low=1, high=1000),
    _NodeParam("qos_reliability", "auto", "Reliability of the input subscriptions: auto "
               "(reliable when every publisher is reliable, else best effort; re-checked "
               "when publishers come and go), best_effort or reliable; read at start.",
               read_only=True, constraints="one of: " + ", ".join(RELIABILITY_MODES)),
    _NodeParam("input", "points", "What to model: points (sensor_msgs/PointCloud2 on "
               "'points') or depth (sensor_msgs/Image on 'depth/image_raw' with "
               "sensor_msgs/CameraInfo on 'depth/camera_info'); read at start.",
               read_only=True, constraints="one of: " + ", ".join(INPUTS)),
    _NodeParam("sensor_frame", "", "The sensor's optical frame (z forward, as the camera "
               "driver publishes its clouds in), for clouds in another frame: the node "
               "looks up its pose in the cloud's frame at the cloud's stamp with tf2 "
               "(tf2_ros) and models the cloud from there; a frame without that transform "
               "within TF_TIMEOUT_S is skipped (counted as failed). Needed for unorganized "
               "clouds in a robot's frame; organized ones give their camera themselves "
               "(viewpoint). Empty: clouds are taken as seen from their frame's origin. "
               "Read at start.", read_only=True),
    _NodeParam("workers", 1, "Frames modeled at once, each in its own worker process (1: in "
               "the node's process). More workers raise the processed rate on a multi-core "
               "computer (up to about one per core), not the speed of one frame; each holds "
               "its own memory. Read at start.", read_only=True, low=1, high=MAX_WORKERS),
    _NodeParam("publish_segments", True, "Publish ~/segments (input points labelled by object)."),
    _NodeParam("publish_reconstruction", True,
               "Publish ~/reconstruction (surface samples of the modeled objects)."),
    _NodeParam("diagnostics", True, "Publish /diagnostics (rates, drops, latency) at 1 Hz."),
    _NodeParam("tracking", True, "Keep object ids stable across frames (tracker, parameters "
               "tracking_*) and publish per-id marker ADD/DELETE; false: per-frame ids and "
               "DELETEALL every frame."),
    _NodeParam("continuous", True, "Model every frame (newest wins); false: only the frames "
               "asked for with the ~/detect service."),
)

#: Numeric node parameters (declared with ranges like the modeling parameters).
NODE_NUMERIC_PARAMETERS: tuple[ParamSpec, ...] = (
    # A depth camera at 30 Hz and this node at 1-10 Hz: below 0.5 Hz results are too stale
    # to act on, above 100 Hz something replays faster than any sensor.
    ParamSpec("expected_rate_min", 0.5, "Hz", 0.0, 1e6,
              "Processing rate below which /diagnostics warns (continuous mode)."),
    ParamSpec("expected_rate_max", 100.0, "Hz", 0.0, 1e6,
              "Processing rate above which /diagnostics warns (continuous mode)."),
    # A few frames' processing time at the slowest expected rate.
    ParamSpec("max_result_age", 5.0, "s", 0.0, 1e6,
              "Largest age of the newest result's stamp before /diagnostics warns "
              "(continuous mode; 0: not checked)."),
    # Several frame periods of a slow camera plus one modeling pass.
    ParamSpec("detect_timeout", 10.0, "s", 0.001, 3600.0,
              "How long ~/detect waits for its frame to be processed."),
)

#: The tracker's parameters as node parameters (``tracking_<name>``).
TRACKING_PARAMETERS: tuple[ParamSpec, ...] = tuple(
    replace(spec, name=f"tracking_{spec.name}") for spec in TRACKER_PARAMETERS)
_TRACKING_PREFIX = "tracking_"


@dataclass(frozen=True)
class NodeOptions:
    """Current values of :data:`NODE_PARAMETERS` (defaults are defined there only)."""

    qos_depth: int
    qos_reliability: str
    input: str
    sensor_frame: str
    workers: int
    publish_segments: bool
    publish_reconstruction: bool
    diagnostics: bool
    tracking: bool
    continuous: bool
    expected_rate_min: float
    expected_rate_max: float
    max_result_age: float
    detect_timeout: float


@dataclass
class FrameStats:
    """Counters of the node since start (a snapshot from :meth:`ModelerNode.stats`).

    Attributes
    ----------
    received : int
        Frames delivered by the subscription.
    processed : int
        Frames whose outputs were published.
    dropped : int
        Frames replaced in the mailbox by a newer one before being processed.
    failed : int
        Frames skipped because the message was malformed or the core failed.
    ignored : int
        Frames not modeled because ``continuous`` was false and no ``~/detect`` asked.
    last_latency_s : float
        Receive -> outputs published of the last processed frame [s] (NaN before any).
    last_stamp_ns : int
        Stamp of the last processed frame [ns] (-1 before any).
    last_timing : dict[str, float]
        Stage times of the last processed frame [s] (``convert_s``, ``model_s``,
        ``markers_s``, ``objects_s``, ``segments_s``, ``reconstruction_s``, ``publish_s``,
        ``turn_s`` (waiting for an earlier frame's outputs, ``workers`` > 1), ``total_s``).
    """

    received: int = 0
    processed: int = 0
    dropped: int = 0
    failed: int = 0
    ignored: int = 0
    last_latency_s: float = math.nan
    last_stamp_ns: int = -1
    last_timing: dict[str, float] = field(default_factory=dict)


class _Mailbox:
    """One slot: ``put`` replaces an item not yet taken; ``take`` blocks until one arrives.

    Every item taken gets the next ticket (0, 1, 2, ...): the order in which the frames
    are finished (:class:`_Turns`).
    """

    def __init__(self) -> None:
        self._cond = threading.Condition()
        self._item: Any = None
        self._closed = False
        self._tickets = 0

    def put(self, item: Any) -> Any:
        """Store ``item``; return the item it replaced (never taken), or None."""
        with self._cond:
            replaced = self._item
            self._item = item
            self._cond.notify()
            return replaced

    def take(self) -> tuple[Any, int] | None:
        """Return the next item and its ticket, or None once the mailbox is closed."""
        with self._cond:
            while self._item is None and not self._closed:
                self._cond.wait()
            if self._closed:
                return None
            item, self._item = self._item, None
            self._tickets += 1
            return item, self._tickets - 1

    def close(self) -> None:
        with self._cond:
            self._closed = True
            self._cond.notify_all()


class _Turns:
    """Lets the holders of tickets 0, 1, 2, ... through one at a time, in ticket order.

    Frames modeled at once (``workers`` > 1) may finish in any order; tracking and
    publishing take turns so that the outputs keep the order of the inputs. A ticket whose
    frame failed before its turn is :meth:`done` without waiting and is skipped.
    """

    def __init__(self) -> None:
        self._cond = threading.Condition()
        self._next = 0  # the ticket whose turn it is
        self._done: set[int] = set()
        self._closed = False

    def wait(self, ticket: int) -> bool:
        """Block until it is ``ticket``'s turn; False if closed meanwhile."""
        with self._cond:
            while self._next != ticket and not self._closed:
                self._cond.wait()
            return not self._closed

    def done(self, ticket: int) -> None:
        """End ``ticket``'s turn (or give it up before it came)."""
        with self._cond:
            self._done.add(ticket)
            while self._next in self._done:
                self._done.remove(self._next)
                self._next += 1
            self._cond.notify_all()

    def close(self) -> None:
        with self._cond:
            self._closed = True
            self._cond.notify_all()


class _DetectRequest:
    """One ``~/detect`` call waiting for its frame's outcome.

    ``wake`` is called (from the worker thread) when the outcome is known, so that the
    executor resumes the waiting service callback at once.
    """

    def __init__(self, wake: Callable[[], None]) -> None:
        self.done = threading.Event()
        self.success = False
        self.message = ""
        self._wake = wake

    def finish(self, success: bool, message: str) -> None:
        self.success, self.message = success, message
        self.done.set()
        self._wake()


class _NextWake:
    """Awaitable that suspends a coroutine callback until the executor's next wake-up.

    rclpy's executors resume a suspended coroutine once per wake-up (a message, a timer,
    :meth:`~rclpy.executors.Executor.wake`) before waiting again, so a callback that awaits
    this between checks neither blocks the executor nor spins it.
    """

    def __await__(self):
        yield


def _summary(frame: FrameResult, stamp: str) -> str:
    """One line: number of objects by type and the frame's stamp."""
    counts: dict[str, int] = {}
    for p in frame.tracked:
        counts[str(p.type)] = counts.get(str(p.type), 0) + 1
    by_type = ", ".join(f"{n} {t}" for t, n in sorted(counts.items()))
    ids = ", ".join(str(p.id) for p in frame.tracked)
    return (f"{len(frame.tracked)} objects" + (f" ({by_type}; ids {ids})" if counts else "")
            + f" at stamp {stamp}")


def _option_descriptor(p: _NodeParam):
    return option_descriptor(p.name, p.default, p.description, read_only=p.read_only,
                             constraints=p.constraints, low=p.low, high=p.high)


def _stamp(msg: PointCloud2 | Image) -> str:
    return stamp_text(stamp_ns(msg))


class ModelerNode(Node):
    """Models every incoming point cloud and publishes markers and labelled clouds.

    Parameters
    ----------
    node_name : str
        Default ``"modeler"`` (the key of ``config/modeler.yaml``).
    model_scene : SceneModeler
        The scene modeling run on every frame (default: the core's ``model_scene``); tests
        and benchmarks pass a stand-in.
    transforms : object, optional
        Where ``sensor_frame``'s pose is looked up: anything with ``tf2_ros.Buffer``'s
        ``lookup_transform(target_frame, source_frame, time, timeout)`` (default: a
        ``tf2_ros`` Buffer filled by its TransformListener, made only when
        ``sensor_frame`` is set).
    **kwargs
        Passed to :class:`rclpy.node.Node` (``context``, ``cli_args``, ``namespace``,
        ``parameter_overrides``, ...).

    Raises
    ------
    ParameterError
        If the initial parameters (overrides, params file) are inconsistent, e.g.
        ``min_radius >= max_radius``, or ``qos_reliability`` is not allowed, or
        ``sensor_frame`` is set where tf2_ros is not installed.
    rclpy.exceptions.ParameterException
        If an initial value has the wrong type or is out of its declared range.
    """

    def __init__(self, node_name: str = "modeler", *,
                 model_scene: SceneModeler = core_model_scene, transforms: Any = None,
                 **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        self._model_scene = model_scene
        self._spec_names = frozenset(p.name for p in PARAMETERS)
        self._numeric_specs = {p.name: p for p in NODE_NUMERIC_PARAMETERS}
        self._tracking_specs = {p.name: p for p in TRACKING_PARAMETERS}
        self._option_names = frozenset(p.name for p in NODE_PARAMETERS) | set(self._numeric_specs)
        try:
            self._params, self._options = self._initial_parameters()
            self._transforms = self._transform_source(transforms)
        except Exception:
            Node.destroy_node(self)  # nothing else exists yet
            raise
        self.add_on_set_parameters_callback(self._validate_parameters)
        self.add_post_set_parameters_callback(self._apply_parameters)

        self._create_publishers()
        self._stats = FrameStats()
        self._stats_lock = threading.Lock()
        self._diag_last = (time.monotonic(), 0, 0, 0)
        self._processed_at: list[float] = []  # monotonic times of processed frames [s]
        self._started_at = time.monotonic()
        # The worker's tracking state, created on first use and kept when tracking is
        # switched off, so that ids are never reused within a run of the node.
        self._tracking: ObjectTracking | None = None
        self._tracking_on = False
        self._detect_lock = threading.Lock()
        self._detect_pending: list[_DetectRequest] = []
        self._mailbox = _Mailbox()
        self._turns = _Turns()
        self._closing = False
        #: Workers still modeling a frame when destroy_node gave up waiting.
        self.frames_abandoned = 0
        self._processes: ProcessModeler | None = None
        if self._options.workers > 1 and model_scene is core_model_scene:
            self._processes = self._start_processes(self._options.workers)
            self._model_scene = self._processes or core_model_scene
        self._workers = [threading.Thread(target=self._run, name=f"{node_name}-worker-{k}",
                                          daemon=True) for k in range(self._options.workers)]
        for worker in self._workers:
            worker.start()
        self._camera_info: CameraInfo | None = None
        self._create_inputs()
        self._diag_timer = self.create_timer(1.0, self._publish_diagnostics)
        # Its own (reentrant) group: a waiting call must not hold the default group, which
        # the input subscription and the timers share.
        self._detect_service = self.create_service(Trigger, "~/detect", self._on_detect,
                                                   callback_group=ReentrantCallbackGroup())
        self.get_logger().info(
            f"modeling {'depth images' if self._options.input == 'depth' else 'clouds'} from "
            f"{', '.join(repr(s.topic_name) for s in self._inputs)} "
            f"({self._options.qos_reliability}, depth {self._options.qos_depth}; "
            f"{'continuous' if self._options.continuous else 'on demand'}); publishing "
            f"'{self._pub_objects.topic_name}', '{self._pub_markers.topic_name}', "
            f"'{self._pub_segments.topic_name}', '{self._pub_reconstruction.topic_name}'")

    def create_input_subscription(self, msg_type: type, topic: str, callback
                                  ) -> AdaptiveSubscription:
        """Subscribe ``topic`` with the input QoS (``qos_depth``, ``qos_reliability``)."""
        return AdaptiveSubscription(self, msg_type, topic, callback, self._options.qos_depth,
                                    self._options.qos_reliability)

    def _create_inputs(self) -> None:
        """Subscribe the inputs of ``input``; poll the publishers' QoS in ``auto`` mode."""
        if self._options.input == "depth":
            self._inputs = (self.create_input_subscription(Image, "depth/image_raw",
                                                           self._on_image),
                            self.create_input_subscription(CameraInfo, "depth/camera_info",
                                                           self._on_camera_info))
        else:
            self._inputs = (self.create_input_subscription(PointCloud2, "points",
                                                           self._on_cloud),)
        self._input_qos_timer = None
        if self._options.qos_reliability == "auto":
            self._input_qos_timer = self.create_timer(INPUT_QOS_POLL_S, self._update_inputs)

    def _update_inputs(self) -> None:
        for subscription in self._inputs:
            subscription.update()

    @property
    def input_reliability(self) -> dict[str, str | None]:
        """Reliability each input topic is subscribed with (resolved name -> policy)."""
        return {s.topic_name: s.reliability for s in self._inputs}

    def _create_publishers(self) -> None:
        """Create the output publishers (reliable, keep last ``qos_depth``; /diagnostics)."""
        qos_out = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=self._options.qos_depth,
                             reliability=ReliabilityPolicy.RELIABLE)
        self._pub_markers = self.create_publisher(MarkerArray, "~/primitives", qos_out)
        self._pub_objects = self.create_publisher(
            PrimitiveArray, "~/objects",
            QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=OBJECTS_QOS_DEPTH,
                       reliability=ReliabilityPolicy.RELIABLE))
        self._pub_segments = self.create_publisher(PointCloud2, "~/segments", qos_out)
        self._pub_reconstruction = self.create_publisher(PointCloud2, "~/reconstruction",
                                                         qos_out)
        self._pub_diagnostics = None
        self._diag_lock = threading.Lock()
        if self._options.diagnostics:
            self._ensure_diagnostics_publisher()

    # ---------------------------------------------------------------------------------
    # state
    # ---------------------------------------------------------------------------------

    @property
    def modeling_params(self) -> ModelingParams:
        """The parameters the next frame is modeled with."""
        return self._params

    @property
    def options(self) -> NodeOptions:
        return self._options

    @property
    def tracker_config(self) -> TrackerConfig:
        """The tracker parameters the next frame is tracked with."""
        return self._tracker_config

    def stats(self) -> FrameStats:
        """Return a snapshot of the frame counters."""
        with self._stats_lock:
            return replace(self._stats, last_timing=dict(self._stats.last_timing))

    # ---------------------------------------------------------------------------------
    # parameters
    # ---------------------------------------------------------------------------------

    def _transform_source(self, given: Any) -> Any:
        """Return where ``sensor_frame``'s pose is looked up (None without one)."""
        if not self._options.sensor_frame:
            return None
        if given is not None:
            return given
        try:
            from tf2_ros import Buffer, TransformListener
        except ImportError as exc:
            raise ParameterError(
                f"parameter 'sensor_frame' = {self._options.sensor_frame!r} needs tf2_ros "
                f"(ros-jazzy-tf2-ros), which cannot be imported here ({exc})") from None
        buffer = Buffer()
        self._transform_listener = TransformListener(buffer, self)
        return buffer

    def _sensor_pose(self, msg: PointCloud2 | Image) -> SensorPose | None:
        """Return the sensor's pose in ``msg``'s frame (``sensor_frame``), or None.

        None when no ``sensor_frame`` is set or the message is in it. Raises LookupError
        (with tf2's reason) when the transform is not known within TF_TIMEOUT_S or is no
        rigid transform.
        """
        sensor_frame = self._options.sensor_frame
        frame_id = header_of(msg).frame_id
        if not sensor_frame or frame_id == sensor_frame:
            return None
        try:
            found = self._transforms.lookup_transform(
                frame_id, sensor_frame, RosTime.from_msg(msg.header.stamp),
                timeout=Duration(seconds=TF_TIMEOUT_S))
            t, q = found.transform.translation, found.transform.rotation
            return SensorPose.from_transform((t.x, t.y, t.z), (q.x, q.y, q.z, q.w))
        except Exception as exc:  # noqa: BLE001 - tf2's lookup, connectivity, timing errors
            raise LookupError(f"{type(exc).__name__}: {exc}") from exc

    def _initial_parameters(self) -> tuple[ModelingParams, NodeOptions]:
        self.declare_parameters("", [(p.name, p.default, spec_descriptor(p))
                                     for p in PARAMETERS])
        self.declare_parameters("", [(p.name, p.default, _option_descriptor(p))
                                     for p in NODE_PARAMETERS])
        self.declare_parameters("", [(p.name, p.default, spec_descriptor(p))
                                     for p in NODE_NUMERIC_PARAMETERS + TRACKING_PARAMETERS])
        # Initial values are checked as a whole (the per-parameter callbacks are registered
        # afterwards, so that e.g. min_radius and max_radius can both move in the YAML).
        params = ModelingParams.from_mapping(
            {p.name: self.get_parameter(p.name).value for p in PARAMETERS})
        options = NodeOptions(**{p.name: self.get_parameter(p.name).value
                                 for p in NODE_PARAMETERS},
                              **{p.name: p.check(self.get_parameter(p.name).value)
                                 for p in NODE_NUMERIC_PARAMETERS})
        for name, allowed in (("qos_reliability", RELIABILITY_MODES), ("input", INPUTS)):
            if getattr(options, name) not in allowed:
                raise ParameterError(
                    f"parameter '{name}' = {getattr(options, name)!r} is not allowed; use "
                    f"one of: {', '.join(allowed)}")
        _check_rate_band(options)
        self._tracker_config = self._tracker_config_with(
            {p.name: self.get_parameter(p.name).value for p in TRACKING_PARAMETERS},
            TrackerConfig())
        return params, options

    @staticmethod
    def _tracker_config_with(changes: dict[str, Any], base: TrackerConfig) -> TrackerConfig:
        """Return ``base`` with the ``tracking_*`` values of ``changes`` (or ParameterError)."""
        fields = {k[len(_TRACKING_PREFIX):]: v for k, v in changes.items()}
        return replace(base, **fields) if fields else base

    def _validate_parameters(self, parameters: list[Parameter]):
        """Accept or reject a set of parameters; no side effects."""
        changes = {p.name: p.value for p in parameters if p.name in self._spec_names}
        if changes:
            try:
                ModelingParams.from_mapping(changes, base=self._params)
            except ParameterError as exc:
                return set_parameters_result(str(exc))
        try:
            self._tracker_config_with(self._tracking_changes(parameters), self._tracker_config)
            numeric = {p.name: self._numeric_specs[p.name].check(p.value) for p in parameters
                       if p.name in self._numeric_specs}
            _check_rate_band(replace(self._options, **numeric))
        except ParameterError as exc:
            return set_parameters_result(str(exc))
        return set_parameters_result()

    def _tracking_changes(self, parameters: list[Parameter]) -> dict[str, Any]:
        return {p.name: p.value for p in parameters if p.name in self._tracking_specs}

    def _apply_parameters(self, parameters: list[Parameter]) -> None:
        """Make accepted parameters effective (from the next frame on)."""
        changes = {p.name: p.value for p in parameters if p.name in self._spec_names}
        if changes:
            try:
                self._params = ModelingParams.from_mapping(changes, base=self._params)
            except ParameterError as exc:  # only if two sets raced; keep the old ones
                self.get_logger().error(f"parameter update not applied: {exc}")
                return
        tracking = self._tracking_changes(parameters)
        if tracking:
            self._tracker_config = self._tracker_config_with(tracking, self._tracker_config)
        options = {p.name: p.value for p in parameters if p.name in self._option_names}
        if options:
            self._options = replace(self._options, **options)
            if self._options.diagnostics:
                self._ensure_diagnostics_publisher()
        updated = ", ".join(f"{p.name}={p.value!r}" for p in parameters)
        self.get_logger().info(f"parameters updated: {updated}")

    def _ensure_diagnostics_publisher(self) -> None:
        with self._diag_lock:
            if self._pub_diagnostics is None:
                self._pub_diagnostics = self.create_publisher(DiagnosticArray, "/diagnostics",
                                                              10)

    # ---------------------------------------------------------------------------------
    # input
    # ---------------------------------------------------------------------------------

    def _start_processes(self, workers: int) -> ProcessModeler | None:
        """Start ``workers`` modeling processes; None (logged) if they cannot start."""
        processes = ProcessModeler(workers)
        try:
            processes.start()
        except Exception as exc:  # noqa: BLE001 - the node still models, in its process
            processes.close()
            self.get_logger().error(
                f"could not start {workers} modeling processes ({type(exc).__name__}: {exc});"
                " modeling in the node's own process")
            return None
        return processes

    def _on_camera_info(self, msg: CameraInfo) -> None:
        self._camera_info = msg  # the latest one; read by the next image

    def _on_image(self, msg: Image) -> None:
        info = self._camera_info
        if info is None:
            with self._stats_lock:
                self._stats.received += 1
                self._stats.failed += 1
            self.get_logger().warning(
                f"depth image {_stamp(msg)} dropped: no CameraInfo received yet on "
                f"'{self._inputs[1].topic_name}' (is it remapped next to the image?)",
                throttle_duration_sec=WARN_THROTTLE_S)
            return
        self._on_cloud(msg, lambda image: depth_to_scene(image, info))

    def _on_cloud(self, msg: PointCloud2 | Image, to_scene=cloud_to_scene) -> None:
        with self._detect_lock:
            requests, self._detect_pending = self._detect_pending, []
        if not requests and not self._options.continuous:
            with self._stats_lock:
                self._stats.received += 1
                self._stats.ignored += 1
            return
        replaced = self._mailbox.put((msg, to_scene, time.monotonic(), requests))
        if replaced is not None:
            requests.extend(replaced[3])  # the newer frame answers them
        with self._stats_lock:
            self._stats.received += 1
            if replaced is not None:
                self._stats.dropped += 1
            dropped = self._stats.dropped
            took = self._stats.last_timing.get("total_s", math.nan)
        if replaced is not None:
            took_s = "first frame still in progress" if math.isnan(took) else \
                f"last frame took {took:.3f} s"
            self.get_logger().warning(
                f"input is faster than processing ({took_s}): only the newest frame is "
                f"modeled, {dropped} dropped so far", throttle_duration_sec=WARN_THROTTLE_S)

    # ---------------------------------------------------------------------------------
    # worker
    # ---------------------------------------------------------------------------------

    def _run(self) -> None:
        while True:
            taken = self._mailbox.take()
            if taken is None:
                return
            (msg, to_scene, received_at, requests), ticket = taken
            outcome = (False, f"frame {_stamp(msg)} failed (see the node's log)")
            try:
                outcome = self._process(msg, to_scene, received_at, ticket)
            except Exception as exc:  # noqa: BLE001 - the worker must outlive any frame
                if self._closing:
                    return
                self._count_failure()
                self.get_logger().error(
                    f"frame {_stamp(msg)} modeled but its outputs could not be published: "
                    f"{type(exc).__name__}: {exc}", throttle_duration_sec=WARN_THROTTLE_S)
            finally:
                self._turns.done(ticket)
                for request in requests:
                    request.finish(*outcome)

    def _count_failure(self) -> None:
        with self._stats_lock:
            self._stats.failed += 1

    def _model(self, msg: PointCloud2 | Image, to_scene, params: ModelingParams
               ) -> ModeledFrame | None:
        """Read and model the frame (:func:`model_frame`); None (logged) if it failed."""
        try:
            sensor = self._sensor_pose(msg)
        except LookupError as exc:
            self._count_failure()
            frame_id = header_of(msg).frame_id
            self.get_logger().warning(
                f"frame '{frame_id}' {_stamp(msg)} skipped: no transform from sensor_frame "
                f"'{self._options.sensor_frame}' to '{frame_id}' at its stamp ({exc})",
                throttle_duration_sec=WARN_THROTTLE_S)
            return None
        try:
            return model_frame(msg, params, model_scene=self._model_scene, to_scene=to_scene,
                               sensor=sensor)
        except (PointCloud2Error, DepthImageError) as exc:
            self._count_failure()
            frame_id, _ = header_of(msg)
            kind = "depth image" if isinstance(exc, DepthImageError) else "PointCloud2"
            self.get_logger().warning(
                f"skipping malformed {kind} (frame '{frame_id}', stamp "
                f"{_stamp(msg)}): {exc}", throttle_duration_sec=WARN_THROTTLE_S)
        except ModelingError as exc:
            self._count_failure()
            frame_id, _ = header_of(msg)
            self.get_logger().warning(
                f"modeling failed on frame '{frame_id}' {_stamp(msg)} "
                f"({exc.valid_points} points), frame skipped: {exc}",
                throttle_duration_sec=WARN_THROTTLE_S)
            self.get_logger().debug("".join(traceback.format_exception(exc.__cause__ or exc)))
        return None

    def _publish_objects(self, markers: MarkerArray, objects: PrimitiveArray) -> None:
        """Publish a frame's typed objects and markers (before its clouds are built)."""
        self._pub_objects.publish(objects)
        if markers.markers:  # tracked and nothing changed: no headerless empty array
            self._pub_markers.publish(markers)

    def _current_tracking(self, enabled: bool) -> ObjectTracking | None:
        """Return the worker's tracking state with the current config (None: disabled)."""
        if not enabled:
            self._tracking_on = False
            return None
        if self._tracking is None:
            self._tracking = ObjectTracking(self._tracker_config)
        elif not self._tracking_on:  # switched on again: old tracks are stale; ids go on
            self._tracking.reset()
        self._tracking_on = True
        self._tracking.tracker.config = self._tracker_config
        return self._tracking

    def _process(self, msg: PointCloud2 | Image, to_scene, received_at: float, ticket: int
                 ) -> tuple[bool, str]:
        """Model and publish one frame; return (success, summary) for ``~/detect``.

        The modeling runs at once with other workers' frames; tracking and publishing wait
        for ``ticket``'s turn.
        """
        t0 = time.perf_counter()
        params = self._params
        modeled = self._model(msg, to_scene, params)
        if modeled is None:
            return False, f"frame {_stamp(msg)} was malformed or failed (see the node's log)"
        t_wait = time.perf_counter()
        if not self._turns.wait(ticket):
            return False, f"frame {_stamp(msg)} abandoned: the node is shutting down"
        t_turn = time.perf_counter()
        options = self._options
        frame = finish_frame(modeled, params, segments=options.publish_segments,
                             reconstruction=options.publish_reconstruction,
                             tracking=self._current_tracking(options.tracking),
                             on_objects=self._publish_objects)
        t5 = time.perf_counter()
        timing = {k: v for k, v in frame.timing.items() if not k.startswith("core_")}
        core_timing = {k: v for k, v in frame.timing.items() if k.startswith("core_")}

        # The typed objects and markers went out as soon as they were built
        # (:meth:`_publish_objects`); the clouds follow.
        if frame.segments is not None:
            self._pub_segments.publish(frame.segments)
        if frame.reconstruction is not None:
            self._pub_reconstruction.publish(frame.reconstruction)
        t6 = time.perf_counter()
        timing["publish_s"] = t6 - t5
        timing["turn_s"] = t_turn - t_wait
        timing["total_s"] = t6 - t0
        latency = time.monotonic() - received_at
        with self._stats_lock:
            self._stats.processed += 1
            self._stats.last_latency_s = latency
            self._stats.last_timing = timing
            self._frame_values = frame.diagnostics
            self._stats.last_stamp_ns = stamp_ns(msg)
            self._processed_at.append(time.monotonic())
        stages = ", ".join(f"{k[:-2]} {1000 * v:.1f}" for k, v in {**timing, **core_timing}.items())
        self.get_logger().debug(
            f"frame {_stamp(msg)}: {frame.valid_points} points, "
            f"{len(frame.result.objects)} objects, "
            f"latency {1000 * latency:.1f} ms ({stages} ms)")
        return True, _summary(frame, _stamp(msg))

    # ---------------------------------------------------------------------------------
    # on-demand detection
    # ---------------------------------------------------------------------------------

    async def _on_detect(self, request: Trigger.Request, response: Trigger.Response
                         ) -> Trigger.Response:
        """Answer with the summary of the next frame processed (or a timeout).

        A coroutine: the executor goes on receiving frames while the call waits, so the
        node needs only one executor thread.
        """
        del request  # Trigger's request is empty
        pending = _DetectRequest(self._wake_executor)
        with self._detect_lock:
            self._detect_pending.append(pending)
        timeout = self._options.detect_timeout
        deadline = time.monotonic() + timeout
        # Wakes the executor at the deadline even when nothing else arrives.
        timer = self.create_timer(timeout, lambda: None)
        try:
            while not pending.done.is_set() and time.monotonic() < deadline:
                await _NextWake()
        finally:
            self.destroy_timer(timer)
        if not pending.done.is_set():
            with self._detect_lock:
                if pending in self._detect_pending:
                    self._detect_pending.remove(pending)
        if pending.done.is_set():  # (also when it finished just before the removal)
            response.success, response.message = pending.success, pending.message
            return response
        response.success = False
        response.message = f"no frame was processed within detect_timeout = {timeout} s"
        return response

    def _wake_executor(self) -> None:
        """Wake the executor spinning this node (a ``~/detect`` call has its answer)."""
        executor = self.executor
        if executor is not None:
            try:
                executor.wake()
            except InvalidHandle:  # shut down meanwhile: no call waits any more
                pass

    # ---------------------------------------------------------------------------------
    # diagnostics
    # ---------------------------------------------------------------------------------

    def _rate(self, now: float, window: float) -> float | None:
        """Frames processed per second over the last ``window`` [s]; None before a window."""
        with self._stats_lock:
            self._processed_at = [t for t in self._processed_at if t > now - window]
            count = len(self._processed_at)
        if now - self._started_at < window:
            return None
        return count / window

    def _diagnostic_level(self, s: FrameStats, failed_prev: int, rate: float | None,
                          age: float | None) -> tuple[str, str]:
        """(level, message): WARN for failures, a rate outside the band or stale results."""
        o = self._options
        if s.failed > failed_prev:
            return "warn", "frames failed"
        if rate is not None and o.continuous and not (
                o.expected_rate_min <= rate <= o.expected_rate_max):
            return "warn", (f"processing rate {rate:.2f} Hz outside the expected "
                            f"[{o.expected_rate_min}, {o.expected_rate_max}] Hz")
        if age is not None and o.continuous and o.max_result_age > 0 and \
                age > o.max_result_age:
            return "warn", f"newest result is {age:.2f} s old (max_result_age {o.max_result_age} s)"
        return "ok", "ok"

    def _publish_diagnostics(self) -> None:
        if not self._options.diagnostics or self._pub_diagnostics is None:
            return
        now = time.monotonic()
        s = self.stats()
        _, _, _, failed_prev = self._diag_last
        self._diag_last = (now, s.processed, s.dropped, s.failed)
        # Two periods of the slowest expected rate: a slow node still has frames in it.
        window = min(RATE_WINDOW_MAX_S,
                     max(RATE_WINDOW_MIN_S, 2.0 / max(self._options.expected_rate_min, 1e-9)))
        rate = self._rate(now, window)
        clock_ns = self.get_clock().now().nanoseconds
        age = (clock_ns - s.last_stamp_ns) / 1e9 if s.last_stamp_ns >= 0 else None
        level, message = self._diagnostic_level(s, failed_prev, rate, age)
        values = {
            "rate_hz": "nan" if rate is None else f"{rate:.2f}",
            "rate_window_s": f"{window:.2f}",
            "frames_received": str(s.received),
            "frames_processed": str(s.processed),
            "frames_dropped": str(s.dropped),
            "frames_ignored": str(s.ignored),
            "frames_failed": str(s.failed),
            "last_latency_s": f"{s.last_latency_s:.4f}",
            "last_processing_s": f"{s.last_timing.get('total_s', math.nan):.4f}",
            "result_age_s": "nan" if age is None else f"{age:.4f}",
            "mode": "continuous" if self._options.continuous else "on demand",
            **getattr(self, "_frame_values", {}),
        }
        # stamped with the time of this report
        self._pub_diagnostics.publish(diagnostics_message(
            f"{self.get_name()}: modeling", self.get_fully_qualified_name(), level, message,
            values, clock_ns))

    # ---------------------------------------------------------------------------------
    # shutdown
    # ---------------------------------------------------------------------------------

    def destroy_node(self) -> None:
        """Stop the workers (waiting for frames in progress) and destroy the node.

        Waits up to :data:`WORKER_JOIN_TIMEOUT_S` in all; ``frames_abandoned`` then counts
        the workers still modeling a frame.
        """
        self._closing = True
        self._mailbox.close()
        deadline = time.monotonic() + WORKER_JOIN_TIMEOUT_S
        others = [w for w in self._workers if w is not threading.current_thread()]
        for worker in others:
            worker.join(max(0.0, deadline - time.monotonic()))
        self.frames_abandoned = sum(worker.is_alive() for worker in others)
        self._turns.close()
        if self._processes is not None:
            self._processes.close()
        self._wait_for_acks(time.monotonic() + ACK_TIMEOUT_S)
        super().destroy_node()

    def _wait_for_acks(self, deadline: float) -> None:
        """Wait until the subscribers acknowledged every reliable publisher's data, or ``deadline``.

        The process crashed at exit inside ``destroy_publisher`` (SIGSEGV, seen under load
        with the fault handler's stacks, no other Python thread busy); a large message the
        middleware still sends (a segments or reconstruction cloud in fragments) is the
        suspected cause, not proven: the wait leaves none in flight.
        """
        for pub in list(self.publishers):
            left = deadline - time.monotonic()
            if left <= 0.0:
                return
            try:
                pub.wait_for_all_acked(Duration(nanoseconds=int(left * 1e9)))
            except (InvalidHandle, RuntimeError):  # already gone, or the middleware cannot tell
                pass


def _check_rate_band(options: NodeOptions) -> None:
    """Raise ParameterError unless ``expected_rate_min <= expected_rate_max``."""
    if options.expected_rate_min > options.expected_rate_max:
        raise ParameterError(
            f"expected_rate_min ({options.expected_rate_min} Hz) must not exceed "
            f"expected_rate_max ({options.expected_rate_max} Hz)")


def main(args: list[str] | None = None) -> int:
    """Entry point of ``ros2 run geomodel_ros modeler``; returns the exit status.

    A crash in native code (numpy, open3d, the middleware) prints every thread's Python
    stack to stderr (:mod:`faulthandler`) before the process dies.
    """
    _enable_fault_handler()
    retain_freed_memory()
    rclpy.init(args=args)
    node: ModelerNode | None = None
    try:
        node = ModelerNode()
        # One thread: callbacks only hand frames over (~/detect waits as a coroutine); a
        # multi-threaded executor re-scans its wait set several times per message in
        # Python, which at 30 Hz costs a third of a core and starves the modeling.
        rclpy.spin(node, executor=SingleThreadedExecutor())
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except (ParameterError, ParameterException) as exc:
        get_logger("modeler").error(f"invalid parameters: {exc}")
        return 2
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
    if node is not None and node.frames_abandoned:
        _exit_now(0, f"{node.frames_abandoned} frame(s) still being modeled after "
                     f"{WORKER_JOIN_TIMEOUT_S:g} s, abandoned")
    return 0


def _enable_fault_handler() -> None:
    """Have a fatal signal print every thread's Python stack to stderr, where it can."""
    try:
        faulthandler.enable(all_threads=True)
    except (AttributeError, ValueError, OSError, RuntimeError):  # no usable stderr
        pass


def _exit_now(status: int, reason: str) -> None:
    """Exit the process with ``status`` at once, without finalizing the interpreter.

    A worker thread still modeling a frame may be inside numpy or open3d; tearing the
    modules down under it can crash the process at exit.
    """
    get_logger("modeler").warning(f"exiting: {reason}")
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):  # closed or broken pipe: nothing to keep
            pass
    os._exit(status)


if __name__ == "__main__":
    raise SystemExit(main())
