"""sgreg_msgs <-> the plain types of sgreg_core.runtime. No decisions here: only field copies,
with malformed messages raising ConversionError (the node logs it and counts it). Every decoder
(`*_from_msg`) raises nothing else, whatever the message holds: a fuzz test feeds them
thousands of mutated messages."""
from __future__ import annotations

import array
import functools
from dataclasses import dataclass

import numpy as np
from builtin_interfaces.msg import Time
from rclpy.serialization import deserialize_message
from scipy.spatial.transform import Rotation
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import TransformStamped
from sgreg_msgs.msg import CoarseGraph, DenseGraph, DenseRequest, InstanceMap, RegistrationResult
from tf2_msgs.msg import TFMessage

from sgreg_core.geometry import MAX_COORD_M
from sgreg_core.maps.level import MAX_TILT_DEG, tilt_deg
from sgreg_core.net.model import NodeFeatures
from sgreg_core.runtime.messages import DenseRequestMessage, Estimate, GraphMessage
from sgreg_core.runtime.wire import WireError, pack_features, unpack_features
from sgreg_core.types import InstanceMap as CoreInstanceMap

from .pointcloud import PointCloudError, pack_xyz_id, unpack_xyz_id


class ConversionError(ValueError):
    """A message whose fields do not fit together."""


def decoder(fn):
    """Turn any exception of a decoder into ConversionError: a field combination nobody
    thought of must cost one message, not the node."""
    @functools.wraps(fn)
    def guarded(msg):
        try:
            return fn(msg)
        except ConversionError:
            raise
        except Exception as exc:
            raise ConversionError(f"{type(msg).__name__} does not decode: {type(exc).__name__}: {exc}") from None
    return guarded


def decode(raw: bytes, cls):
    """CDR bytes -> message; ConversionError when they do not decode. Nodes subscribe raw and
    decode here so that a malformed message becomes a counted refusal, not an exception inside
    the executor (which would take the node down)."""
    try:
        return deserialize_message(raw, cls)
    except Exception as exc:
        raise ConversionError(f"undecodable {cls.__name__} ({len(raw)} bytes): {exc}") from None


# Stamps travel as integer nanoseconds, so that an output carries its map's stamp to the
# nanosecond (float seconds of today's epoch resolve 240 ns)
def stamp_to_ns(t: Time) -> int:
    """ConversionError for nanosec >= 1e9: it is not a time another clock can be compared with
    (builtin_interfaces/Time keeps the fraction below a second)."""
    if not 0 <= int(t.nanosec) < 1_000_000_000:
        raise ConversionError(f"stamp nanosec {int(t.nanosec)} is not below 1e9")
    return int(t.sec) * 1_000_000_000 + int(t.nanosec)


def ns_to_stamp(ns: int) -> Time:
    sec, nanosec = divmod(int(ns), 1_000_000_000)
    return Time(sec=sec, nanosec=nanosec)


def _f32(values, n: int, name: str) -> np.ndarray:
    a = np.asarray(values, dtype=np.float32)
    if a.size != 3 * n:
        raise ConversionError(f"{name} has {a.size} values, expected 3 x {n} nodes")
    return a.reshape(n, 3)


# ---- instance maps -----------------------------------------------------------------------
@decoder
def instance_map_from_msg(msg: InstanceMap) -> CoreInstanceMap:
    n = len(msg.instance_ids)
    if len(msg.labels) != n or len(msg.label_scores) not in (0, n):
        raise ConversionError(f"{n} instance ids but {len(msg.labels)} labels and "
                              f"{len(msg.label_scores)} scores")
    ids, counts = np.unique(np.asarray(msg.instance_ids, np.int64), return_counts=True)
    if (counts > 1).any():    # which label is the instance's? taking the last would guess
        raise ConversionError(f"instance ids repeat: {ids[counts > 1][:5].tolist()}")
    try:
        points, inst = unpack_xyz_id(msg.points, "instance")
    except PointCloudError as exc:
        raise ConversionError(f"points: {exc}") from None
    ids = [int(i) for i in msg.instance_ids]
    scores = list(msg.label_scores) or [1.0] * n
    return CoreInstanceMap(points=points, instance=inst.astype(np.int64).astype(np.int32),
                           labels=dict(zip(ids, msg.labels)),
                           scores={i: float(s) for i, s in zip(ids, scores)})


