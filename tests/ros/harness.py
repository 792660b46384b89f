"""A test-side ROS node that feeds instance maps to real agent processes and watches what they
publish: transforms, registration results and diagnostics."""
from __future__ import annotations

import time

import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import TransformStamped
from sgreg_msgs.msg import InstanceMap, RegistrationResult

from sgreg_core.metrics import two_agent_success
from sgreg_core.bench.replay_score import ground_truth
from sgreg_core.simulation.walks import overlapping_views
from sgreg_cli import processes
from sgreg_ros import qos
from sgreg_ros.convert import instance_map_to_msg, transform_from_msg


# quick protocol timings so that tests see requests, retries and give-ups within seconds
FAST = {"min_request_interval_s": 2.0, "request_timeout_s": 1.0, "retry_backoff": 2.0, "max_retries": 2,
        "dense_min_interval_s": 0.5}


def verified_pairs_ok(w, frames, pairs):
    """The last verified transform of every (agent, peer) pair is within the success criterion."""
    for agent, peer in pairs:
        got = w.transforms.get((agent, peer))
        if not got or not two_agent_success(got[-1], ground_truth(frames, agent, peer)):
            return False
    return True



def agent_maps(names, seed=0, rooms=1):
    """One synthetic scene seen by each agent ({name: InstanceMap}, {name: T_scene_map})."""
    return overlapping_views(names, seed, rooms)


class Watcher:
    def __init__(self, names):
        self.node = rclpy.create_node("sgreg_test_watcher")
        self.names = names
        self.transforms: dict[tuple, list] = {}
        self.results: list[RegistrationResult] = []
        self.diagnostics: dict[str, dict] = {}     # node name -> its counters
        self.levels: dict[str, list] = {}          # node name -> levels seen, in order
        self.map_stamps: set[int] = set()           # ns stamps of every map published
        self.node.create_subscription(DiagnosticArray, "/diagnostics", self._on_diag, qos.DIAGNOSTICS)
        self.map_pubs = {}
        for n in names:
            self.watch(n)

    def watch(self, n):
        if n in self.map_pubs:
            return
        self.map_pubs[n] = self.node.create_publisher(InstanceMap, f"/{n}/mapping/instances", qos.INSTANCES)
        self.node.create_subscription(TransformStamped, f"/{n}/sgreg/transform", self._on_tf, qos.RESULTS)
        self.node.create_subscription(RegistrationResult, f"/{n}/sgreg/registration", self.results.append, qos.RESULTS)

    def _on_tf(self, msg):
        key = (msg.child_frame_id.split("/")[0], msg.header.frame_id.split("/")[0])
        self.transforms.setdefault(key, []).append(transform_from_msg(msg))

    def _on_diag(self, msg):
        for s in msg.status:
            self.diagnostics[s.name] = {kv.key: kv.value for kv in s.values}
            self.levels.setdefault(s.name, []).append((s.level[0], s.hardware_id, s.message))

    def counter(self, status_name, key) -> int:
        return int(self.diagnostics.get(status_name, {}).get(key, 0))

    def publisher(self, cls, topic, profile):
        return self.node.create_publisher(cls, topic, profile)

    def spin_until(self, done, timeout, publish_maps=None, period=1.0, each=None):
        """Spin; every `period` s publish the maps in publish_maps ({name: InstanceMap}); call
        each() on every turn (e.g. a test's /clock)."""
        deadline = time.monotonic() + timeout
        seq = {}
        next_pub = 0.0
        while time.monotonic() < deadline:
            if publish_maps and time.monotonic() >= next_pub:
                for name, m in publish_maps.items():
                    seq[name] = seq.get(name, 0) + 1
                    stamp_ns = time.time_ns()
                    self.map_stamps.add(stamp_ns)
                    self.map_pubs[name].publish(instance_map_to_msg(m, name, seq[name], stamp_ns))
                next_pub = time.monotonic() + period
            if each is not None:
                each()
            rclpy.spin_once(self.node, timeout_sec=0.05)
            if done():
                return True
        return done()

    def wait_ready(self, names, timeout=120, per_agent=2):
        """Until every agent's nodes subscribe to its mapping/instances."""
        return self.spin_until(lambda: all(self.node.count_subscribers(f"/{n}/mapping/instances") >= per_agent
                                           for n in names), timeout)

    def close(self):
        self.node.destroy_node()


def alive(procs):
    return [f"{p.agent}/{p.executable}" for p in procs if p.proc.poll() is not None]


__all__ = ["FAST", "agent_maps", "Watcher", "processes", "alive", "verified_pairs_ok"]
