"""An agent's own side: instance map -> scene graph -> node features, the coarse and dense
messages made from them, and the answers to dense requests. Encoding happens once per map
update, not per message. Both nodes of an agent take their maps through `take_map` and count
every refusal in `counters` (one table per node, which the node publishes as diagnostics). A
well-formed map too small to register (fewer than min_nodes nodes: a robot that has seen only
the floor) is no refusal: it is counted as `small_map` and waited out (NotYet).
"""
from __future__ import annotations

import time
from collections import Counter
from dataclasses import dataclass, field, replace

import numpy as np

from ..config import param
from ..maps.instance_map import points_problem, validate_instance_map
from ..net.model import NodeFeatures, SGRegModel
from ..pipeline import reference_cloud
from ..pose import PoseConfig, ReferenceCloud
from ..maps.level import LevelConfig, Levelling, estimate_level
from ..maps.scene_graph import GraphConfig, build_scene_graph
from ..types import InstanceMap, SceneGraph
from .clock import stamp_ns as _stamp_ns
from .auth import is_agent_id
from .messages import DenseRequestMessage, GraphMessage, graph_digest

ANSWER_SLACK = 0.1   # share of dense_min_interval_s a request may come early and be answered


@dataclass
class AgentConfig:
    """name: agent id, also the namespace of its topics.
    min_nodes: a graph with fewer nodes is not broadcast (nothing useful to match).
    max_nodes: a map whose graph has more nodes is refused, and so is a peer's graph with more
        (both nodes read it, so what an agent sends its peers take).
    max_points_in_map: a bigger instance map is refused (protects the node's memory and time).
    dense_min_interval_s: at most one dense answer per requester per this interval (a request
        up to ANSWER_SLACK of it early is on time: a requester that asks again as soon as this
        allows, PeersConfig.prompt_request, would otherwise be refused by jitter alone).
    dense_answers_per_s: at most this many dense answers per second to all requesters
        together (a token bucket of that size): requests under many names cannot make the
        agent send much more than it receives.
    max_answer_nodes: a dense request that would be answered with more nodes (one naming more,
        or an empty one, "all", of a bigger graph) is refused: the budget counts answers, so
        each must stay small (peers ask for their best matched nodes,
        PeersConfig.max_request_nodes).
    quiet_after_s / heartbeat_period_s: once the graph has not changed for quiet_after_s, a
        coarse graph goes out only every heartbeat_period_s (peers that join late get the last
        one at once from the transient-local topic; the heartbeat tells the others the agent
        is alive). Until then it goes out at the node's rate: a front end often holds a map
        still for a few seconds, and peers keep registering against it (on the real replay
        suite, 5 s instead of 20 s lost a fifth of the query frames, most of them successes:
        84.1 % instead of 86.8 % over registrable frames, training rooms 84.9 % vs 87.3 %).
    level / relevel_deg: each map is levelled on its own surfaces before its graph is built
        (maps/level.py); the levelling of the last map is kept while a new map's estimate lies
        within relevel_deg of it, so that a growing map keeps one frame (a re-levelled map
        drops the point correspondences its peers kept: they are in the old frame). 1 deg is
        above the estimate's noise on partial views (0.4 deg median) and within what ICP takes
        up in a full 6-DoF refinement."""

    name: str = "a"
    min_nodes: int = param(3, "graphs with fewer nodes are neither sent nor registered", 1, 1000)
    max_nodes: int = param(2000, "graphs with more nodes are refused, own and peers'", 10, 100_000,
                           live=True)
    max_points_in_map: int = param(2_000_000, "bigger instance maps are refused", 1000, 50_000_000)
    dense_min_interval_s: float = param(1.0, "at most one dense answer per requester per interval (a prompt "
                                        "request waits as long)",
                                        0.0, 3600.0, live=True)
    dense_answers_per_s: float = param(2.0, "dense answers per second to all requesters together",
                                       0.1, 100.0, live=True)
    max_answer_nodes: int = param(100, "dense requests answered with more nodes than this are "
                                  "refused", 3, 100_000, live=True)
    quiet_after_s: float = param(20.0, "coarse graphs drop to the heartbeat once the graph is "
                                 "unchanged for this long", 0.0, 3600.0, live=True)
    heartbeat_period_s: float = param(10.0, "coarse graph period while the graph does not change",
                                      1.0, 3600.0, live=True)
    relevel_deg: float = 1.0
    level: LevelConfig = field(default_factory=LevelConfig)
    graph: GraphConfig = field(default_factory=GraphConfig)

    def __post_init__(self):
        if self.min_nodes > self.max_nodes:   # every map would be too small or refused
            raise ValueError(f"agent: min_nodes ({self.min_nodes}) must not exceed max_nodes ({self.max_nodes})")


