"""Every sgreg_msgs type crosses real DDS between two processes and comes back field-exact."""
import os
import subprocess
import sys
import time
from pathlib import Path

import pytest
import rclpy
from rclpy.qos import QoSProfile, ReliabilityPolicy

import sgreg_msgs.msg as msgs

from .msg_compare import to_plain
from .samples import all_samples

ECHO = Path(__file__).with_name("echo_node.py")


@pytest.fixture
def echo_process():
    proc = subprocess.Popen([sys.executable, str(ECHO)], env=dict(os.environ),
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        assert proc.stdout.readline().strip() == "echo ready"
        yield proc
    finally:
        proc.terminate()
        try:
            proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            proc.kill()


def test_every_type_round_trips_over_dds(echo_process):
    samples = all_samples(seed=7)
    assert len(bytes(samples["DenseGraph"].points.data)) >= 5 * 1024 * 1024
    rclpy.init()
    node = rclpy.create_node("sgreg_roundtrip_test")
    try:
        qos = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
        received = {}
        pubs = {}
        for name in samples:
            cls = getattr(msgs, name)
            pubs[name] = node.create_publisher(cls, f"in/{name}", qos)
            node.create_subscription(cls, f"out/{name}", lambda m, n=name: received.setdefault(n, m), qos)
        deadline = time.monotonic() + 20
        # Wait until discovery matched both directions, then send each message once.
        while time.monotonic() < deadline and not all(
                p.get_subscription_count() > 0 for p in pubs.values()):
            rclpy.spin_once(node, timeout_sec=0.05)
        while time.monotonic() < deadline and not all(
                node.count_publishers(f"out/{n}") > 0 for n in samples):
            rclpy.spin_once(node, timeout_sec=0.05)
        time.sleep(0.3)  # let the echo's subscriptions see our publishers too
        for name, msg in samples.items():
            pubs[name].publish(msg)
        while time.monotonic() < deadline and len(received) < len(samples):
            rclpy.spin_once(node, timeout_sec=0.05)
        assert set(received) == set(samples), f"missing: {set(samples) - set(received)}"
        for name, msg in samples.items():
            assert received[name] == msg, name
            assert to_plain(received[name], msg) == to_plain(msg, msg), name
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
