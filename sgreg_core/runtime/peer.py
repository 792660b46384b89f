"""Per-peer registration: the coarse-to-fine protocol of SG-Reg (paper section VI) as a plain
state machine, with every failure of DESIGN.md section 5 turned into a counter and a one-line
reason instead of an exception.

For each peer: coarse graphs arrive at ~1 Hz -> node matching -> an estimate from node centers
(merged with the point correspondences kept from the last dense exchange) and, when enough nodes
match and the minimum interval has passed, a dense request. A dense answer -> point matching ->
a dense estimate. An estimate is verified only by the pose estimator's verification against a
dense cloud of the peer; without one it is reported, never marked verified.
"""
from __future__ import annotations

import time
from collections import Counter
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from ..net.model import NodeFeatures, SGRegModel
from ..pose.estimator import PoseConfig, estimate_pose
from .agent import AgentCore
from .messages import DenseRequestMessage, Estimate, GraphMessage


@dataclass
class RegistrationConfig:
    """min_node_matches: node matches needed before asking a peer for dense data.
    min_request_interval_s: at most one dense request per peer per this interval.
    request_timeout_s: an unanswered request is retried after this, then after
        timeout * retry_backoff^k, up to max_retries; then the link gives up until the next
        interval.
    min_coarse_matches: node matches needed to attempt a coarse estimate.
    restart_sequence_max: a sequence that goes back to at most this value means the peer
        restarted (its map frame is new); any other step back is an out-of-order message.
    max_nodes / max_points: bigger messages are refused (oversized).
    keep_correspondences: keep the latest dense point correspondences and merge them with
        node-center matches when only coarse data arrives (the paper's scheme).
    pose: the estimator, with ICP on: an estimate is verified only when, after ICP, at least
        pose.min_fitness of the peer's points that land on the agent's footprint lie on its
        surfaces (pose/verify.py). Verification on a 10 cm grid, as `sgreg register`."""

    min_node_matches: int = 3
    min_request_interval_s: float = 5.0
    request_timeout_s: float = 2.0
    retry_backoff: float = 2.0
    max_retries: int = 3
    min_coarse_matches: int = 4
    restart_sequence_max: int = 1
    max_nodes: int = 2000
    max_points: int = 500_000
    keep_correspondences: bool = True
    pose: PoseConfig = field(default_factory=lambda: PoseConfig(icp=True, verify_voxel=0.1))


@dataclass
class _PendingRequest:
    sequence: int
    coarse_sequence: int
    node_ids: np.ndarray
    sent_at: float
    retries: int = 0


@dataclass
class PeerLink:
    """What the agent knows about one peer."""

    peer_id: str
    coarse: GraphMessage | None = None
    coarse_features: NodeFeatures | None = None
    dense: GraphMessage | None = None
    dense_cloud: np.ndarray | None = None
    kept_own: np.ndarray | None = None    # (c, 3) own-frame points of kept correspondences
    kept_peer: np.ndarray | None = None   # (c, 3) peer-frame points
    kept_score: np.ndarray | None = None
    pending: _PendingRequest | None = None
    last_request_at: float = -np.inf
    last_seq: dict = field(default_factory=dict)   # stream -> last sequence seen
    last_verified: Estimate | None = None


