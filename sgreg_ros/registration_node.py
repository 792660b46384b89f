"""The `registration` executable: one per robot, in the robot's namespace (e.g. /a).

Builds its own graph from mapping/instances, listens to the coarse and dense graphs of its peers
(the `peers` parameter, or every /<x>/sgreg/coarse it discovers), asks them for dense data, and
publishes every estimate T_<agent>^<peer> on sgreg/registration and the verified ones on
sgreg/transform. All decisions live in sgreg_core.runtime.peers.Peers; its parameters are
declared from the configs (PeersConfig, AgentConfig, GraphConfig, the verdict's min_fitness and min_confidence, and
RegistrationNodeConfig below)."""
from __future__ import annotations

import re
import sys
import time
from dataclasses import dataclass

from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import TransformStamped
from rclpy.node import Node
from sgreg_msgs.msg import CoarseGraph, DenseGraph, DenseRequest, InstanceMap, RegistrationResult

from sgreg_core.config import param
from sgreg_core.maps.scene_graph import GraphConfig
from sgreg_core.net.model import load_model
from sgreg_core.pose.verdict import VerdictConfig
from sgreg_core.runtime.agent import AgentConfig, AgentCore
from sgreg_core.runtime.peers import Peers, PeersConfig

from . import convert, qos
from .params import agent_name_from, declare_and_read, params_of, pick
from .runner import run_node


@dataclass
class RegistrationNodeConfig:
    """What only the registration node decides: who it is, which model, whom it listens to."""

    agent_name: str = param("", "agent id; empty: the node's namespace (/a -> a)")
    weights_path: str = param("", "model weights (.safetensors with its .json); empty: the shipped model")
    peers: list = param(help="peer agent ids; [''] or []: every agent whose /<id>/sgreg/coarse appears",
                        factory=lambda: [""])
    discovery_period_s: float = param(2.0, "how often to look for new peers", 0.1, 60.0)


# the agent's own map is refused or kept as the agent node does; it answers no requests
PARAMS = params_of(RegistrationNodeConfig, PeersConfig, AgentConfig, GraphConfig, VerdictConfig,
                   skip=("dense_min_interval_s",))
COARSE_TOPIC = re.compile(r"^/([A-Za-z0-9_]+)/sgreg/coarse$")


