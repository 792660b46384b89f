"""rosbag2 (MCAP) play and record on rclpy + rosbags: what `ros2 bag` does, for a ROS 2 that
comes from wheels and has no rosbag2.

Messages travel as CDR bytes: rosbags' bytes are rclpy's, so nothing is re-encoded."""
from __future__ import annotations

import importlib
import time
from dataclasses import dataclass, field
from pathlib import Path

import rclpy
from rclpy.duration import Duration
from rclpy.executors import ExternalShutdownException
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from rclpy.serialization import deserialize_message
from rosbags.interfaces import Qos, QosDurability, QosHistory, QosLiveliness, QosReliability, QosTime
from rosbags.rosbag2 import Reader, StoragePlugin, Writer, WriterError
from sgreg_msgs.msg import InstanceMap

from sgreg_core.maps.instance_map import points_problem
from sgreg_ros import qos
from sgreg_ros.pointcloud import PointCloudError, unpack_xyz_id
from .bag_types import typestore


class BagError(ValueError):
    """A bag that cannot be opened or a topic that cannot be played or recorded."""


def message_class(msgtype: str):
    """'sgreg_msgs/msg/CoarseGraph' -> the rclpy message class."""
    try:
        pkg, kind, name = msgtype.split("/")
        return getattr(importlib.import_module(f"{pkg}.{kind}"), name)
    except (ValueError, ImportError, AttributeError):
        raise BagError(f"message type {msgtype} is not available in this environment") from None


def qos_for(topic: str) -> QoSProfile:
    """The QoS sgreg's own nodes use on a topic of that name (see qos.py)."""
    for suffix, profile in (("/sgreg/coarse", qos.COARSE), ("/sgreg/dense", qos.DENSE),
                            ("/sgreg/dense_request", qos.DENSE_REQUEST),
                            ("/mapping/instances", qos.INSTANCES), ("/tf_static", qos.TF_STATIC),
                            ("/sgreg/markers", qos.VIEW), ("/sgreg/merged_cloud", qos.VIEW)):
        if topic.endswith(suffix):
            return profile
    return qos.RESULTS


def offered_qos(profile: QoSProfile) -> Qos:
    """A publisher's QoS as rosbag2 metadata (offered_qos_profiles), from which the real `ros2 bag
    play` publishes: a transient-local subscriber (sgreg/coarse, /tf_static) matches only a
    transient-local publisher. Deadline, lifespan and lease left at rosbag2's 0 (the default)."""
    zero = QosTime(sec=0, nsec=0)
    return Qos(history=QosHistory.KEEP_LAST, depth=int(profile.depth),
               reliability=(QosReliability.BEST_EFFORT if profile.reliability == ReliabilityPolicy.BEST_EFFORT
                            else QosReliability.RELIABLE),
               durability=(QosDurability.TRANSIENT_LOCAL if profile.durability == DurabilityPolicy.TRANSIENT_LOCAL
                           else QosDurability.VOLATILE),
               deadline=zero, lifespan=zero, liveliness=QosLiveliness.AUTOMATIC,
               liveliness_lease_duration=zero, avoid_ros_namespace_conventions=False)


def play_qos(conn) -> QoSProfile:
    """The QoS a bag topic is played with: the recorded publishers' reliability and durability
    when they all agree (`ros2 bag play` adapts to the recorded offers: a transient-local
    subscriber, RViz's markers, matches only a transient-local publisher), else sgreg's for a
    topic of that name; the depth is sgreg's (rosbag2 records 0)."""
    base = qos_for(conn.topic)
    offered = getattr(conn.ext, "offered_qos_profiles", None) or []
    reliability = {q.reliability == QosReliability.BEST_EFFORT for q in offered}
    durability = {q.durability == QosDurability.TRANSIENT_LOCAL for q in offered}
    if len(reliability) != 1 or len(durability) != 1:      # none recorded, or publishers differ
        return base
    return QoSProfile(depth=base.depth,
                      reliability=ReliabilityPolicy.BEST_EFFORT if reliability.pop() else ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.TRANSIENT_LOCAL if durability.pop() else DurabilityPolicy.VOLATILE)


def adapted_qos(topic: str, offered: list[QoSProfile]) -> QoSProfile:
    """A recorder's subscription that matches every publisher on the topic, as `ros2 bag record`
    adapts: reliable only when all of them are, transient local only when all of them are
    (with sgreg's depth for its own topics)."""
    depth = qos_for(topic).depth
    reliable = all(p.reliability != ReliabilityPolicy.BEST_EFFORT for p in offered)
    transient = bool(offered) and all(p.durability == DurabilityPolicy.TRANSIENT_LOCAL for p in offered)
    return QoSProfile(depth=depth,
                      reliability=ReliabilityPolicy.RELIABLE if reliable else ReliabilityPolicy.BEST_EFFORT,
                      durability=DurabilityPolicy.TRANSIENT_LOCAL if transient else DurabilityPolicy.VOLATILE)