# a map stamped further ahead of the node's clock is refused: robots' clocks may disagree by
# minutes, a stamp years ahead is a broken front-end clock that every result would carry
MAX_AHEAD_S = 3600.0


# what an instance map holds besides its points (ids, labels, scores, headers) is far below this
MAP_OVERHEAD_BYTES = 8 << 20
# bytes a point may take in a front end's cloud: sgreg's layout takes 16, PCL's padded ones 32
# (PointXYZL) or 48; a map is refused before decoding only when even this much a point is too big
MAX_POINT_BYTES = 64
# a dense request: its header, names and node ids (4 bytes each), at most max_nodes of them
REQUEST_OVERHEAD_BYTES = 4096


def max_request_bytes(max_nodes: int) -> int:
    """The biggest dense request a node asking for at most max_nodes nodes can send."""
    return REQUEST_OVERHEAD_BYTES + 4 * int(max_nodes)


def take_instance_map(raw: bytes, take, refuse, agent_id: str, now_ns: int = 0,
                      max_points: int = 0) -> str | None:
    """The one map intake of both nodes of agent `agent_id`: decode an InstanceMap and hand it
    to take(imap, sequence, stamp_ns) (AgentCore.take_map or Peers.take_own_map). Returns None,
    what take says of a map too small to use yet (agent.NotYet: no refusal), or the one-line
    reason the map was refused, counted through refuse(counter, why): bytes
    that do not decode are "malformed_message", fields that do not fit "bad_instance_map", and
    so is a map that names another agent or frame (a remapping slip: registered as the own
    map, another agent's map verifies the identity as the transform to that agent), has no
    stamp, or is stamped more than MAX_AHEAD_S after now_ns (the node's clock; 0: not checked).
    Bytes that cannot hold at most max_points points (0: not checked) are "oversized_message",
    refused before they are decoded (a copy of them would be made first)."""
    if max_points > 0 and len(raw) > max_points * MAX_POINT_BYTES + MAP_OVERHEAD_BYTES:
        return refuse("oversized_message", f"instance map of {len(raw) / 1e6:.1f} MB refused before decoding: "
                                           f"more than max_points_in_map={max_points} points")
    try:
        msg = decode(raw, InstanceMap)
    except ConversionError as exc:
        return refuse("malformed_message", f"instance map refused: {exc}")
    foreign = _foreign(msg, agent_id)
    if foreign:
        return refuse("bad_instance_map", f"instance map {msg.sequence} refused: {foreign}")
    try:
        stamp = stamp_to_ns(msg.header.stamp)
    except ConversionError as exc:
        return refuse("bad_instance_map", f"instance map {msg.sequence} refused: {exc}")
    if stamp == 0:   # every result made from it would carry no time
        return refuse("bad_instance_map", f"instance map {msg.sequence} refused: header.stamp is "
                                          "0 (unset)")
    if now_ns > 0 and stamp - now_ns > MAX_AHEAD_S * 1e9:   # now 0: no clock yet (sim time)
        return refuse("bad_instance_map", f"instance map {msg.sequence} refused: stamped "
                                          f"{(stamp - now_ns) / 1e9:.0f} s ahead of this node's clock")
    try:
        imap = instance_map_from_msg(msg)
    except ConversionError as exc:
        return refuse("bad_instance_map", f"instance map {msg.sequence} refused: {exc}")
    try:
        return take(imap, int(msg.sequence), stamp)
    except Exception as exc:  # a bug must cost one map, not the node
        return refuse("internal_error", f"instance map {msg.sequence} failed: {exc!r}")


def _foreign(msg: InstanceMap, agent_id: str) -> str:
    """Why an instance map is not agent_id's own ("" when it is): its sender or its frames name
    another agent. Empty fields are taken (a front end may leave them unset)."""
    frame = f"{agent_id}/map"
    if msg.agent_id and msg.agent_id != agent_id:
        return f"it is agent {msg.agent_id!r}'s map, not {agent_id!r}'s"
    for name, value in (("header.frame_id", msg.header.frame_id),
                        ("points.header.frame_id", msg.points.header.frame_id)):
        if value and value.lstrip("/") != frame:
            return f"{name} is {value!r}, not {frame!r}"
    return ""


