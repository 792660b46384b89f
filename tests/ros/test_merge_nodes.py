"""The merger inside a real registration node, over DDS: other agents' links come in on their
sgreg/registration topics, a wrong one is refused by the cycles it breaks, and /tf carries one
tree (sgreg_merged -> <id>/map) that places every agent where the right links say."""
import time

import numpy as np
import pytest
import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from tf2_msgs.msg import TFMessage
from sgreg_msgs.msg import RegistrationResult

from sgreg_core.geometry import invert_transform, yaw_transform
from sgreg_core.metrics import rre, rte
from sgreg_cli import processes
from sgreg_ros import qos
from sgreg_ros.convert import transform_from_msg, transform_msg

WORLD = {"a": yaw_transform(0.4, (1.0, 2.0, 0.0)), "b": yaw_transform(-1.1, (-4.0, 0.5, 0.0)),
         "c": yaw_transform(2.4, (3.0, -6.0, 0.0))}


def link(src: str, dst: str, wrong: bool = False) -> np.ndarray:
    T = invert_transform(WORLD[dst]) @ WORLD[src]
    return yaw_transform(np.radians(35.0), (3.0, -1.0, 0.0)) @ T if wrong else T


def result(agent: str, peer: str, T: np.ndarray, seq: int) -> RegistrationResult:
    r = RegistrationResult()
    r.agent_id, r.peer_id, r.sequence = agent, peer, seq
    r.header.frame_id = f"{peer}/map"
    r.header.stamp.sec = int(time.time())
    r.transform = transform_msg(T, agent, peer, time.time_ns())
    r.verified, r.reason, r.link, r.mode = True, "ok", "confirmed", "dense"
    r.confidence = 0.99
    return r


@pytest.fixture
def node_a(tmp_path):
    rclpy.init()
    procs = processes.start_agents(["a"], overrides={"peers": ["b", "c"], "merge_period_s": 0.5},
                                   executables=("registration",), log_dir=tmp_path)
    node = rclpy.create_node("sgreg_test_links")
    yield node, procs, tmp_path
    processes.stop(procs)
    node.destroy_node()
    rclpy.try_shutdown()


def test_a_wrong_link_is_rejected_and_tf_places_every_agent(node_a):
    node, procs, logs = node_a
    pubs = {x: node.create_publisher(RegistrationResult, f"/{x}/sgreg/registration", qos.RESULTS) for x in "bc"}
    tf, counters = {}, {}

    def on_tf(msg):
        for t in msg.transforms:
            tf[t.child_frame_id] = (t.header.frame_id, transform_from_msg(t))

    def on_diag(msg):
        for s in msg.status:
            if s.name == "/a/registration":
                counters.update({kv.key: kv.value for kv in s.values})

    node.create_subscription(TFMessage, "/tf", on_tf, qos.TF)
    node.create_subscription(DiagnosticArray, "/diagnostics", on_diag, qos.DIAGNOSTICS)
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and not all(node.count_subscribers(f"/{x}/sgreg/registration") for x in "bc"):
        rclpy.spin_once(node, timeout_sec=0.1)
    assert all(node.count_subscribers(f"/{x}/sgreg/registration") for x in "bc"), "a never listened"
    # b and c each publish their links: b -> a, c -> a, c -> b right, and b -> c wrong
    links = [("b", "a", False), ("c", "a", False), ("c", "b", False), ("b", "c", True)]
    seq = 0
    done = lambda: len(tf) == 3 and int(counters.get("links_rejected", 0)) == 1
    deadline = time.monotonic() + 30
    while time.monotonic() < deadline and not done():
        seq += 1
        for src, dst, wrong in links:
            pubs[src].publish(result(src, dst, link(src, dst, wrong), seq))
        end = time.monotonic() + 0.5
        while time.monotonic() < end:
            rclpy.spin_once(node, timeout_sec=0.05)
    assert done(), f"tf {sorted(tf)}, counters {counters}, node alive: {procs[0].proc.poll() is None}"
    for x in "abc":
        parent, T = tf[f"{x}/map"]
        assert parent == "sgreg_merged"
        truth = invert_transform(WORLD["a"]) @ WORLD[x]     # anchored to a, the lowest id
        assert rte(T, truth) < 0.01 and rre(T, truth) < 0.1, x
    log = next(logs.glob("a_registration*.log")).read_text()
    assert "link b -> c rejected: breaks the cycles" in log
