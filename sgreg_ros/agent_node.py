"""The `agent` node: one per robot, in the robot's namespace (e.g. /a).

Consumes mapping/instances, keeps the latest scene graph and its features, publishes
sgreg/coarse (at coarse_rate_hz, dropping to every heartbeat_period_s once the graph has not
changed for quiet_after_s), and answers sgreg/dense_request with sgreg/dense (rate-limited per requester). All
decisions live in sgreg_core.runtime.agent.AgentCore; its parameters are declared from the
configs (AgentConfig, GraphConfig, HealthConfig and AgentNodeConfig below)."""
from __future__ import annotations

from dataclasses import dataclass, replace

from sgreg_msgs.msg import CoarseGraph, DenseGraph, DenseRequest, InstanceMap

from sgreg_core.config import param
from sgreg_core.maps.scene_graph import GraphConfig
from sgreg_core.runtime.agent import AgentConfig, AgentCore
from sgreg_core.runtime.auth import AuthConfig
from sgreg_core.runtime.health import HealthConfig
from sgreg_core.runtime.wire import DEFAULT_ENCODING, ENCODINGS

from . import convert, qos
from .node_base import SgregNode
from .params import parameter_errors, params_of, pick


@dataclass
class AgentNodeConfig:
    """What only the agent node decides: who it is, which model, how often and how it talks."""

    agent_name: str = param("", "agent id and topic prefix (/<id>/sgreg/...); empty: the node's namespace")
    weights_path: str = param("", "model weights (.safetensors with its .json); empty: the shipped model")
    coarse_rate_hz: float = param(1.0, "coarse graph rate while the graph changes", 0.05, 20.0, live=True)
    feature_encoding: str = param(DEFAULT_ENCODING, "node descriptors on the wire", choices=tuple(ENCODINGS),
                                  live=True)


PARAMS = params_of(AgentNodeConfig, AgentConfig, GraphConfig, HealthConfig, AuthConfig)


class AgentNode(SgregNode):
    def __init__(self):
        super().__init__("agent", PARAMS, "sgreg/coarse")
        p = self.p
        self.encoding = ENCODINGS[p["feature_encoding"]]
        model = self.load_model()
        self.core = None
        if model is not None:
            with parameter_errors():
                cfg = AgentConfig(name=self.name, **pick(AgentConfig, p), graph=GraphConfig(**pick(GraphConfig, p)))
            self.core = AgentCore(cfg, model)
            self.core.warm_up()
            self.coarse_pub = self.create_publisher(CoarseGraph, self.topic("sgreg/coarse"), qos.COARSE)
            self.dense_pub = self.create_publisher(DenseGraph, self.topic("sgreg/dense"), qos.DENSE)
            self.create_subscription(InstanceMap, self.topic("mapping/instances"), self.on_instances,
                                     qos.INSTANCES, raw=True)
            self.create_subscription(DenseRequest, self.topic("sgreg/dense_request"), self.on_request,
                                     qos.DENSE_REQUEST, raw=True)
            self.coarse_timer = self.create_timer(1.0 / p["coarse_rate_hz"], self.on_coarse_timer)
            self.get_logger().info(f"agent '{self.name}' up, weights {self.core.weights_id}")
        self.accept_live_parameters()

    def apply(self, changes: dict) -> None:
        # the new config first: values that do not fit the others change nothing (ValueError)
        cfg = replace(self.core.cfg, **pick(AgentConfig, changes)) if self.core is not None else None
        if "feature_encoding" in changes:
            self.encoding = ENCODINGS[changes["feature_encoding"]]
        if self.core is None:
            return
        if "coarse_rate_hz" in changes:
            self.destroy_timer(self.coarse_timer)
            self.coarse_timer = self.create_timer(1.0 / changes["coarse_rate_hz"], self.on_coarse_timer)
        self.core.cfg = cfg

    def guarded(self, what: str, work) -> None:
        super().guarded(what, work, self.core.refuse)

    def on_instances(self, raw: bytes) -> None:
        self.map_taken(convert.take_instance_map(raw, self.core.take_map, self.core.refuse,
                                                 self.core.cfg.name, self.stamp_clock_ns(),
                                                 self.core.cfg.max_points_in_map))
        if self.core.ready and not self.core.counters["coarse_sent"]:
            # the first graph goes out at once, and the timer starts over: the same graph again
            # at the next tick, a fraction of a second later, would be no new evidence to a peer
            self.on_coarse_timer()
            self.coarse_timer.reset()

    def on_coarse_timer(self) -> None:
        self.guarded("the coarse graph", self.publish_coarse)

    def publish_coarse(self) -> None:
        now = self.clock_s()
        if self.core.coarse_due(now):
            msg = convert.coarse_to_msg(self.core.broadcast(now), self.encoding)
            self.coarse_pub.publish(self.auth.sign(msg, self.topic("sgreg/coarse")))

    def on_request(self, raw: bytes) -> None:
        # no request names more nodes than a graph may hold, or than the one sent holds (max_nodes
        # may have been lowered live since)
        held = self.core.graph.num_nodes if self.core.graph is not None else 0
        limit = convert.max_request_bytes(max(self.core.cfg.max_nodes, held))
        if len(raw) > limit:
            return self.refusal(self.core.refuse("oversized_message", f"dense request of {len(raw)} bytes "
                                                 f"refused before decoding (max {limit})"),
                                key="oversized request")
        try:
            msg = convert.decode(raw, DenseRequest)
        except convert.ConversionError as exc:
            return self.refusal(self.core.refuse("malformed_message", f"dense request refused: {exc}"),
                                key="malformed request")
        # who sent it before anything of it is converted: a stranger's request costs a signature check
        refused = self.auth.check(msg, self.topic("sgreg/dense_request"), msg.from_agent)
        if refused:
            return self.refusal(self.core.refuse(refused, f"dense request {msg.sequence} "
                                                 f"from {msg.from_agent!r} refused: {refused}"), key=refused)
        try:
            req = convert.request_from_msg(msg)
        except convert.ConversionError as exc:
            return self.refusal(self.core.refuse("malformed_message", f"dense request refused: {exc}"),
                                key="malformed request")
        self.guarded(f"dense request {req.sequence} of {req.from_agent!r}", lambda: self._answer(req))

    def _answer(self, req) -> None:
        dense, why = self.core.answer_request(req, self.clock_s())
        if dense is None:   # one log key per kind of refusal; the agent's own limits at info
            counter, routine = self.core.last_refusal
            return self.refusal(why, key=counter, quiet=routine)
        msg = convert.dense_to_msg(dense, self.encoding)
        self.dense_pub.publish(self.auth.sign(msg, self.topic("sgreg/dense")))

    # ---- diagnostics ---------------------------------------------------------------------
    def counters(self) -> dict:
        return dict(self.core.counters) if self.core else {}

    def refused(self) -> int:
        return self.core.refused if self.core else 0

    def summary(self) -> str:
        if self.core is None or not self.core.ready:
            small = self.core.counters["small_map"] if self.core else 0
            return (f"waiting for a map of {self.core.cfg.min_nodes} nodes or more ({small} too "
                    "small so far)") if small else "waiting for the first instance map"
        return f"map {self.core.map_sequence}: {self.core.graph.num_nodes} nodes"