def instance_map_to_msg(imap: CoreInstanceMap, agent_id: str, sequence: int, stamp_ns: int) -> InstanceMap:
    msg = InstanceMap()
    msg.header.stamp = ns_to_stamp(stamp_ns)
    msg.header.frame_id = f"{agent_id}/map"
    msg.agent_id, msg.sequence = agent_id, int(sequence)
    ids = sorted(imap.labels)
    msg.instance_ids = ids
    msg.labels = [imap.labels[i] for i in ids]
    msg.label_scores = [float(imap.scores.get(i, 1.0)) for i in ids]
    inst = np.where(imap.instance > 0, imap.instance, 0).astype(np.uint32)
    msg.points = pack_xyz_id(imap.points, inst, "instance", frame_id=msg.header.frame_id,
                             stamp=msg.header.stamp)
    return msg


# ---- coarse and dense graphs ---------------------------------------------------------------
def coarse_to_msg(g: GraphMessage, encoding: int) -> CoarseGraph:
    msg = CoarseGraph()
    msg.header.stamp = ns_to_stamp(g.stamp_ns)
    msg.header.frame_id = f"{g.agent_id}/map"
    msg.agent_id, msg.sequence, msg.map_sequence = g.agent_id, int(g.sequence), int(g.map_sequence)
    msg.weights_id = g.weights_id
    q = Rotation.from_matrix(np.asarray(g.level, np.float64)).as_quat()   # x, y, z, w
    msg.level.x, msg.level.y, msg.level.z, msg.level.w = (float(v) for v in q)
    msg.node_ids = array.array("I", np.asarray(g.nodes.node_ids, np.uint32).tobytes())
    msg.centers = array.array("f", np.asarray(g.nodes.centers, "<f4").tobytes())
    msg.extents = array.array("f", np.asarray(g.extents, "<f4").tobytes())
    payload, scales = pack_features(g.nodes.descriptor, encoding)
    msg.feature_dim = int(g.nodes.descriptor.shape[1])
    msg.feature_encoding = encoding
    msg.feature_scales = array.array("f", scales.astype("<f4").tobytes())
    msg.features = payload
    return msg


@decoder
def coarse_from_msg(msg: CoarseGraph) -> GraphMessage:
    n = len(msg.node_ids)
    try:
        x = unpack_features(bytes(msg.features), n, int(msg.feature_dim), int(msg.feature_encoding),
                            np.asarray(msg.feature_scales, np.float32))
    except WireError as exc:
        raise ConversionError(f"features: {exc}") from None
    return GraphMessage(agent_id=msg.agent_id, sequence=int(msg.sequence),
                        map_sequence=int(msg.map_sequence), weights_id=msg.weights_id,
                        stamp_ns=stamp_to_ns(msg.header.stamp),
                        nodes=NodeFeatures(node_ids=np.asarray(msg.node_ids, np.int64),
                                           centers=_f32(msg.centers, n, "centers"), descriptor=x),
                        extents=_f32(msg.extents, n, "extents"), level=_level(msg.level))


def _is_unit_quaternion(q: np.ndarray) -> bool:
    """Finite, each component within [-1, 1] (so that a huge one fails here rather than
    overflowing the norm), and of norm 1 within 1e-3."""
    return bool(np.isfinite(q).all() and np.abs(q).max() <= 1.0 + 1e-3 and abs(np.linalg.norm(q) - 1.0) <= 1e-3)


def _level(q) -> np.ndarray:
    """The sender's levelling rotation from its quaternion: a unit quaternion that tilts by at
    most MAX_TILT_DEG (levelling never turns a map about z, and a map is never on its
    side)."""
    v = np.array([q.x, q.y, q.z, q.w], np.float64)
    if not _is_unit_quaternion(v):
        raise ConversionError(f"level is not a unit quaternion: {v.tolist()}")
    R = Rotation.from_quat(v).as_matrix()
    if tilt_deg(R) > MAX_TILT_DEG:
        raise ConversionError(f"level tilts the map by more than {MAX_TILT_DEG:g} deg")
    return R


def dense_to_msg(g: GraphMessage, encoding: int) -> DenseGraph:
    msg = DenseGraph()
    msg.graph = coarse_to_msg(g, encoding)
    msg.header = msg.graph.header
    msg.agent_id, msg.sequence = g.agent_id, int(g.sequence)
    msg.requester, msg.request_sequence = g.requester, int(g.request_sequence)
    node_ids = np.asarray(g.nodes.node_ids, np.uint32)[g.point_node]
    msg.points = pack_xyz_id(g.points, node_ids, "node_id", frame_id=msg.header.frame_id,
                             stamp=msg.header.stamp)
    return msg


