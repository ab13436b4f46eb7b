"""rosbag2 files: synthetic bags, offline processing through the node's chain, replay.

* :func:`write_synth_bag` renders synthetic scenes into a rosbag2 (MCAP or sqlite3) of
  organized ``sensor_msgs/PointCloud2`` frames, with the ground truth in ``<bag>.json``.
* :func:`process_bag` runs every cloud of a topic through
  :func:`geomodel_ros.ros.processing.process_cloud` -- exactly what the ``modeler`` node does
  with a frame -- and writes the input topic plus the node's output topics to a new bag.
* :func:`play` publishes a bag's PointCloud2 records into DDS at the recorded rate, as
  serialized bytes (no deserialization), like ``ros2 bag play``.

Bags are read and written with ``rosbags`` (pure Python; ``rosbag2_py`` is not needed).
Messages are built, read and (de)serialized only through :mod:`msg_adapters` (no
``rclpy.init`` needed); only :func:`play` starts DDS.
"""

from __future__ import annotations

import json
import math
import os
import threading
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from rosbags.interfaces import (Connection, Qos, QosDurability, QosHistory, QosLiveliness,
                                QosReliability, QosTime)
from rosbags.rosbag2 import Reader, StoragePlugin, Writer
from rosbags.typesys import Stores, get_typestore

from geomodel_ros.ros.processing import (FrameResult, ModelingError, SceneModeler,
                                         process_cloud)

from geomodel_ros.core.params import ModelingParams
from geomodel_ros.core.modeling import model_scene as core_model_scene
from geomodel_ros.core.viewpoint import SensorPose

from msg_adapters.header import make_header
from msg_adapters.interfaces import PointCloud2
from msg_adapters.pointcloud2 import PointCloud2Error, xyz_to_cloud
from msg_adapters.serialization import (OBJECTS_TYPE, DeserializationError, deserialize_cloud,
                                        geomodel_typestore, serialize, serialize_objects)

__all__ = [
    "BagError",
    "BagSummary",
    "DEFAULT_FRAME_ID",
    "DEFAULT_TOPIC",
    "MARKER_ARRAY",
    "OUTPUT_NAMESPACE",
    "PLAY_QOS_DEPTH",
    "POINTCLOUD2",
    "PRIMITIVE_ARRAY",
    "STORAGES",
    "SYNTH_START_NS",
    "ground_truth_path",
    "play",
    "pointcloud_topics",
    "process_bag",
    "write_synth_bag",
]

POINTCLOUD2 = "sensor_msgs/msg/PointCloud2"
MARKER_ARRAY = "visualization_msgs/msg/MarkerArray"
#: The typed objects (``~/objects``), a type of this repository's ``geomodel_msgs``.
PRIMITIVE_ARRAY = OBJECTS_TYPE
#: Topic and frame of the synthetic bags (a typical RGB-D driver's names).
DEFAULT_TOPIC = "/camera/depth/points"
DEFAULT_FRAME_ID = "camera_depth_optical_frame"
#: Header stamp and bag time of the first synthetic frame: 2026-01-01T00:00:00Z [ns].
SYNTH_START_NS = 1_767_225_600 * 10**9
#: Namespace of the output topics, as published by the node ``/modeler``.
OUTPUT_NAMESPACE = "/modeler"
#: Storage plugins by name (``rosbag2``'s storage ids).
STORAGES: Mapping[str, StoragePlugin] = {"mcap": StoragePlugin.MCAP,
                                         "sqlite3": StoragePlugin.SQLITE3}
#: History depth of the replay publishers: ``ros2 bag play``'s default offer is
#: rmw_qos_profile_default's depth (keep last 10), reliable, volatile -- or the recorded
#: reliability/durability when every recorded publisher offered the same.
PLAY_QOS_DEPTH = 10
#: After the last record, how long [s] replay waits for reliable readers to acknowledge
#: everything before the publishers go (a multi-MB cloud takes well under a second on
#: loopback; readers that never answer must not hold the tool).
ACK_TIMEOUT_S = 5.0