class Registrar:
    """All peers of one agent. Call on_coarse / on_dense / on_tick; read counters."""

    def __init__(self, cfg: RegistrationConfig, agent: AgentCore, model: SGRegModel,
                 log: Callable[[str], None] = print):
        self.cfg = cfg
        self.agent = agent
        self.model = model
        self.log = log
        self.peers: dict[str, PeerLink] = {}
        self.counters: Counter = Counter()
        self._request_seq = 0
        self._said: set = set()

    # ---- inputs --------------------------------------------------------------------------
    def prepare_own_map(self) -> None:
        """Build the own map's reference cloud (voxels, KD-tree, normals, footprint) now, once
        per map update, so that no estimate waits for it."""
        if self.agent.ready:
            self.agent.reference_cloud(self.cfg.pose)

    def on_coarse(self, msg: GraphMessage, now: float) -> tuple[Estimate | None, DenseRequestMessage | None]:
        if msg.agent_id == self.agent.cfg.name:
            return None, None
        link = self._accept(msg, "coarse")
        if link is None:
            return None, None
        link.coarse = msg
        link.coarse_features = NodeFeatures(node_ids=msg.node_ids, centers=msg.centers, x=msg.x)
        if not self.agent.ready:
            self._count("own_map_not_ready")
            return None, None
        timings: dict = {}
        t0 = time.perf_counter()
        own = self.agent.features
        matches = self.model.match_coarse(own, link.coarse_features, timings)
        estimate = self._estimate_coarse(link, matches, timings, t0)
        request = self._maybe_request(link, matches, now)
        return estimate, request

    def on_dense(self, msg: GraphMessage, now: float) -> Estimate | None:
        if msg.agent_id == self.agent.cfg.name:
            return None
        link = self._accept(msg, "dense")
        if link is None:
            return None
        if link.pending is not None and msg.requester == self.agent.cfg.name \
                and msg.request_sequence == link.pending.sequence:
            link.pending = None
        if not self.agent.ready:
            self._count("own_map_not_ready")
            return None
        timings: dict = {}
        t0 = time.perf_counter()
        peer = self._dense_features(msg, timings)
        own = self.agent.features
        dm = self.model.match_dense(own, peer, timings)
        link.dense, link.dense_cloud = msg, msg.points
        pts = dm.points
        result, inliers = self._run_pose(link, "dense", len(dm.nodes), pts.src_xyz, pts.ref_xyz,
                                         pts.score, link.dense_cloud, timings, t0, dense_seq=msg.sequence)
        if self.cfg.keep_correspondences and result.verified:
            # only the verified inliers: clean and few, so merged estimates stay fast
            link.kept_own, link.kept_peer, link.kept_score = (
                pts.src_xyz[inliers], pts.ref_xyz[inliers], pts.score[inliers])
        return result

    def on_tick(self, now: float) -> list[DenseRequestMessage]:
        """Retries of unanswered requests (with back-off), and giving up on silent peers."""
        out = []
        for link in self.peers.values():
            p = link.pending
            if p is None:
                continue
            deadline = p.sent_at + self.cfg.request_timeout_s * self.cfg.retry_backoff ** p.retries
            if now < deadline:
                continue
            if p.retries >= self.cfg.max_retries:
                self._count("request_gave_up")
                self.log(f"peer {link.peer_id} did not answer dense request {p.sequence} after "
                         f"{p.retries} retries; giving up until the next request interval")
                link.pending = None
                link.last_request_at = now
                continue
            self._count("request_retry")
            self._request_seq += 1
            p.sequence, p.retries, p.sent_at = self._request_seq, p.retries + 1, now
            out.append(self._request_message(link, p))
        return out

    # ---- validation ----------------------------------------------------------------------
    def _accept(self, msg: GraphMessage, stream: str) -> PeerLink | None:
        """The peer's link if the message is usable; else None, with a counter and a log line."""
        problem = self._check(msg)
        if problem is not None:
            counter, text = problem
            self._count(counter)
            self._say_once((counter, msg.agent_id), f"{stream} graph from {msg.agent_id!r} "
                           f"(seq {msg.sequence}) refused: {text}")
            return None
        link = self.peers.setdefault(msg.agent_id, PeerLink(msg.agent_id))
        last = link.last_seq.get(stream)
        if last is not None and msg.sequence <= last:
            if msg.sequence <= self.cfg.restart_sequence_max and last > msg.sequence:
                self._count("peer_restart")
                self.log(f"peer {msg.agent_id} restarted (sequence {last} -> {msg.sequence}): "
                         "forgetting its old map")
                link = self.peers[msg.agent_id] = PeerLink(msg.agent_id)
            else:
                counter = "duplicate_sequence" if msg.sequence == last else "out_of_order_sequence"
                self._count(counter)
                self.log(f"{stream} graph from {msg.agent_id} dropped: sequence {msg.sequence} "
                         f"after {last} ({counter.replace('_', ' ')})")
                return None
        link.last_seq[stream] = msg.sequence
        return link

    def _check(self, msg: GraphMessage) -> tuple[str, str] | None:
        if msg.weights_id != self.agent.weights_id:
            return ("rejected_weights", f"features from weights {msg.weights_id!r}, this agent "
                    f"runs {self.agent.weights_id!r}")
        n = msg.num_nodes
        if n > self.cfg.max_nodes or (msg.points is not None and msg.points.shape[0] > self.cfg.max_points):
            return "oversized_message", f"{n} nodes / points over max_nodes={self.cfg.max_nodes}, max_points={self.cfg.max_points}"
        dim = self.agent.features.x.shape[1] if self.agent.ready else msg.x.shape[1]
        if msg.x.ndim != 2 or msg.x.shape != (n, dim) or msg.centers.shape != (n, 3):
            return "bad_feature_size", f"features {msg.x.shape}, centers {msg.centers.shape}, expected ({n}, {dim})"
        arrays = [msg.x, msg.centers] + ([msg.points] if msg.points is not None else [])
        if not all(np.isfinite(a).all() for a in arrays):
            return "invalid_values", "NaN or inf in features, centers or points"
        if n < self.agent.cfg.min_nodes:
            return "too_few_nodes", f"{n} nodes (min_nodes={self.agent.cfg.min_nodes})"
        if msg.points is not None:
            if msg.point_node is None or msg.point_node.shape[0] != msg.points.shape[0] \
                    or (msg.point_node.size and (msg.point_node.min() < 0 or msg.point_node.max() >= n)):
                return "bad_points", "points name nodes that are not in the message"
        return None

    # ---- estimation ----------------------------------------------------------------------
    def _dense_features(self, msg: GraphMessage, timings: dict) -> NodeFeatures:
        """The peer's points per node, padded to the model's K, and their point features Z."""
        t0 = time.perf_counter()
        k = self.model.cfg.shape.points_per_node
        n = msg.num_nodes
        order = np.argsort(msg.point_node, kind="stable")
        node = msg.point_node[order]
        rank = np.arange(node.size) - np.searchsorted(node, node)
        keep = rank < k
        points = np.zeros((n, k, 3), np.float32)
        valid = np.zeros((n, k), bool)
        points[node[keep], rank[keep]] = msg.points[order][keep]
        valid[node[keep], rank[keep]] = True
        z = self.model.point_features(points, valid, msg.centers, msg.x)
        timings["shape"] = timings.get("shape", 0.0) + 1e3 * (time.perf_counter() - t0)
        return NodeFeatures(node_ids=msg.node_ids, centers=msg.centers, x=msg.x,
                            points=points, valid=valid, z=z)

    def _estimate_coarse(self, link: PeerLink, matches, timings: dict, t0: float) -> Estimate:
        src, ref = matches.src_xyz, matches.ref_xyz
        score = matches.score
        mode = "coarse"
        if self.cfg.keep_correspondences and link.kept_own is not None:
            src = np.concatenate([src, link.kept_own])
            ref = np.concatenate([ref, link.kept_peer])
            score = np.concatenate([score, link.kept_score])
            mode = "merged"
        if len(matches) < self.cfg.min_coarse_matches and mode == "coarse":
            return self._unverified(link, mode, "too_few_matches", len(matches), timings, t0)
        return self._run_pose(link, mode, len(matches), src, ref, score, link.dense_cloud, timings, t0)[0]

    def _run_pose(self, link: PeerLink, mode: str, node_matches: int, src, ref, score,
                  peer_cloud, timings: dict, t0: float,
                  dense_seq: int | None = None) -> tuple[Estimate, np.ndarray]:
        """The estimate, and which of the given correspondences are its inliers."""
        t_pose = time.perf_counter()
        # Solved peer -> own and inverted: verification checks the sparse peer points (K per
        # requested node) against the agent's full cloud, not the other way round, where most
        # of the full cloud has no sampled partner and fitness would say nothing.
        res = estimate_pose(np.asarray(ref, np.float64), np.asarray(src, np.float64),
                            weights=np.asarray(score, np.float64), src_cloud=peer_cloud,
                            ref_cloud=self.agent.reference_cloud(self.cfg.pose)
                            if peer_cloud is not None else None,
                            cfg=self.cfg.pose)
        T = np.linalg.inv(np.asarray(res.T, np.float64))
        timings["pose"] = 1e3 * (time.perf_counter() - t_pose)
        timings["total"] = 1e3 * (time.perf_counter() - t0)
        if not res.success:
            reason = res.reason
        elif peer_cloud is None:
            reason = "no_peer_cloud_to_verify"
        else:
            reason = "ok"
        verified = reason == "ok"
        confidence = float(res.footprint_fitness) if np.isfinite(res.footprint_fitness) else 0.0
        est = Estimate(peer_id=link.peer_id, T=T, verified=verified,
                       mode=mode, reason=reason, node_matches=node_matches,
                       correspondences=int(len(src)), inliers=int(res.inliers),
                       inlier_ratio=float(res.inlier_ratio), confidence=confidence,
                       peer_coarse_sequence=link.coarse.sequence if link.coarse else 0,
                       peer_dense_sequence=dense_seq if dense_seq is not None else
                       (link.dense.sequence if link.dense else 0),
                       timing_ms=timings)
        self._count(f"estimates_{mode}")
        if verified:
            self._count("verified")
            link.last_verified = est
        return est, np.asarray(res.inlier_mask, bool)

    def _unverified(self, link: PeerLink, mode: str, reason: str, node_matches: int,
                    timings: dict, t0: float) -> Estimate:
        timings["total"] = 1e3 * (time.perf_counter() - t0)
        self._count(reason)
        return Estimate(peer_id=link.peer_id, T=np.eye(4), verified=False, mode=mode, reason=reason,
                        node_matches=node_matches, correspondences=node_matches, inliers=0,
                        inlier_ratio=0.0, confidence=0.0,
                        peer_coarse_sequence=link.coarse.sequence if link.coarse else 0,
                        peer_dense_sequence=link.dense.sequence if link.dense else 0,
                        timing_ms=timings)

    # ---- dense requests ------------------------------------------------------------------
    def _maybe_request(self, link: PeerLink, matches, now: float) -> DenseRequestMessage | None:
        if len(matches) < self.cfg.min_node_matches or link.pending is not None:
            return None
        if now - link.last_request_at < self.cfg.min_request_interval_s:
            return None
        self._request_seq += 1
        wanted = np.unique(link.coarse.node_ids[matches.ref_idx])
        link.pending = _PendingRequest(self._request_seq, link.coarse.sequence, wanted, now)
        link.last_request_at = now
        self._count("requests")
        return self._request_message(link, link.pending)

    def _request_message(self, link: PeerLink, p: _PendingRequest) -> DenseRequestMessage:
        return DenseRequestMessage(from_agent=self.agent.cfg.name, to_agent=link.peer_id,
                                   sequence=p.sequence, coarse_sequence=p.coarse_sequence,
                                   weights_id=self.agent.weights_id, node_ids=p.node_ids)

    # ---- bookkeeping ---------------------------------------------------------------------
    def _count(self, name: str) -> None:
        self.counters[name] += 1

    def _say_once(self, key, text: str) -> None:
        if key not in self._said:
            self._said.add(key)
            self.log(text)