def open_bag(path: str | Path) -> Reader:
    path = Path(path)
    if not (path / "metadata.yaml").exists():
        raise BagError(f"{path} is not a rosbag2 directory (no metadata.yaml)")
    try:
        reader = Reader(path)
        reader.open()
    except Exception as exc:  # rosbags raises its own types for every malformed bag
        raise BagError(f"cannot open bag {path}: {exc}") from None
    return reader


def select_connections(reader: Reader, topics: list[str] | None, path) -> list:
    """The bag's connections of `topics` (None: all of them). BagError, naming the bag's topics,
    when none matches: rosbags reads an empty selection as "every connection"."""
    if topics is None:
        return list(reader.connections)
    conns = [c for c in reader.connections if c.topic in topics]
    if not conns:
        held = ", ".join(sorted({c.topic for c in reader.connections})) or "no topic"
        raise BagError(f"bag {path} has none of the topics {', '.join(topics) or '(none given)'}; "
                       f"it holds {held}")
    return conns


def read_messages(reader: Reader, conns: list, path):
    """(connection, t_ns, raw) of `conns` in bag order; nothing for no connection. A chunk that
    does not decompress or fails its checksum raises BagError: the reader cannot go on past it,
    so the rest of the bag is lost to every tool alike."""
    if not conns:
        return
    try:
        yield from reader.messages(connections=conns)
    except Exception as exc:  # rosbags' ReaderError, zstd's ZstdError, struct errors, ...
        raise BagError(f"bag {path} is damaged: {exc}") from None


def seal_chunks(bag: str | Path) -> None:
    """Write each chunk's CRC-32 into the bag's MCAP files, where rosbags' writer leaves 0
    ("no checksum"): readers then refuse a damaged chunk instead of decoding flipped bytes into
    messages. In place, only the 4 checksum bytes of each chunk change."""
    from binascii import crc32

    from rosbags.rosbag2.storage_mcap import decompress

    for mcap in Path(bag).glob("*.mcap"):
        with mcap.open("r+b") as f:
            pos = 8                                         # after the magic
            while len(head := _read_at(f, pos, 9)) == 9 and head[0] != 0x0F:   # 0x0F: data end
                length = int.from_bytes(head[1:], "little")
                if head[0] == 0x06:                         # chunk record
                    body = f.read(length)
                    size = int.from_bytes(body[16:24], "little")
                    n = int.from_bytes(body[28:32], "little")
                    raw = decompress(body[40 + n:], body[32:32 + n].decode(), size, 0)
                    f.seek(pos + 9 + 24)
                    f.write(crc32(raw).to_bytes(4, "little"))
                pos += 9 + length


def _read_at(f, pos: int, n: int) -> bytes:
    f.seek(pos)
    return f.read(n)


@dataclass
class PlayReport:
    """published / corrupted / per_topic: what was played; clock: (monotonic s, bag s) at the
    first message, so that any later moment maps to bag time (scaled by the rate)."""

    published: int = 0
    corrupted: list = field(default_factory=list)   # (topic, index, error)
    per_topic: dict = field(default_factory=dict)
    clock: tuple[float, float] | None = None
    interrupted: str = ""     # what ended play before the bag's end: "Ctrl-C" or "shutdown"