_TYPESTORE = get_typestore(Stores.ROS2_JAZZY)
#: Jazzy's types plus geomodel_msgs (registered from the .msg definitions), for the objects.
_OBJECTS_TYPESTORE = geomodel_typestore()
_ZERO = QosTime(0, 0)  # "default" duration


class BagError(Exception):
    """A bag that cannot be read or written, or a topic that is missing or ambiguous."""


def _qos(reliability: QosReliability, depth: int) -> Qos:
    return Qos(QosHistory.KEEP_LAST, depth, reliability, QosDurability.VOLATILE, _ZERO, _ZERO,
               QosLiveliness.AUTOMATIC, _ZERO, False)


#: What the node's output publishers offer (reliable, keep last ``qos_depth`` = 1).
_NODE_OUTPUT_QOS = _qos(QosReliability.RELIABLE, 1)
#: What the synthetic "camera" offers (a reliable driver publisher).
_SYNTH_QOS = _qos(QosReliability.RELIABLE, 10)


def ground_truth_path(bag: str | os.PathLike[str]) -> Path:
    """``<bag>.json``: the ground-truth file written beside a synthetic bag."""
    return Path(str(Path(bag)) + ".json")


def _storage_plugin(storage: str) -> StoragePlugin:
    try:
        return STORAGES[storage]
    except KeyError:
        raise BagError(f"storage {storage!r} is not supported; use one of: "
                       f"{', '.join(STORAGES)}") from None


def _open_writer(path: Path, storage: str) -> Writer:
    plugin = _storage_plugin(storage)
    try:
        writer = Writer(path, version=Writer.VERSION_LATEST, storage_plugin=plugin)
        writer.open()
    except Exception as exc:  # WriterError (exists), OSError (permissions, ...)
        raise BagError(f"cannot create bag {path}: {exc}") from None
    return writer


def _close_writer(writer: Writer) -> None:
    if writer.storage is not None:
        writer.close()


# ---------------------------------------------------------------------------------------
# synthetic bags
# ---------------------------------------------------------------------------------------

def write_synth_bag(path: str | os.PathLike[str], names: Sequence[str], *, frames: int = 3,
                    rate: float = 10.0, noise: bool = False, seed: int = 1,
                    topic: str = DEFAULT_TOPIC, frame_id: str = DEFAULT_FRAME_ID,
                    storage: str = "mcap") -> dict:
    """Render synthetic scenes into a rosbag2 of organized PointCloud2 frames.

    Parameters
    ----------
    path : path
        The bag directory to create (must not exist).  The ground truth goes to
        :func:`ground_truth_path` (``<path>.json``).
    names : sequence of str
        Scenes (:data:`geomodel_ros.tools.synth.SCENE_NAMES`), recorded one after the other.
    frames : int
        Frames per scene (>= 1).
    rate : float
        Frame rate [Hz] (> 0): frame ``k`` (counted over all scenes) has header stamp and
        bag time ``SYNTH_START_NS + k / rate``.
    noise : bool
        Add :data:`geomodel_ros.tools.synth.SENSOR_NOISE`, drawn anew for every frame from one
        generator seeded with ``seed``.
    topic, frame_id : str
        Topic of the clouds and ``header.frame_id`` (the sensor's optical frame).
    storage : {"mcap", "sqlite3"}

    Returns
    -------
    dict
        The ground truth as written to the JSON: ``topic``, ``frame_id``, ``rate_hz``,
        ``noise``, ``seed``, ``frames`` (total) and ``scenes``, each with ``name``,
        ``frames`` (global frame indices), ``stamps_ns``, ``intrinsics`` and ``objects``
        (``GroundTruthObject.to_dict()``, id = label value, 0 = the desk).

    Raises
    ------
    BagError
        If a scene name, ``frames``, ``rate`` or ``storage`` is invalid, or the bag cannot
        be created.

    Notes
    -----
    Clouds: ``height x width`` = the camera's image, float32 x, y, z [m] in the camera's
    optical frame (REP 103), NaN where the ray hit nothing or dropped out.
    """
    from geomodel_ros.tools.synth import SCENE_NAMES, SENSOR_NOISE, render_scene

    unknown = [n for n in names if n not in SCENE_NAMES]
    if not names or unknown:
        what = f"unknown scene {unknown[0]!r}" if unknown else "no scene given"
        raise BagError(f"{what}; choose from {', '.join(SCENE_NAMES)}")
    if int(frames) != frames or frames < 1:
        raise BagError(f"frames must be an integer >= 1, got {frames!r}")
    if not math.isfinite(rate) or rate <= 0.0:
        raise BagError(f"rate must be a finite number > 0 [Hz], got {rate!r}")
    _storage_plugin(storage)  # checked before anything is created
    rng = np.random.default_rng(seed)
    period_ns = 1e9 / rate
    truth: dict[str, Any] = {"topic": topic, "frame_id": frame_id, "rate_hz": float(rate),
                             "noise": bool(noise), "seed": int(seed), "storage": storage,
                             "frames": 0, "scenes": []}
    out = Path(path)
    writer = _open_writer(out, storage)
    k = 0
    try:
        conn = writer.add_connection(topic, POINTCLOUD2, typestore=_TYPESTORE,
                                     offered_qos_profiles=[_SYNTH_QOS])
        for name in names:
            entry: dict[str, Any] = {"name": name, "frames": [], "stamps_ns": []}
            for _ in range(int(frames)):
                scene = render_scene(name, noise=SENSOR_NOISE if noise else None, rng=rng)
                t_ns = SYNTH_START_NS + int(round(k * period_ns))
                msg = xyz_to_cloud(scene.organized.astype(np.float32),
                                   make_header(frame_id, t_ns))
                writer.write(conn, t_ns, serialize(msg))
                entry["frames"].append(k)
                entry["stamps_ns"].append(t_ns)
                k += 1
            entry["intrinsics"] = scene.intrinsics
            entry["objects"] = [o.to_dict() for o in scene.objects]
            truth["scenes"].append(entry)
    finally:
        _close_writer(writer)
    truth["frames"] = k
    ground_truth_path(out).write_text(json.dumps(truth, indent=2))
    return truth