class RegistrationNode(Node):
    def __init__(self):
        super().__init__("sgreg_registration")
        p = declare_and_read(self, PARAMS)
        self.name = agent_name_from(self, p["agent_name"])
        model = load_model(p["weights_path"] or None)
        agent_cfg = AgentConfig(name=self.name, **pick(AgentConfig, p), graph=GraphConfig(**pick(GraphConfig, p)))
        defaults = PeersConfig()
        peers_cfg = PeersConfig(**pick(PeersConfig, p),
                                pipeline=defaults.pipeline.with_verdict(**pick(VerdictConfig, p)))
        self.agent = AgentCore(agent_cfg, model)
        self.agent.warm_up()
        self.peers = Peers(peers_cfg, self.agent, model, log=self.get_logger().warning)
        self.fixed_peers = [x for x in p["peers"] if x]
        self.result_seq = 0
        self.request_pubs: dict[str, object] = {}
        self.transform_pub = self.create_publisher(TransformStamped, "sgreg/transform", qos.RESULTS)
        self.result_pub = self.create_publisher(RegistrationResult, "sgreg/registration", qos.RESULTS)
        self.create_subscription(InstanceMap, "mapping/instances", self.on_instances, qos.INSTANCES, raw=True)
        for peer in self.fixed_peers:
            self.add_peer(peer)
        if not self.fixed_peers:
            self.create_timer(p["discovery_period_s"], self.discover_peers)
        self.diag_pub = self.create_publisher(DiagnosticArray, "sgreg/diagnostics", qos.RESULTS)
        self.create_timer(0.2, self.on_tick)
        self.create_timer(1.0, self.publish_diagnostics)
        self.get_logger().info(f"registration for '{self.name}' up, peers: "
                               f"{self.fixed_peers or 'discovered'}, weights {self.agent.weights_id}")

    # ---- peers ---------------------------------------------------------------------------
    def discover_peers(self) -> None:
        for topic, _ in self.get_topic_names_and_types():
            m = COARSE_TOPIC.match(topic)
            if m and m.group(1) != self.name and m.group(1) not in self.request_pubs:
                self.add_peer(m.group(1))

    def add_peer(self, peer: str) -> None:
        if peer == self.name or peer in self.request_pubs:
            return
        self.request_pubs[peer] = self.create_publisher(DenseRequest, f"/{peer}/sgreg/dense_request",
                                                        qos.DENSE_REQUEST)
        self.create_subscription(CoarseGraph, f"/{peer}/sgreg/coarse", self.on_coarse, qos.COARSE_SUB, raw=True)
        self.create_subscription(DenseGraph, f"/{peer}/sgreg/dense", self.on_dense, qos.DENSE, raw=True)
        self.get_logger().info(f"listening to peer '{peer}'")

    # ---- callbacks -----------------------------------------------------------------------
    def on_instances(self, raw: bytes) -> None:
        why = convert.take_instance_map(raw, self.peers.take_own_map, self.agent.refuse)
        if why:
            self.get_logger().warning(why)

    def on_coarse(self, raw: bytes) -> None:
        graph = self._decode(convert.coarse_from_msg, raw, CoarseGraph, "coarse")
        if graph is None:
            return
        try:
            estimate, request = self.peers.on_coarse(graph, time.monotonic())
        except Exception as exc:  # a bug must cost one estimate, not the node
            return self.internal_error(f"coarse graph {graph.sequence} of {graph.agent_id}", exc)
        if request is not None:
            self.send_request(request)
        self.publish(estimate)

    def on_dense(self, raw: bytes) -> None:
        graph = self._decode(convert.dense_from_msg, raw, DenseGraph, "dense")
        if graph is None:
            return
        try:
            estimate = self.peers.on_dense(graph, time.monotonic())
        except Exception as exc:  # a bug must cost one estimate, not the node
            return self.internal_error(f"dense graph {graph.sequence} of {graph.agent_id}", exc)
        self.publish(estimate)

    def on_tick(self) -> None:
        for request in self.peers.on_tick(time.monotonic()):
            self.send_request(request)

    def publish_diagnostics(self) -> None:
        verified = {p: link.confirmed is not None for p, link in self.peers.links.items()}
        summary = ", ".join(f"{p}: {'registered' if v else 'not registered'}" for p, v in verified.items()) or "no peers yet"
        self.diag_pub.publish(convert.diagnostics_msg(f"sgreg registration {self.name}", self.name,
                                                      dict(self.peers.counters), self.now(), summary))

    def internal_error(self, what: str, exc: Exception) -> None:
        self.get_logger().error(self.agent.refuse("internal_error", f"{what}: internal error {exc!r}; skipped"))

    # ---- helpers -------------------------------------------------------------------------
    def _decode(self, fn, raw: bytes, cls, what: str):
        try:
            return fn(convert.decode(raw, cls))
        except convert.ConversionError as exc:
            self.get_logger().warning(self.agent.refuse("malformed_message", f"malformed {what} graph refused: {exc}"))
            return None

    def send_request(self, request) -> None:
        pub = self.request_pubs.get(request.to_agent)
        if pub is not None:
            pub.publish(convert.request_to_msg(request, self.now()))

    def now(self) -> float:
        return self.get_clock().now().nanoseconds * 1e-9

    def publish(self, estimate) -> None:
        if estimate is None:
            return
        stamp = self.now()
        self.result_seq += 1
        self.result_pub.publish(convert.result_to_msg(estimate, self.name, self.result_seq, stamp,
                                                      dict(self.peers.counters)))
        if estimate.verified:
            self.transform_pub.publish(convert.transform_msg(estimate.T, self.name, estimate.peer_id, stamp))


def main(args=None) -> int:
    return run_node(RegistrationNode, args)


if __name__ == "__main__":
    sys.exit(main())