@decoder
def dense_from_msg(msg: DenseGraph) -> GraphMessage:
    g = coarse_from_msg(msg.graph)
    if msg.agent_id != g.agent_id:
        raise ConversionError(f"dense graph from {msg.agent_id!r} carries a graph of {g.agent_id!r}")
    try:
        points, node_ids = unpack_xyz_id(msg.points, "node_id")
    except PointCloudError as exc:
        raise ConversionError(f"points: {exc}") from None
    ids = g.nodes.node_ids
    order = np.argsort(ids)
    pos = np.searchsorted(ids[order], node_ids.astype(np.int64))
    pos = np.clip(pos, 0, max(g.num_nodes - 1, 0))
    if g.num_nodes == 0 or not np.array_equal(ids[order][pos], node_ids.astype(np.int64)):
        raise ConversionError("points carry node ids that are not in the graph")
    g.sequence = int(msg.sequence)
    g.points, g.point_node = points, order[pos]
    g.requester, g.request_sequence = msg.requester, int(msg.request_sequence)
    return g


# ---- requests and results ------------------------------------------------------------------
def request_to_msg(r: DenseRequestMessage, stamp_ns: int) -> DenseRequest:
    msg = DenseRequest()
    msg.header.stamp = ns_to_stamp(stamp_ns)
    msg.from_agent, msg.to_agent = r.from_agent, r.to_agent
    msg.sequence, msg.coarse_sequence = int(r.sequence), int(r.coarse_sequence)
    msg.weights_id = r.weights_id
    msg.node_ids = array.array("I", np.asarray(r.node_ids, np.uint32).tobytes())
    return msg


@decoder
def request_from_msg(msg: DenseRequest) -> DenseRequestMessage:
    return DenseRequestMessage(from_agent=msg.from_agent, to_agent=msg.to_agent,
                               sequence=int(msg.sequence), coarse_sequence=int(msg.coarse_sequence),
                               weights_id=msg.weights_id, node_ids=np.asarray(msg.node_ids, np.int64))


def transform_msg(T: np.ndarray, agent_id: str, peer_id: str, stamp_ns: int) -> TransformStamped:
    t = TransformStamped()
    t.header.stamp = ns_to_stamp(stamp_ns)
    t.header.frame_id = f"{peer_id}/map"
    t.child_frame_id = f"{agent_id}/map"
    t.transform.translation.x, t.transform.translation.y, t.transform.translation.z = (
        float(v) for v in T[:3, 3])
    q = Rotation.from_matrix(T[:3, :3]).as_quat()  # x, y, z, w
    r = t.transform.rotation
    r.x, r.y, r.z, r.w = (float(v) for v in q)
    return t


def tf_msg(poses: dict, merged_frame: str, stamp_ns: int) -> TFMessage:
    """/tf: one transform per attached agent, merged_frame -> <id>/map (p_merged = T p_map)."""
    msg = TFMessage()
    for agent, T in sorted(poses.items()):
        t = transform_msg(T, agent, "", stamp_ns)
        t.header.frame_id = merged_frame
        msg.transforms.append(t)
    return msg


def transform_from_msg(t: TransformStamped) -> np.ndarray:
    T = np.eye(4)
    r = t.transform.rotation
    T[:3, :3] = Rotation.from_quat([r.x, r.y, r.z, r.w]).as_matrix()
    tr = t.transform.translation
    T[:3, 3] = [tr.x, tr.y, tr.z]
    return T