class AgentInputError(ValueError):
    """An instance map the agent refuses; the message says why in one line."""


class SmallMapError(AgentInputError):
    """A well-formed instance map whose graph has too few nodes to register yet."""


class NotYet(str):
    """What take_map says of a map that is fine but too small to use yet (the agent keeps what
    it had): no refusal, so neither a warning nor a WARN in the diagnostics, and the front end
    counts as heard from."""


class AgentCore:
    def __init__(self, cfg: AgentConfig, model: SGRegModel):
        self.cfg = cfg
        self.model = model
        self.weights_id = model.weights_id
        self.graph: SceneGraph | None = None
        self.features: NodeFeatures | None = None
        self.digest = ""        # graph_digest of the current graph
        self.map_sequence = 0
        self.stamp_ns = 0     # the map's stamp (ns), carried by every message made from it
        self.timing_ms: dict = {}
        self.level = Levelling()      # how the current map was levelled
        self._reference: tuple[tuple, ReferenceCloud] | None = None
        self._last_answer: dict[str, float] = {}   # requester -> time of the last dense answer
        self._budget = (0.0, -np.inf)                # (tokens, time) of the dense answer budget
        self._last_broadcast: tuple[str, float] = ("", -np.inf)   # (digest, time) of the last coarse
        self._changed_at = -np.inf    # when a coarse graph last went out with new content
        self.counters: Counter = Counter()            # refusals and messages sent, by name
        self.refused = 0                              # inputs refused so far (all counters of refuse)
        self.last_refusal: tuple[str, bool] = ("", False)   # (counter, routine) of the last one

    def warm_up(self) -> None:
        """Load the text encoder now: its first use takes seconds, which would otherwise
        delay the agent's first graph."""
        self.model.text_encoder.encode(["floor"])

    @property
    def ready(self) -> bool:
        return self.features is not None

    def refuse(self, counter: str, why: str, routine: bool = False) -> str:
        """Count a refused input; returns the one-line reason for the log. routine: a refusal
        of a well-formed input that the agent's own limits turn away (rate, budget), counted
        but no sign of trouble (not in `refused`, which the diagnostics warn on)."""
        self.counters[counter] += 1
        self.refused += not routine
        self.last_refusal = (counter, routine)
        return why

    def take_map(self, imap: InstanceMap, map_sequence: int, stamp_ns: int) -> str | None:
        """A new instance map from the agent's own front end: None when it became the agent's
        map, NotYet (counted as small_map) when its graph has too few nodes to use yet, else the
        one-line reason it was refused (counted): the same sequence again, or a map update_map
        refuses. A sequence lower than the current map's is the front end starting over: the
        old map is dropped first (front_end_restarts), whether or not the new one is usable."""
        if self.ready and map_sequence == self.map_sequence:
            return self.refuse("duplicate_map", f"instance map {map_sequence} received twice; ignored")
        restarted = self.ready and map_sequence < self.map_sequence
        if restarted:
            # the front end started over (its sequence went back, its map likely in a new frame):
            # the old graph must not go on standing for this map, not even until the new one is
            # big enough to use
            was = self.map_sequence
            self.forget_map()
            self.counters["front_end_restarts"] += 1
        try:
            self.update_map(imap, map_sequence, stamp_ns)
        except SmallMapError as exc:
            self.counters["small_map"] += 1
            if restarted:
                return NotYet(f"instance map {map_sequence} after {was}: the front end restarted, "
                              f"the old map is dropped; {exc}: not registered until it holds more")
            return NotYet(f"{exc}: not registered until it holds more")
        except AgentInputError as exc:
            return self.refuse("bad_instance_map", f"instance map {map_sequence} refused: {exc}")
        return None

    def forget_map(self) -> None:
        """No map any more: nothing is sent or answered until the next usable one."""
        self.features, self.graph, self.digest, self._reference = None, None, "", None
        self.map_sequence, self.stamp_ns, self.level = 0, 0, Levelling()

    def update_map(self, imap: InstanceMap, map_sequence: int, stamp_ns: int) -> SceneGraph:
        """Rebuild graph and features from a new instance map; raises AgentInputError."""
        size = len(imap.points) if hasattr(imap.points, "__len__") else 0
        if size > self.cfg.max_points_in_map:     # before any copy of it is made
            raise AgentInputError(f"instance map has {size} points "
                                  f"(max_points_in_map={self.cfg.max_points_in_map})")
        try:
            imap = validate_instance_map(imap, where=f"instance map {map_sequence}")
        except ValueError as exc:
            raise AgentInputError(str(exc)) from None
        timings: dict = {}
        t0 = time.perf_counter()
        level = self._level(imap)
        if not np.allclose(level.R, np.eye(3)):
            imap = replace(imap, points=level.apply(imap.points).astype(np.float32))
            far = points_problem(imap.points)
            if far:   # what the agent sends, its peers must take (they check the same bound)
                raise AgentInputError(f"levelled map: {far}")
        timings["level"] = 1e3 * (time.perf_counter() - t0)
        t0 = time.perf_counter()
        graph = build_scene_graph(imap, self.cfg.graph)
        graph.level, graph.map_points = level, imap.points
        timings["graph"] = 1e3 * (time.perf_counter() - t0)
        if graph.num_nodes < self.cfg.min_nodes:
            raise SmallMapError(f"instance map {map_sequence} gives {graph.num_nodes} nodes "
                                f"(min_nodes={self.cfg.min_nodes})")
        if graph.num_nodes > self.cfg.max_nodes:   # every peer would refuse its graphs
            raise AgentInputError(f"instance map {map_sequence} gives {graph.num_nodes} nodes "
                                  f"(max_nodes={self.cfg.max_nodes})")
        self.set_graph(graph, map_sequence, stamp_ns, timings)
        return graph

    def _level(self, imap: InstanceMap) -> Levelling:
        """This map's levelling: the last one while the new estimate agrees with it."""
        new = estimate_level(imap.points, self.cfg.level)
        if not new.ok:
            return self.level if self.ready else new
        drift = np.degrees(np.arccos(np.clip(float(new.up @ self.level.up), -1.0, 1.0)))
        return self.level if self.ready and drift < self.cfg.relevel_deg else new

    def set_graph(self, graph: SceneGraph, map_sequence: int, stamp_ns: int,
                  timings: dict | None = None) -> None:
        """Encode a graph and make it the agent's current one."""
        stamp_ns = _stamp_ns(stamp_ns)
        timings = {} if timings is None else timings
        self.features = self.model.encode(graph, dense=True, timings=timings)
        self.digest = graph_digest(self.features.node_ids, self.features.centers)
        self.graph = graph
        self.level = graph.level if graph.level is not None else Levelling()
        self.map_sequence, self.stamp_ns, self.timing_ms = map_sequence, stamp_ns, timings

    def coarse_due(self, now: float) -> bool:
        """Whether a coarse graph should go out at this tick of the node's rate: the graph
        changed since the last one or within quiet_after_s, or heartbeat_period_s has passed."""
        digest, sent_at = self._last_broadcast
        return self.ready and (self.digest != digest or now - self._changed_at < self.cfg.quiet_after_s
                               or now - sent_at >= self.cfg.heartbeat_period_s)

    def broadcast(self, now: float) -> GraphMessage:
        """The next coarse graph to publish (its sequence counts the coarse graphs sent)."""
        self.counters["coarse_sent"] += 1
        if self.digest != self._last_broadcast[0]:
            self._changed_at = now
        self._last_broadcast = (self.digest, now)
        return self.coarse_message(self.counters["coarse_sent"])

    def coarse_message(self, sequence: int) -> GraphMessage:
        f = self.features
        return GraphMessage(agent_id=self.cfg.name, sequence=sequence,
                            map_sequence=self.map_sequence, weights_id=self.weights_id,
                            stamp_ns=self.stamp_ns,
                            nodes=NodeFeatures(node_ids=f.node_ids, centers=f.centers,
                                               descriptor=f.descriptor),
                            extents=np.asarray(self.graph.extents, np.float32), level=self.level.R)

    def dense_message(self, sequence: int, node_ids: np.ndarray | None = None,
                      requester: str = "", request_sequence: int = 0) -> GraphMessage:
        """Coarse content plus the sampled points of the requested nodes (all when empty)."""
        msg = self.coarse_message(sequence)
        f = self.features
        keep = np.ones(msg.num_nodes, bool)
        if node_ids is not None and len(node_ids):
            keep = np.isin(f.node_ids, np.asarray(node_ids, np.int64))
        idx = np.flatnonzero(keep)
        valid = f.valid[idx]
        node_of_point = np.broadcast_to(np.arange(idx.size)[:, None], valid.shape)[valid]
        msg.nodes = NodeFeatures(node_ids=f.node_ids[idx], centers=f.centers[idx],
                                 descriptor=f.descriptor[idx])
        msg.extents = msg.extents[idx]
        msg.points = f.points[idx][valid].astype(np.float32)
        msg.point_node = node_of_point.astype(np.int64)
        msg.requester, msg.request_sequence = requester, request_sequence
        return msg

    def answer_request(self, req: DenseRequestMessage, now: float) -> tuple[GraphMessage | None, str]:
        """The dense answer to a peer's request, or why there is none.

        Returns (message, "") or (None, one-line reason, counted): a request for another agent,
        from other weights, before any map, or within dense_min_interval_s (less ANSWER_SLACK
        of it) of the last answer to the same requester is not answered."""
        if len(req.from_agent) > 64 or not is_agent_id(req.from_agent) or req.from_agent == self.cfg.name \
                or len(req.node_ids) > 100_000:
            return None, self.refuse("bad_request", f"dense request from {req.from_agent[:64]!r} for "
                                     f"{len(req.node_ids)} nodes refused")
        if req.to_agent != self.cfg.name:
            return None, self.refuse("request_not_for_me", f"dense request for '{req.to_agent}' on "
                                     f"{self.cfg.name}'s topic; ignored")
        if req.weights_id != self.weights_id:
            return None, self.refuse("request_other_weights", f"dense request from {req.from_agent} runs "
                                     f"weights {req.weights_id}, this agent {self.weights_id}; not answered")
        if not self.ready:
            return None, self.refuse("request_before_map", f"dense request from {req.from_agent} "
                                     "before any map; not answered")
        asked = np.isin(self.features.node_ids, np.asarray(req.node_ids, np.int64)).sum() \
            if len(req.node_ids) else len(self.features.node_ids)
        if asked > self.cfg.max_answer_nodes:
            return None, self.refuse("request_too_large", f"dense request {req.sequence} from "
                                     f"{req.from_agent} for {asked} nodes (max_answer_nodes="
                                     f"{self.cfg.max_answer_nodes}); not answered")
        if now - self._last_answer.get(req.from_agent, -np.inf) < \
                (1.0 - ANSWER_SLACK) * self.cfg.dense_min_interval_s:
            return None, self.refuse("request_rate_limited", f"dense request {req.sequence} from "
                                     f"{req.from_agent} within {self.cfg.dense_min_interval_s} s of the "
                                     "last answer; not answered", routine=True)
        rate = self.cfg.dense_answers_per_s
        tokens, then = self._budget
        tokens = min(max(rate, 1.0), tokens + (now - then) * rate)
        if tokens < 1.0:
            return None, self.refuse("request_over_budget", f"dense request {req.sequence} from "
                                     f"{req.from_agent}: over the budget of {rate:g} answers/s; not answered",
                                     routine=True)
        self._budget = (tokens - 1.0, now)
        if len(self._last_answer) > 64:    # only the last interval matters: bounded memory
            self._last_answer = {k: t for k, t in self._last_answer.items()
                                 if now - t < self.cfg.dense_min_interval_s}
        self._last_answer[req.from_agent] = now
        self.counters["dense_sent"] += 1
        return self.dense_message(self.counters["dense_sent"], req.node_ids, req.from_agent,
                                  req.sequence), ""

    def own_cloud(self) -> np.ndarray:
        """Every point of the own map, labelled or not (the node points of a graph set without
        its map): what a peer's points are verified against."""
        return reference_cloud(self.graph).astype(np.float32, copy=False)

    def reference_cloud(self, pose: PoseConfig) -> ReferenceCloud:
        """The own cloud prepared for verification and ICP (voxels, KD-tree, normals,
        footprint), built once per map update: every peer's estimates reuse it."""
        key = (id(self.graph), self.map_sequence, pose.verify_voxel, pose.footprint_cell)
        if self._reference is None or self._reference[0] != key:
            self._reference = key, ReferenceCloud(self.own_cloud(), pose.verify_voxel,
                                                  pose.footprint_cell)
        return self._reference[1]
