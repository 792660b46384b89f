"""The `registration` executable: one per robot, in the robot's namespace (e.g. /a).

Builds its own graph from mapping/instances, listens to the coarse and dense graphs of its peers
(the `peers` parameter, or every /<x>/sgreg/coarse it discovers), asks them for dense data, and
publishes every estimate T_<agent>^<peer> on sgreg/registration and the verified ones on
sgreg/transform. All decisions live in sgreg_core.runtime.Registrar."""
from __future__ import annotations

import re
import sys
import time
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import TransformStamped
from rclpy.node import Node
from sgreg_msgs.msg import CoarseGraph, DenseGraph, DenseRequest, InstanceMap, RegistrationResult

from sgreg_core.net.model import load_model
from sgreg_core.runtime.agent import AgentConfig, AgentCore, AgentInputError
from sgreg_core.runtime.peer import Registrar, RegistrationConfig
from sgreg_core.scene_graph import GraphConfig

from . import convert, qos
from .params import Param, agent_name_from, declare_and_read
from .runner import run_node

PARAMS = [
    Param("agent_name", "", "agent id; empty: the node's namespace (/a -> a)"),
    Param("peers", [""], "peer agent ids; [''] or []: every agent whose /<id>/sgreg/coarse appears"),
    Param("weights_path", "", "model weights (.safetensors with its .json); empty: the shipped model"),
    Param("voxel_size", 0.05, "voxel size of node point clouds (m)", 0.01, 0.5),
    Param("min_nodes", 3, "graphs with fewer nodes are not registered", 1, 1000),
    Param("min_node_matches", 3, "node matches needed before a dense request", 1, 1000),
    Param("min_coarse_matches", 4, "node matches needed for a coarse estimate", 3, 1000),
    Param("min_request_interval_s", 5.0, "at most one dense request per peer per interval", 0.0, 3600.0),
    Param("search_request_interval_s", 2.0, "the request interval while no link to the peer is confirmed", 0.0, 3600.0),
    Param("request_timeout_s", 2.0, "an unanswered dense request is retried after this", 0.1, 600.0),
    Param("retry_backoff", 2.0, "each retry waits this factor longer", 1.0, 10.0),
    Param("max_retries", 3, "retries before giving up until the next interval", 0, 100),
    Param("keep_correspondences", True, "merge the last dense correspondences into coarse estimates"),
    Param("min_fitness", 0.7, "after ICP, the share of the peer's points over own footprint that must lie on own surfaces to verify", 0.05, 1.0),
    Param("max_nodes", 2000, "bigger graphs are refused", 10, 100000),
    Param("max_points", 500_000, "dense graphs with more points are refused", 1000, 50_000_000),
    Param("discovery_period_s", 2.0, "how often to look for new peers", 0.1, 60.0),
]
COARSE_TOPIC = re.compile(r"^/([A-Za-z0-9_]+)/sgreg/coarse$")


class RegistrationNode(Node):
    def __init__(self):
        super().__init__("sgreg_registration")
        p = declare_and_read(self, PARAMS)
        self.name = agent_name_from(self, p["agent_name"])
        model = load_model(p["weights_path"] or None)
        agent_cfg = AgentConfig(name=self.name, min_nodes=p["min_nodes"],
                                graph=GraphConfig(voxel_size=p["voxel_size"]))
        reg_cfg = RegistrationConfig(
            min_node_matches=p["min_node_matches"], min_coarse_matches=p["min_coarse_matches"],
            min_request_interval_s=p["min_request_interval_s"],
            search_request_interval_s=p["search_request_interval_s"], request_timeout_s=p["request_timeout_s"],
            retry_backoff=p["retry_backoff"], max_retries=p["max_retries"],
            keep_correspondences=p["keep_correspondences"],
            register=RegistrationConfig().register.with_verdict(min_fitness=p["min_fitness"]),
            max_nodes=p["max_nodes"],
            max_points=p["max_points"])
        self.agent = AgentCore(agent_cfg, model)
        self.agent.warm_up()
        self.registrar = Registrar(reg_cfg, self.agent, model, log=self.get_logger().warning)
        self.fixed_peers = [x for x in p["peers"] if x]
        self.result_seq = 0
        self.last_map_seq = None
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
        try:
            msg = convert.decode(raw, InstanceMap)
            if msg.sequence == self.last_map_seq:
                return
            self.agent.update_map(convert.instance_map_from_msg(msg), int(msg.sequence),
                                  convert.stamp_to_sec(msg.header.stamp))
            self.registrar.prepare_own_map()
            self.last_map_seq = msg.sequence
        except (convert.ConversionError, AgentInputError) as exc:
            self.registrar.counters["bad_instance_map"] += 1
            self.get_logger().warning(f"instance map refused: {exc}")
        except Exception as exc:  # a bug must cost one map, not the node
            self.internal_error("instance map", exc)

    def on_coarse(self, raw: bytes) -> None:
        graph = self._decode(convert.coarse_from_msg, raw, CoarseGraph, "coarse")
        if graph is None:
            return
        try:
            estimate, request = self.registrar.on_coarse(graph, time.monotonic())
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
            estimate = self.registrar.on_dense(graph, time.monotonic())
        except Exception as exc:  # a bug must cost one estimate, not the node
            return self.internal_error(f"dense graph {graph.sequence} of {graph.agent_id}", exc)
        self.publish(estimate)

    def on_tick(self) -> None:
        for request in self.registrar.on_tick(time.monotonic()):
            self.send_request(request)

    def publish_diagnostics(self) -> None:
        verified = {p: link.confirmed is not None for p, link in self.registrar.peers.items()}
        summary = ", ".join(f"{p}: {'registered' if v else 'not registered'}" for p, v in verified.items()) or "no peers yet"
        self.diag_pub.publish(convert.diagnostics_msg(f"sgreg registration {self.name}", self.name,
                                                      dict(self.registrar.counters), self.now(), summary))

    def internal_error(self, what: str, exc: Exception) -> None:
        self.registrar.counters["internal_error"] += 1
        self.get_logger().error(f"{what}: internal error {exc!r}; skipped")

    # ---- helpers -------------------------------------------------------------------------
    def _decode(self, fn, raw: bytes, cls, what: str):
        try:
            return fn(convert.decode(raw, cls))
        except convert.ConversionError as exc:
            self.registrar.counters["malformed_message"] += 1
            self.get_logger().warning(f"malformed {what} graph refused: {exc}")
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
                                                      dict(self.registrar.counters)))
        if estimate.verified:
            self.transform_pub.publish(convert.transform_msg(estimate.T, self.name, estimate.peer_id, stamp))


def main(args=None) -> int:
    return run_node(RegistrationNode, args)


if __name__ == "__main__":
    sys.exit(main())