# ---------------------------------------------------------------------------------------
# reading
# ---------------------------------------------------------------------------------------

def _open_reader(path: Path) -> Reader:
    if not path.exists():
        raise BagError(f"bag {path} does not exist")
    try:
        reader = Reader(path)
        reader.open()
    except Exception as exc:  # ReaderError, FileNotFoundError, struct/sqlite errors, ...
        raise BagError(f"cannot read bag {path}: {_describe(exc)}") from None
    return reader


def _describe(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()
    return text[0] if text else type(exc).__name__


def _messages(reader: Reader, path: Path, connections: Sequence[Connection]
              ) -> Iterator[tuple[Connection, int, bytes]]:
    """Yield the reader's records, with any storage failure turned into :class:`BagError`."""
    it = reader.messages(connections=connections)
    while True:
        try:
            conn, t_ns, raw = next(it)
        except StopIteration:
            return
        except Exception as exc:  # truncated / corrupt storage
            raise BagError(f"cannot read bag {path}: {_describe(exc)}") from None
        yield conn, t_ns, raw if isinstance(raw, bytes) else bytes(raw)


def pointcloud_topics(path: str | os.PathLike[str]) -> dict[str, int]:
    """PointCloud2 topics of a bag and their message counts.

    Raises
    ------
    BagError
        If the bag cannot be read.
    """
    reader = _open_reader(Path(path))
    try:
        return {name: info.msgcount for name, info in reader.topics.items()
                if info.msgtype == POINTCLOUD2}
    finally:
        reader.close()


def _select_topics(reader: Reader, path: Path, topics: Sequence[str] | None,
                   single: bool) -> list[str]:
    infos = reader.topics
    clouds = sorted(t for t, info in infos.items() if info.msgtype == POINTCLOUD2)
    listing = ", ".join(f"{t} ({info.msgtype})" for t, info in sorted(infos.items())) or "none"
    if topics:
        for t in topics:
            if t not in infos:
                raise BagError(f"topic {t!r} is not in bag {path}; its topics: {listing}")
            if infos[t].msgtype != POINTCLOUD2:
                raise BagError(f"topic {t!r} in bag {path} is {infos[t].msgtype}, not "
                               f"{POINTCLOUD2}; its topics: {listing}")
        return list(dict.fromkeys(topics))
    if not clouds:
        raise BagError(f"bag {path} has no {POINTCLOUD2} topic; its topics: {listing}")
    if single and len(clouds) > 1:
        raise BagError(f"bag {path} has {len(clouds)} {POINTCLOUD2} topics "
                       f"({', '.join(clouds)}); choose one with --topic")
    return clouds


def _input_storage(path: Path) -> str:
    if path.is_dir():
        suffixes = {p.suffix for p in path.iterdir()}
        return "sqlite3" if ".db3" in suffixes and ".mcap" not in suffixes else "mcap"
    return "sqlite3" if path.suffix == ".db3" else "mcap"


# ---------------------------------------------------------------------------------------
# offline processing
# ---------------------------------------------------------------------------------------

@dataclass
class BagSummary:
    """What :func:`process_bag` did.

    Attributes
    ----------
    topic : str
        The input topic.
    frames : int
        Clouds read from the input topic.
    processed : int
        Clouds whose outputs were written.
    skipped : list of str
        One reason per cloud that was skipped (malformed message, core failure).
    output_topics : dict[str, int]
        Messages written per topic of the output bag.
    seconds : float
        Wall time [s].
    """

    topic: str
    frames: int = 0
    processed: int = 0
    skipped: list[str] = field(default_factory=list)
    output_topics: dict[str, int] = field(default_factory=dict)
    seconds: float = 0.0


@dataclass(frozen=True)
class _Outputs:
    """Connections of the output bag: the copied input and the node's output topics."""

    cloud: Connection
    markers: Connection
    objects: Connection
    segments: Connection | None
    reconstruction: Connection | None


def _add_outputs(writer: Writer, name: str, conns: Sequence[Connection], ns: str,
                 segments: bool, reconstruction: bool) -> _Outputs:
    """Create the output bag's connections (input QoS kept, outputs as the node offers)."""
    qos = conns[0].ext.offered_qos_profiles if hasattr(conns[0].ext,
                                                      "offered_qos_profiles") else []

    def add(topic: str, msgtype: str) -> Connection:
        store = _OBJECTS_TYPESTORE if msgtype == PRIMITIVE_ARRAY else _TYPESTORE
        return writer.add_connection(topic, msgtype, typestore=store,
                                     offered_qos_profiles=[_NODE_OUTPUT_QOS])

    return _Outputs(
        cloud=writer.add_connection(name, POINTCLOUD2, typestore=_TYPESTORE,
                                    offered_qos_profiles=qos),
        markers=add(f"{ns}/primitives", MARKER_ARRAY),
        objects=add(f"{ns}/objects", PRIMITIVE_ARRAY),
        segments=add(f"{ns}/segments", POINTCLOUD2) if segments else None,
        reconstruction=add(f"{ns}/reconstruction", POINTCLOUD2) if reconstruction else None)


def _model_record(raw: bytes, params: ModelingParams, segments: bool, reconstruction: bool,
                  model_scene: SceneModeler, sensor: SensorPose | None
                  ) -> tuple[FrameResult | None, str | None]:
    """Model one serialized cloud: the node's outputs, or None and why it was skipped."""
    try:
        msg = deserialize_cloud(raw)
        return process_cloud(msg, params, segments=segments, reconstruction=reconstruction,
                             model_scene=model_scene, sensor=sensor), None
    except PointCloud2Error as exc:
        return None, f"malformed PointCloud2: {exc}"
    except ModelingError as exc:
        return None, f"modeling failed: {exc}"
    except DeserializationError as exc:
        return None, f"cannot deserialize PointCloud2: {exc}"


def _write_outputs(writer: Writer, outs: _Outputs, t_ns: int, frame: FrameResult) -> None:
    writer.write(outs.markers, t_ns, serialize(frame.markers))
    if frame.objects is not None:
        # rosbags' serializer: rclpy's pads empty float64 sequences (see serialize_objects)
        writer.write(outs.objects, t_ns, serialize_objects(frame.objects))
    if outs.segments is not None and frame.segments is not None:
        writer.write(outs.segments, t_ns, serialize(frame.segments))
    if outs.reconstruction is not None and frame.reconstruction is not None:
        writer.write(outs.reconstruction, t_ns, serialize(frame.reconstruction))


def process_bag(src: str | os.PathLike[str], dst: str | os.PathLike[str], *,
                params: ModelingParams | None = None, topic: str | None = None,
                storage: str | None = None, namespace: str = OUTPUT_NAMESPACE,
                segments: bool = True, reconstruction: bool = True,
                progress: Callable[[int, int], None] | None = None,
                warn: Callable[[str], None] | None = None,
                model_scene: SceneModeler = core_model_scene,
                sensor: SensorPose | None = None) -> BagSummary:
    """Model every PointCloud2 of a bag offline, as the ``modeler`` node would.

    Parameters
    ----------
    src : path
        Input bag: a rosbag2 directory (MCAP or sqlite3) or a single ``.mcap``/``.db3``.
    dst : path
        Output bag directory (must not exist).
    params : ModelingParams, optional
        Defaults: ``ModelingParams()`` (the node's defaults).  Same parameters -> same
        output (the core is seeded by ``params.seed``).
    topic : str, optional
        The cloud topic; by default the bag's only PointCloud2 topic.
    storage : {"mcap", "sqlite3"}, optional
        Storage of the output; default: the input's.
    namespace : str
        Output topics are ``<namespace>/primitives`` (MarkerArray),
        ``<namespace>/objects`` (``geomodel_msgs/msg/PrimitiveArray``, the typed objects),
        ``<namespace>/segments`` and ``<namespace>/reconstruction`` (PointCloud2).
    segments, reconstruction : bool
        Write those two topics.
    progress : callable(k, n), optional
        Called after each cloud (``n`` = clouds on the topic).
    warn : callable(str), optional
        Called with a one-line reason for every skipped cloud.
    model_scene : SceneModeler
        The scene modeling (default: the core's ``model_scene``, as the node runs it).
    sensor : SensorPose, optional
        The sensor's pose in the clouds' frame, one for every cloud (a camera fixed on the
        robot's base, clouds in that base's frame; the node looks it up with tf2 per
        frame, ``sensor_frame``): each cloud is modeled from there, outputs in its frame.

    Returns
    -------
    BagSummary

    Raises
    ------
    BagError
        Input unreadable, corrupt or truncated; topic missing, not PointCloud2 or
        ambiguous; output not creatable.  Whatever was written before a read error stays
        a valid (closed) bag.

    Notes
    -----
    The output holds the input topic (raw records copied) and, per processed cloud, the
    node's outputs with the input's header (``frame_id``, ``stamp``) and the input
    record's bag time.  A malformed cloud is skipped (reported through ``warn``).  The
    objects' connection carries the ``geomodel_msgs`` definitions, so any rosbag2 reader
    can decode it.
    """
    params = params if params is not None else ModelingParams()
    src_path, dst_path = Path(src), Path(dst)
    ns = "/" + namespace.strip("/") if namespace.strip("/") else ""
    t_start = time.perf_counter()
    reader = _open_reader(src_path)
    try:
        (name,) = _select_topics(reader, src_path, [topic] if topic else None, single=True)
        summary = BagSummary(topic=name)
        conns = [c for c in reader.connections if c.topic == name]
        total = sum(c.msgcount for c in conns)
        writer = _open_writer(dst_path, storage or _input_storage(src_path))
        try:
            outs = _add_outputs(writer, name, conns, ns, segments, reconstruction)
            for _, t_ns, raw in _messages(reader, src_path, conns):
                summary.frames += 1
                writer.write(outs.cloud, t_ns, raw)
                frame, reason = _model_record(raw, params, segments, reconstruction,
                                              model_scene, sensor)
                if frame is None:
                    summary.skipped.append(f"message {summary.frames} (bag time {t_ns} ns) "
                                           f"skipped: {reason}")
                    if warn is not None:
                        warn(summary.skipped[-1])
                else:
                    _write_outputs(writer, outs, t_ns, frame)
                    summary.processed += 1
                if progress is not None:
                    progress(summary.frames, total)
        finally:
            summary.output_topics = {c.topic: writer.counts[c.id] for c in writer.connections}
            _close_writer(writer)
    finally:
        reader.close()
    summary.seconds = time.perf_counter() - t_start
    return summary


# ---------------------------------------------------------------------------------------
# replay
# ---------------------------------------------------------------------------------------

def _parse_remaps(remap: Mapping[str, str] | Sequence[str] | None) -> dict[str, str]:
    if remap is None:
        return {}
    if isinstance(remap, Mapping):
        return dict(remap)
    out = {}
    for item in remap:
        old, sep, new = item.partition(":=")
        if not sep or not old or not new:
            raise BagError(f"remap must look like OLD:=NEW, got {item!r}")
        out[old] = new
    return out


def _play_qos(conns: Sequence[Connection]):
    """Return the QoS ``ros2 bag play`` offers for a topic recorded with these connections."""
    from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

    reliability, durability = ReliabilityPolicy.RELIABLE, DurabilityPolicy.VOLATILE
    offers = [q for c in conns for q in getattr(c.ext, "offered_qos_profiles", [])]
    if offers and len({(q.reliability, q.durability) for q in offers}) == 1:
        if offers[0].reliability == QosReliability.BEST_EFFORT:
            reliability = ReliabilityPolicy.BEST_EFFORT
        if offers[0].durability == QosDurability.TRANSIENT_LOCAL:
            durability = DurabilityPolicy.TRANSIENT_LOCAL
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=PLAY_QOS_DEPTH,
                      reliability=reliability, durability=durability)