def play_bag(node, path: str | Path, rate: float = 1.0, topics: list[str] | None = None,
             log=print, should_stop=lambda: False, delay: float = 1.0,
             wait_subscribers: float = 0.0, flush_timeout: float = 2.0,
             clock_hz: float = 0.0) -> PlayReport:
    """Publish a bag's messages with their recorded timing (scaled by 1/rate) from `node`.

    `delay` seconds pass between creating the publishers and the first message, so that
    subscribers (a recorder discovers topics only once they exist) can match them; with
    `wait_subscribers` > 0, play first waits up to that long until every topic has a subscriber.
    At the end it waits up to `flush_timeout` seconds until reliable subscribers acknowledged
    everything. With clock_hz > 0 it also publishes the bag's time on /clock at that rate (from
    the bag's start, during the delay too), as `ros2 bag play --clock` does, so that nodes run
    with use_sim_time follow the bag; the bag's own /clock is then not played (two clocks would
    send time back and forth). Topics are played with their recorded QoS (play_qos), on the
    bag's timeline: a topic that starts late in the bag starts as late. A topic whose message
    type is not installed is left out with a line in the log, as `ros2 bag play` does.
    Each message is checked by deserialising it first; one that does not decode, or an instance
    map whose points are not finite or absurdly far (points_problem), is reported and
    skipped, and the rest of the bag plays on. A damaged chunk (many messages compressed
    together) ends play with a BagError: nothing after it can be read.
    `topics` (None: all) that the bag does not hold at all raise BagError."""
    if rate <= 0:
        raise BagError(f"rate must be positive, got {rate}")
    report = PlayReport()
    reader = open_bag(path)
    try:
        conns = select_connections(reader, topics, path)
        if clock_hz > 0:
            conns = [c for c in conns if c.topic != "/clock"]
        classes = {}
        for c in conns:
            try:
                classes[c.id] = message_class(c.msgtype)
            except BagError as exc:
                log(f"not playing {c.topic}: {exc}")
        conns = [c for c in conns if c.id in classes]
        if not conns:
            raise BagError(f"bag {path}: nothing to play (no topic of an installed message type)")
        pubs = {}
        for c in conns:
            if c.topic not in pubs:
                pubs[c.topic] = node.create_publisher(classes[c.id], c.topic, play_qos(c))
        clock = _BagClock(node, reader.start_time, rate, clock_hz)
        # the bag's timeline from its start: a topic selected with `topics` that starts late
        # in the bag starts as late (and /clock runs through the gap)
        t0_bag = reader.start_time
        try:
            deadline = time.monotonic() + wait_subscribers
            while time.monotonic() < deadline and not all(p.get_subscription_count() for p in pubs.values()):
                time.sleep(0.05)
            clock.sleep_until(time.monotonic() + delay)
            t0_wall = time.monotonic()
            report.clock = (t0_wall, t0_bag * 1e-9)
            clock.start(t0_wall, t0_bag)
            for index, (conn, t_ns, raw) in enumerate(read_messages(reader, conns, path)):
                if should_stop():
                    break
                if not rclpy.ok():    # rclpy's SIGTERM handler shuts the context down
                    report.interrupted = "shutdown"
                    break
                clock.sleep_until(t0_wall + (t_ns - t0_bag) * 1e-9 / rate)
                problem = _message_problem(bytes(raw), classes[conn.id])
                if problem:
                    report.corrupted.append((conn.topic, index, problem[:200]))
                    log(f"bag message {index} on {conn.topic} is corrupted ({problem}); skipped")
                    continue
                pubs[conn.topic].publish(bytes(raw))
                report.published += 1
                report.per_topic[conn.topic] = report.per_topic.get(conn.topic, 0) + 1
        except KeyboardInterrupt:     # Ctrl-C: what was played is still reported
            report.interrupted = "Ctrl-C"
        except Exception:
            if rclpy.ok():
                raise
            report.interrupted = "shutdown"   # SIGTERM shut the context down mid-publish
        # a reliable message still in flight dies with the process: wait for the readers' acks
        for pub in pubs.values() if rclpy.ok() else ():
            pub.wait_for_all_acked(Duration(seconds=flush_timeout))
    finally:
        reader.close()
    return report


def _message_problem(raw: bytes, cls) -> str | None:
    """Why a bag message must not be published, else None."""
    try:
        msg = deserialize_message(raw, cls)
    except Exception as exc:
        return str(exc)
    if not isinstance(msg, InstanceMap):
        return None
    try:
        return points_problem(unpack_xyz_id(msg.points, "instance")[0])
    except PointCloudError as exc:
        return str(exc)


class _BagClock:
    """The bag's time on /clock (rosgraph_msgs/Clock) while play waits, at clock_hz; idle at 0."""

    def __init__(self, node, start_ns: int, rate: float, clock_hz: float):
        self.period = 1.0 / clock_hz if clock_hz > 0 else None
        self.pub = None
        if self.period:
            from rosgraph_msgs.msg import Clock

            self.msg = Clock()
            self.pub = node.create_publisher(Clock, "/clock", 10)
        self.rate, self.wall0, self.bag0 = rate, None, start_ns
        self.next_tick = 0.0

    def start(self, wall0: float, bag0_ns: int) -> None:
        self.wall0, self.bag0 = wall0, bag0_ns

    def sleep_until(self, wall: float) -> None:
        while rclpy.ok():
            now = time.monotonic()
            if self.pub is not None and now >= self.next_tick:   # at clock_hz, however often called
                t = self.bag0 + (0 if self.wall0 is None else int((now - self.wall0) * self.rate * 1e9))
                self.msg.clock.sec, self.msg.clock.nanosec = divmod(t, 1_000_000_000)
                self.pub.publish(self.msg)
                # fallen behind (a slow publish): the next tick a period from now, no burst
                self.next_tick = max(self.next_tick + self.period, now + 0.5 * self.period)
            if now >= wall:
                return
            time.sleep(min(wall - now, (self.next_tick - now) if self.pub is not None else wall - now))


