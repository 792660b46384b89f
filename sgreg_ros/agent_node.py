"""The `agent` executable: one per robot, in the robot's namespace (e.g. /a).

Consumes mapping/instances, keeps the latest scene graph and its features, publishes
sgreg/coarse at coarse_rate_hz, and answers sgreg/dense_request with sgreg/dense (rate-limited
per requester). All decisions live in sgreg_core.runtime.agent.AgentCore; its parameters are
declared from the configs (AgentConfig, GraphConfig, and AgentNodeConfig below)."""
from __future__ import annotations

import sys
import time
from dataclasses import dataclass

from diagnostic_msgs.msg import DiagnosticArray
from rclpy.node import Node
from sgreg_msgs.msg import CoarseGraph, DenseGraph, DenseRequest, InstanceMap

from sgreg_core.config import param
from sgreg_core.maps.scene_graph import GraphConfig
from sgreg_core.net.model import load_model
from sgreg_core.runtime.agent import AgentConfig, AgentCore
from sgreg_core.runtime.wire import ENCODINGS

from . import convert, qos
from .params import agent_name_from, declare_and_read, params_of, pick
from .runner import run_node


@dataclass
class AgentNodeConfig:
    """What only the agent node decides: who it is, which model, how often and how it talks."""

    agent_name: str = param("", "agent id; empty: the node's namespace (/a -> a)")
    weights_path: str = param("", "model weights (.safetensors with its .json); empty: the shipped model")
    coarse_rate_hz: float = param(1.0, "coarse graph broadcast rate", 0.05, 20.0)
    feature_encoding: str = param("float16", "node descriptors on the wire", choices=tuple(ENCODINGS))


PARAMS = params_of(AgentNodeConfig, AgentConfig, GraphConfig)


class AgentNode(Node):
    def __init__(self):
        super().__init__("sgreg_agent")
        p = declare_and_read(self, PARAMS)
        self.name = agent_name_from(self, p["agent_name"])
        self.encoding = ENCODINGS[p["feature_encoding"]]
        cfg = AgentConfig(name=self.name, **pick(AgentConfig, p), graph=GraphConfig(**pick(GraphConfig, p)))
        self.core = AgentCore(cfg, load_model(p["weights_path"] or None))
        self.core.warm_up()
        self.coarse_pub = self.create_publisher(CoarseGraph, "sgreg/coarse", qos.COARSE)
        self.dense_pub = self.create_publisher(DenseGraph, "sgreg/dense", qos.DENSE)
        self.create_subscription(InstanceMap, "mapping/instances", self.on_instances, qos.INSTANCES, raw=True)
        self.create_subscription(DenseRequest, "sgreg/dense_request", self.on_request, qos.DENSE_REQUEST, raw=True)
        self.diag_pub = self.create_publisher(DiagnosticArray, "sgreg/diagnostics", qos.RESULTS)
        self.create_timer(1.0 / p["coarse_rate_hz"], self.publish_coarse)
        self.create_timer(1.0, self.publish_diagnostics)
        self.get_logger().info(f"agent '{self.name}' up, weights {self.core.weights_id}")

    def warn(self, why: str | None) -> None:
        if why:
            self.get_logger().warning(why)

    def on_instances(self, raw: bytes) -> None:
        self.warn(convert.take_instance_map(raw, self.core.take_map, self.core.refuse))

    def publish_coarse(self) -> None:
        if self.core.ready:
            self.coarse_pub.publish(convert.coarse_to_msg(self.core.broadcast(), self.encoding))

    def publish_diagnostics(self) -> None:
        summary = (f"map {self.core.map_sequence}: {self.core.graph.num_nodes} nodes" if self.core.ready
                   else "waiting for the first instance map")
        stamp = self.get_clock().now().nanoseconds * 1e-9
        self.diag_pub.publish(convert.diagnostics_msg(f"sgreg agent {self.name}", self.name,
                                                      dict(self.core.counters), stamp, summary))

    def on_request(self, raw: bytes) -> None:
        try:
            req = convert.request_from_msg(convert.decode(raw, DenseRequest))
        except convert.ConversionError as exc:
            return self.warn(self.core.refuse("malformed_message", f"dense request refused: {exc}"))
        dense, why = self.core.answer_request(req, time.monotonic())
        if dense is None:
            return self.warn(why)
        self.dense_pub.publish(convert.dense_to_msg(dense, self.encoding))


def main(args=None) -> int:
    return run_node(AgentNode, args)


if __name__ == "__main__":
    sys.exit(main())