def _wait_for_subscribers(pubs: Mapping[str, Any], wait_timeout: float,
                          min_subscribers: int, stop: threading.Event) -> bool:
    """Wait until a publisher has ``min_subscribers``; False if ``stop`` was set first.

    Raises
    ------
    BagError
        If none has them after ``wait_timeout`` [s] (0: do not wait).
    """
    deadline = time.monotonic() + wait_timeout
    while wait_timeout > 0 and max(p.get_subscription_count() for p in pubs.values()) \
            < min_subscribers:
        if time.monotonic() > deadline:
            raise BagError(
                f"no subscriber on {', '.join(p.topic_name for p in pubs.values())} "
                f"after {wait_timeout:g} s; start the consumer first (same "
                f"ROS_DOMAIN_ID) or use --remap")
        if stop.wait(0.01):
            return False
    return True


def _publish_once(reader: Reader, bag: Path, conns: Sequence[Connection],
                  pubs: Mapping[str, Any], rate: float, stop: threading.Event) -> int:
    """Publish the records once at the recorded rate / ``rate``; records published.

    The clock starts once the readers have acknowledged the first record (at most
    :data:`ACK_TIMEOUT_S`; at once for a best-effort publisher): a publisher sees a new
    reader before that reader has matched it, and a record sent in between reaches the
    reader only when the writer sends it again, together with the next record. A node
    that models only the newest of the frames waiting (the modeler) then drops the first.
    """
    from rclpy.duration import Duration

    published = 0
    t0_bag: int | None = None
    t0_wall = time.monotonic()
    for conn, t_ns, raw in _messages(reader, bag, conns):
        if t0_bag is not None:
            delay = t0_wall + (t_ns - t0_bag) / 1e9 / rate - time.monotonic()
            if delay > 0 and stop.wait(delay):
                break
        pubs[conn.topic].publish(raw)
        published += 1
        if t0_bag is None:
            t0_bag = t_ns
            pubs[conn.topic].wait_for_all_acked(Duration(seconds=ACK_TIMEOUT_S))
            t0_wall = time.monotonic()
    return published


