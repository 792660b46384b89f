"""The `agent` executable: one per robot, in the robot's namespace (e.g. /a).

Consumes mapping/instances, keeps the latest scene graph and its features, publishes
sgreg/coarse at coarse_rate_hz, and answers sgreg/dense_request with sgreg/dense (rate-limited
per requester). All decisions live in sgreg_core.runtime.AgentCore."""
from __future__ import annotations

import sys
import time

from diagnostic_msgs.msg import DiagnosticArray
from rclpy.node import Node
from sgreg_msgs.msg import CoarseGraph, DenseGraph, DenseRequest, InstanceMap

from sgreg_core.net.model import load_model
from sgreg_core.runtime.agent import AgentConfig, AgentCore, AgentInputError
from sgreg_core.runtime.wire import ENCODINGS
from sgreg_core.scene_graph import GraphConfig

from . import convert, qos
from .params import Param, agent_name_from, declare_and_read
from .runner import run_node

PARAMS = [
    Param("agent_name", "", "agent id; empty: the node's namespace (/a -> a)"),
    Param("weights_path", "", "model weights (.safetensors with its .json); empty: the shipped model"),
    Param("coarse_rate_hz", 1.0, "coarse graph broadcast rate", 0.05, 20.0),
    Param("dense_min_interval_s", 1.0, "at most one dense answer per requester per interval", 0.0, 3600.0),
    Param("feature_encoding", "float16", "node features on the wire", choices=tuple(ENCODINGS)),
    Param("voxel_size", 0.05, "voxel size of node point clouds (m)", 0.01, 0.5),
    Param("min_nodes", 3, "a graph with fewer nodes is not broadcast", 1, 1000),
    Param("max_points_in_map", 2_000_000, "bigger instance maps are refused", 1000, 50_000_000),
]


class AgentNode(Node):
    def __init__(self):
        super().__init__("sgreg_agent")
        p = declare_and_read(self, PARAMS)
        self.name = agent_name_from(self, p["agent_name"])
        self.encoding = ENCODINGS[p["feature_encoding"]]
        cfg = AgentConfig(name=self.name, min_nodes=p["min_nodes"],
                          max_points_in_map=p["max_points_in_map"],
                          dense_min_interval_s=p["dense_min_interval_s"],
                          graph=GraphConfig(voxel_size=p["voxel_size"]))
        self.core = AgentCore(cfg, load_model(p["weights_path"] or None))
        self.core.warm_up()
        self.counters: dict[str, int] = {}
        self.coarse_seq = 0
        self.last_map_seq: int | None = None
        self.coarse_pub = self.create_publisher(CoarseGraph, "sgreg/coarse", qos.COARSE)
        self.dense_pub = self.create_publisher(DenseGraph, "sgreg/dense", qos.DENSE)
        self.create_subscription(InstanceMap, "mapping/instances", self.on_instances, qos.INSTANCES, raw=True)
        self.create_subscription(DenseRequest, "sgreg/dense_request", self.on_request, qos.DENSE_REQUEST, raw=True)
        self.diag_pub = self.create_publisher(DiagnosticArray, "sgreg/diagnostics", qos.RESULTS)
        self.create_timer(1.0 / p["coarse_rate_hz"], self.publish_coarse)
        self.create_timer(1.0, self.publish_diagnostics)
        self.get_logger().info(f"agent '{self.name}' up, weights {self.core.weights_id}")

    def count(self, name: str, why: str | None = None) -> None:
        self.counters[name] = self.counters.get(name, 0) + 1
        if why:
            self.get_logger().warning(why)

    def on_instances(self, raw: bytes) -> None:
        try:
            msg = convert.decode(raw, InstanceMap)
        except convert.ConversionError as exc:
            return self.count("malformed_message", f"instance map refused: {exc}")
        if self.last_map_seq is not None and msg.sequence == self.last_map_seq:
            return self.count("duplicate_map", f"instance map {msg.sequence} received twice; ignored")
        try:
            imap = convert.instance_map_from_msg(msg)
            graph = self.core.update_map(imap, int(msg.sequence), convert.stamp_to_sec(msg.header.stamp))
        except (convert.ConversionError, AgentInputError) as exc:
            return self.count("bad_instance_map", f"instance map {msg.sequence} refused: {exc}")
        except Exception as exc:  # a bug must cost one map, not the node
            return self.count("internal_error", f"instance map {msg.sequence} failed: {exc!r}")
        self.last_map_seq = msg.sequence
        self.get_logger().debug(f"map {msg.sequence}: {graph.num_nodes} nodes, {graph.num_edges} edges")

    def publish_coarse(self) -> None:
        if not self.core.ready:
            return
        self.coarse_seq += 1
        self.coarse_pub.publish(convert.coarse_to_msg(self.core.coarse_message(self.coarse_seq), self.encoding))

    def publish_diagnostics(self) -> None:
        summary = (f"map {self.core.map_sequence}: {self.core.graph.num_nodes} nodes" if self.core.ready
                   else "waiting for the first instance map")
        stamp = self.get_clock().now().nanoseconds * 1e-9
        counters = {**self.counters, "coarse_sent": self.coarse_seq, "dense_sent": self.core.dense_sent}
        self.diag_pub.publish(convert.diagnostics_msg(f"sgreg agent {self.name}", self.name, counters, stamp, summary))

    def on_request(self, raw: bytes) -> None:
        try:
            req = convert.request_from_msg(convert.decode(raw, DenseRequest))
        except convert.ConversionError as exc:
            return self.count("malformed_message", f"dense request refused: {exc}")
        dense, counter, why = self.core.answer_request(req, time.monotonic())
        if dense is None:
            return self.count(counter, why)
        self.dense_pub.publish(convert.dense_to_msg(dense, self.encoding))


def main(args=None) -> int:
    return run_node(AgentNode, args)


if __name__ == "__main__":
    sys.exit(main())