def result_to_msg(e: Estimate, agent_id: str, sequence: int, stamp_ns: int,
                  counters: dict) -> RegistrationResult:
    msg = RegistrationResult()
    msg.header.stamp = ns_to_stamp(stamp_ns)
    msg.header.frame_id = f"{e.peer_id}/map"
    msg.agent_id, msg.peer_id, msg.sequence = agent_id, e.peer_id, int(sequence)
    msg.transform = transform_msg(e.T, agent_id, e.peer_id, stamp_ns)
    msg.verified, msg.mode, msg.reason, msg.link = bool(e.verified), e.mode, e.reason, e.link
    msg.node_matches, msg.correspondences, msg.inliers = (
        int(e.node_matches), int(e.correspondences), int(e.inliers))
    msg.inlier_ratio, msg.confidence = float(e.inlier_ratio), float(e.confidence)
    ev = e.registration.evidence
    msg.inlier_objects, msg.ambiguity = int(ev.objects), float(ev.ambiguity)
    msg.fitness = float(ev.fitness) if np.isfinite(ev.fitness) else 0.0
    msg.peer_coarse_sequence, msg.peer_dense_sequence = (
        int(e.peer_coarse_sequence), int(e.peer_dense_sequence))
    pairs = e.registration.inlier_node_pairs()[:, ::-1]     # (peer, own) -> (agent, peer)
    msg.inlier_node_pairs = array.array("I", np.ascontiguousarray(pairs, np.uint32).tobytes())
    msg.timing_names = list(e.timing_ms)
    msg.timing_ms = [float(v) for v in e.timing_ms.values()]
    msg.counter_names = list(counters)
    msg.counter_values = [int(v) for v in counters.values()]
    return msg


MAX_LINK_M = MAX_COORD_M    # maps are refused beyond it too (sgreg_core/maps/instance_map.py)


@dataclass
class Result:
    """What the merger takes from a RegistrationResult of any agent."""

    agent: str
    peer: str
    T: np.ndarray            # T_agent^peer
    verified: bool
    reason: str
    link: str
    confidence: float
    stamp_ns: int
    node_pairs: np.ndarray   # (k, 2) (agent node id, peer node id)
    mode: str = ""           # "coarse", "dense" or "merged"
    signed_ns: int = 0       # when its sender signed it (wall clock, ns; 0: unsigned)


@decoder
def result_from_msg(msg: RegistrationResult) -> Result:
    if not msg.agent_id or not msg.peer_id or msg.agent_id == msg.peer_id:
        raise ConversionError(f"result of {msg.agent_id!r} for {msg.peer_id!r}")
    # the frames the result names are the link's: another pair's transform is not this one
    # (empty ones are taken, as in an instance map)
    frames = {"header.frame_id": (msg.header.frame_id, f"{msg.peer_id}/map"),
              "transform.header.frame_id": (msg.transform.header.frame_id, f"{msg.peer_id}/map"),
              "transform.child_frame_id": (msg.transform.child_frame_id, f"{msg.agent_id}/map")}
    for name, (value, want) in frames.items():
        if value and value.lstrip("/") != want:
            raise ConversionError(f"{name} is {value!r}, not {want!r}")
    r = msg.transform.transform.rotation
    q = np.array([r.x, r.y, r.z, r.w], np.float64)
    if not _is_unit_quaternion(q):   # not normalised away
        raise ConversionError(f"transform rotation is not a unit quaternion: {q.tolist()}")
    T = transform_from_msg(msg.transform)
    if not np.isfinite(T).all() or not np.isfinite(msg.confidence):
        raise ConversionError("NaN or inf in the transform or the confidence")
    if np.abs(T[:3, 3]).max() > MAX_LINK_M:
        raise ConversionError(f"a link of more than {MAX_LINK_M:g} m")
    pairs = np.asarray(msg.inlier_node_pairs, np.int64)
    if pairs.size % 2:
        raise ConversionError("inlier_node_pairs holds an odd number of ids")
    return Result(msg.agent_id, msg.peer_id, T, bool(msg.verified), msg.reason, msg.link,
                  float(np.clip(msg.confidence, 0.0, 1.0)), stamp_to_ns(msg.header.stamp),
                  pairs.reshape(-1, 2), msg.mode, int(msg.signed_ns))


def diagnostics_msg(name: str, agent_id: str, level: int, message: str, counters: dict,
                    stamp_ns: int) -> DiagnosticArray:
    """One DiagnosticStatus per node (name: the node's full name, hardware_id: the agent id), with
    every counter that has counted as a key/value (rqt_robot_monitor and Foxglove display
    them); one still at 0 is left out."""
    arr = DiagnosticArray()
    arr.header.stamp = ns_to_stamp(stamp_ns)
    status = DiagnosticStatus(level=bytes([level]), name=name, message=message, hardware_id=agent_id)
    status.values = [KeyValue(key=k, value=str(v)) for k, v in sorted(counters.items())]
    arr.status = [status]
    return arr