class BagRecorder:
    """Records raw messages of live topics into a rosbag2 directory (MCAP)."""

    def __init__(self, node, out: str | Path):
        out = Path(out)
        if out.exists():
            raise BagError(f"{out} exists; rosbag2 writes a new directory")
        self.node, self.out = node, out
        self.store = typestore()
        self.writer = Writer(out, version=9, storage_plugin=StoragePlugin.MCAP)
        try:
            self.writer.open()
        except (OSError, WriterError) as exc:   # a folder that cannot be created
            raise BagError(f"cannot create bag {out}: {exc}") from None
        self.connections: dict[str, object] = {}
        self.counts: dict[str, int] = {}

    def add_topic(self, topic: str, msgtype: str) -> None:
        """msgtype as 'pkg/msg/Name'. The subscription adapts to the topic's publishers (a
        best-effort one would send a reliable subscriber nothing), and their QoS goes into the
        bag for `ros2 bag play`."""
        if topic in self.connections:
            return
        cls = message_class(msgtype)
        offered = [i.qos_profile for i in self.node.get_publishers_info_by_topic(topic)]
        try:
            conn = self.writer.add_connection(topic, msgtype, typestore=self.store,
                                              offered_qos_profiles=[offered_qos(p) for p in offered]
                                              or [offered_qos(qos_for(topic))])
        except Exception as exc:  # rosbags: a type its typestore lacks, among others
            raise BagError(f"cannot record {msgtype}: {exc}") from None
        self.connections[topic] = conn
        self.counts[topic] = 0
        self.node.create_subscription(cls, topic, lambda raw, c=conn, t=topic: self._write(c, t, raw),
                                      adapted_qos(topic, offered), raw=True)

    def _write(self, conn, topic: str, raw: bytes) -> None:
        self.writer.write(conn, self.node.get_clock().now().nanoseconds, raw)
        self.counts[topic] += 1

    def close(self) -> None:
        self.writer.close()
        seal_chunks(self.out)


def spin_for(node, duration: float) -> None:
    """Spin `node` for `duration` seconds (0: until Ctrl-C or SIGTERM), for the live tools."""
    start = time.monotonic()
    try:
        while rclpy.ok() and (duration <= 0 or time.monotonic() - start < duration):
            rclpy.spin_once(node, timeout_sec=0.1)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except Exception:
        # the signal handler shut the context down between the check and the wait: a stop
        if rclpy.ok():
            raise


def instance_maps_in_bag(path: str | Path, t_origin: float = 0.0) -> list:
    """Every */mapping/instances message of a bag as (bag time - t_origin in s, agent id,
    sgreg_core InstanceMap), in bag order; for offline replays. Undecodable messages and maps
    with damaged points are skipped, as `play_bag` skips them; a damaged chunk raises BagError."""
    from sgreg_ros.convert import ConversionError, instance_map_from_msg

    reader = open_bag(path)
    out = []
    try:
        conns = [c for c in reader.connections if c.topic.endswith("/mapping/instances")]
        for conn, t_ns, raw in read_messages(reader, conns, path):
            try:
                imap = instance_map_from_msg(deserialize_message(bytes(raw), InstanceMap))
            except (ConversionError, Exception):
                continue
            if points_problem(imap.points):
                continue
            out.append((t_ns * 1e-9 - t_origin, conn.topic.split("/")[1], imap))
    finally:
        reader.close()
    return out


def final_maps(path: str | Path, gt: dict | None = None) -> dict:
    """agent -> the points (N, 3) of its last instance map in the bag (its map frame)."""
    origin = (gt or {}).get("t_origin", 0.0)
    last = {}
    for _, agent, imap in instance_maps_in_bag(path, origin):
        last[agent] = imap.points
    return last


def tf_in_bag(path: str | Path) -> dict:
    """child frame -> (parent frame, 4x4) of the last /tf transforms recorded in a bag (empty
    when it recorded none). A damaged chunk raises BagError."""
    from tf2_msgs.msg import TFMessage

    from sgreg_ros.convert import transform_from_msg

    reader = open_bag(path)
    out = {}
    try:
        conns = [c for c in reader.connections if c.topic == "/tf"]
        for _, _, raw in read_messages(reader, conns, path):
            try:
                msg = deserialize_message(bytes(raw), TFMessage)
            except Exception:
                continue
            for t in msg.transforms:
                out[t.child_frame_id] = (t.header.frame_id, transform_from_msg(t))
    finally:
        reader.close()
    return out