def play(path: str | os.PathLike[str], *, rate: float = 1.0, loop: bool = False,
         topics: Sequence[str] | None = None,
         remap: Mapping[str, str] | Sequence[str] | None = None, context: Any = None,
         wait_timeout: float = 10.0, stop: threading.Event | None = None,
         min_subscribers: int = 1,
         node_name: str = "geomodel_player",
         on_start: Callable[[dict[str, str]], None] | None = None) -> int:
    """Publish a bag's PointCloud2 records into DDS at the recorded rate.

    Parameters
    ----------
    path : path
        The bag (rosbag2 directory, ``.mcap`` or ``.db3``).
    rate : float
        Speed factor (> 0): record ``i`` is published ``(t_i - t_0) / rate`` seconds after
        the readers acknowledged the first (bag times; a best-effort publisher does not
        wait for acknowledgements).
    loop : bool
        Start over at the end, until ``stop`` is set or Ctrl-C.
    topics : sequence of str, optional
        PointCloud2 topics to play; default all of them.
    remap : mapping or sequence of ``"OLD:=NEW"``, optional
        Publish topic ``OLD`` as ``NEW``.
    context : rclpy.context.Context, optional
        An initialized context to publish in.  Without one, a private context is
        initialized (with ``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST``) and shut down.
    min_subscribers : int
        Subscribers (on any played topic) to wait for before publishing (e.g. 2 when a
        recorder listens besides the node).
    wait_timeout : float
        Wait up to this long [s] for at least one subscriber before the first record;
        ``0`` starts at once.
    stop : threading.Event, optional
        Set it to stop the playback (another thread); Ctrl-C stops it too.
    node_name : str
        Name of the publishing node.
    on_start : callable(dict), optional
        Called with ``{bag topic: published topic}`` once publishers are up (before the
        subscriber wait).

    Returns
    -------
    int
        Records published.

    Raises
    ------
    BagError
        Bag unreadable, topic missing or not PointCloud2, invalid ``rate``/``remap``, or no
        subscriber within ``wait_timeout``.

    Notes
    -----
    Records are published as the serialized bytes stored in the bag.  The publishers offer
    what ``ros2 bag play`` (Jazzy) offers by default: the recorded reliability and
    durability if every recorded publisher of the topic offered the same, otherwise
    reliable and volatile; history keep last :data:`PLAY_QOS_DEPTH`.
    """
    if not math.isfinite(rate) or rate <= 0.0:
        raise BagError(f"rate must be a finite number > 0, got {rate!r}")
    if not math.isfinite(wait_timeout) or wait_timeout < 0.0:
        raise BagError(f"wait timeout must be a finite number >= 0 [s], got {wait_timeout!r}")
    remaps = _parse_remaps(remap)
    stop = stop if stop is not None else threading.Event()
    bag = Path(path)
    reader = _open_reader(bag)
    try:
        names = _select_topics(reader, bag, topics, single=False)
        conns = {n: [c for c in reader.connections if c.topic == n] for n in names}
    except BaseException:
        reader.close()
        raise

    import rclpy
    from rclpy.context import Context
    from rclpy.duration import Duration
    from rclpy.node import Node

    own_context = context is None
    if own_context:
        os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
        context = Context()
        rclpy.init(args=[], context=context)
    node = None
    published = 0
    try:
        node = Node(node_name, context=context)
        pubs = {n: node.create_publisher(PointCloud2, remaps.get(n, n), _play_qos(conns[n]))
                for n in names}
        if on_start is not None:
            on_start({n: p.topic_name for n, p in pubs.items()})
        if not _wait_for_subscribers(pubs, wait_timeout, min_subscribers, stop):
            return published
        all_conns = [c for n in names for c in conns[n]]
        while not stop.is_set():
            published += _publish_once(reader, bag, all_conns, pubs, rate, stop)
            if not loop:
                break
        # A reliable writer destroyed right after its last write can take that message
        # with it (a multi-MB cloud is still in fragments): wait for the readers' acks.
        for pub in pubs.values():
            pub.wait_for_all_acked(Duration(seconds=ACK_TIMEOUT_S))
    except KeyboardInterrupt:
        stop.set()
    finally:
        reader.close()
        if node is not None:
            try:
                node.destroy_node()
            except Exception:  # noqa: BLE001 - the context may already be shut down (SIGINT)
                pass
        if own_context:
            rclpy.try_shutdown(context=context)
    return published
