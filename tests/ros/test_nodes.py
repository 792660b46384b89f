"""Real agent and registration nodes, as separate processes over DDS on loopback (a domain of
this run's own): two agents register and every failure case of
docs/ARCHITECTURE.md ("Failure behaviour") is counted while the nodes carry on."""
import copy
import os
import re
import signal
import time

import numpy as np
import pytest
import rclpy
from sgreg_msgs.msg import CoarseGraph, DenseGraph, DenseRequest, InstanceMap

from sgreg_core.metrics import two_agent_success
from sgreg_core.bench.replay_score import ground_truth
from sgreg_core.types import InstanceMap as CoreMap
from sgreg_ros import qos
from sgreg_ros.convert import instance_map_to_msg, stamp_to_ns

from .harness import FAST, Watcher, agent_maps, alive, processes, verified_pairs_ok



@pytest.fixture(scope="module")
def ros():
    rclpy.init()
    yield
    rclpy.try_shutdown()


@pytest.fixture(scope="module")
def two(ros, tmp_path_factory):
    names = ["a", "b"]
    maps, frames = agent_maps(names, seed=11)
    procs = processes.start_agents(names, overrides=FAST, log_dir=tmp_path_factory.mktemp("logs"))
    w = Watcher(names)
    coarse_b = []
    w.node.create_subscription(CoarseGraph, "/b/sgreg/coarse", coarse_b.append, qos.COARSE)
    try:
        assert w.wait_ready(names), f"nodes did not start; dead: {alive(procs)}"
        yield procs, w, maps, frames, coarse_b
    finally:
        processes.stop(procs)
        w.close()


def test_two_agents_reach_a_verified_transform(two):
    procs, w, maps, frames, _ = two
    pairs = [("a", "b"), ("b", "a")]
    assert w.spin_until(lambda: verified_pairs_ok(w, frames, pairs), 90, publish_maps=maps), (
        f"no correct verified transform; results: {[(r.agent_id, r.mode, r.reason) for r in w.results[-6:]]}")
    # nothing published as verified was wrong
    for (agent, peer), Ts in w.transforms.items():
        gt = ground_truth(frames, agent, peer)
        assert all(two_agent_success(T, gt) for T in Ts), (agent, peer)
    # every result carries the stamp of a map it was made from, to the nanosecond
    assert {stamp_to_ns(r.header.stamp) for r in w.results} <= w.map_stamps
    assert not alive(procs)


def test_bad_input_is_counted_and_the_nodes_carry_on(two):
    procs, w, maps, frames, coarse_b = two
    assert w.spin_until(lambda: coarse_b, 30, publish_maps=maps)
    pub_map = w.publisher(InstanceMap, "/a/mapping/instances", qos.INSTANCES)
    pub_x = w.publisher(CoarseGraph, "/x/sgreg/coarse", qos.COARSE)
    pub_req = w.publisher(DenseRequest, "/a/sgreg/dense_request", qos.DENSE_REQUEST)
    pub_x_dense = w.publisher(DenseGraph, "/x/sgreg/dense", qos.DENSE)
    good = coarse_b[-1]

    empty = CoreMap(points=np.zeros((0, 3), np.float32), instance=np.zeros(0, np.int32), labels={})
    nan = copy.deepcopy(maps["a"])
    nan.points = nan.points.copy()
    nan.points[::7] = np.nan
    tiny = copy.deepcopy(maps["a"])
    keep = tiny.instance == tiny.instance[tiny.instance > 0][0]
    tiny = CoreMap(points=tiny.points[keep], instance=tiny.instance[keep], labels=tiny.labels)

    def fake_coarse(seq, **changes):
        m = copy.deepcopy(good)
        m.agent_id, m.sequence = "x", seq
        for k, v in changes.items():
            setattr(m, k, v)
        return m

    big = fake_coarse(60)
    n = 3000
    big.node_ids = list(range(n))
    big.centers, big.extents = [0.0] * 3 * n, [1.0] * 3 * n
    big.feature_scales = []
    big.feature_encoding = CoarseGraph.FEATURE_FLOAT16
    big.features = bytes(2 * n * good.feature_dim)
    # (publisher, message): one at a time, since the topics keep only the newest message
    bad = [(pub_map, instance_map_to_msg(m, "a", 10_000 + i, time.time_ns())) for i, m in enumerate((empty, nan, tiny))]
    # b's map on a's input (a remapping slip): taken as a's own, it verified the identity as a -> b
    other_frame = instance_map_to_msg(maps["b"], "a", 10_003, time.time_ns())
    other_frame.header.frame_id = "b/map"
    bad += [(pub_map, instance_map_to_msg(maps["b"], "b", 10_004, time.time_ns())), (pub_map, other_frame),
            (pub_map, instance_map_to_msg(maps["a"], "a", 10_005, 0)),       # unstamped
            (pub_map, instance_map_to_msg(maps["a"], "a", 10_006, time.time_ns() + 10 * 365 * 86400 * 10**9))]
    bad += [(pub_map, b"\x00\x01garbage"),                              # undecodable
            (pub_x, b"\x00\x01\x00\x00garbage"),
            (pub_x, fake_coarse(50, weights_id="deadbeef0000")),       # other weights
            (pub_x, fake_coarse(51, feature_dim=good.feature_dim + 8, feature_encoding=CoarseGraph.FEATURE_FLOAT16,
                                feature_scales=[], features=bytes(2 * len(good.node_ids) * (good.feature_dim + 8)))),  # wrong size
            (pub_x, fake_coarse(52)),
            (pub_x, fake_coarse(52)),                                  # duplicate
            (pub_x, fake_coarse(40)),                                  # out of order
            (pub_x, big),                                              # oversized
            (pub_req, DenseRequest(from_agent="b", to_agent="c", sequence=1, weights_id=good.weights_id)),
            (pub_x_dense, DenseGraph(agent_id="x", sequence=1, requester="c", request_sequence=1,
                                     graph=fake_coarse(53)))]   # x's answer to c: a's to skip, points unread

    def inject():
        for pub, msg in bad:
            pub.publish(msg)
            w.spin_until(lambda: False, 1.0)

    # the registration node discovers /x/sgreg/coarse first; then inject and watch the counters
    assert w.spin_until(lambda: w.node.count_subscribers("/x/sgreg/coarse") >= 2, 30)
    time.sleep(1.0)
    inject()
    reg_a, agent_a = "/a/registration", "/a/agent"
    # the map of one object is no bad input: a front end's first maps are that small
    wanted = [(agent_a, "bad_instance_map", 6), (agent_a, "small_map", 1), (reg_a, "small_map", 1),
              (agent_a, "malformed_message", 1),
              (reg_a, "malformed_message", 1), (reg_a, "rejected_weights", 1),
              (reg_a, "bad_feature_size", 1), (reg_a, "duplicate_sequence", 1),
              (reg_a, "out_of_order_sequence", 1), (reg_a, "oversized_message", 1),
              (agent_a, "request_not_for_me", 1), (reg_a, "dense_for_others", 1)]
    ok = w.spin_until(lambda: all(w.counter(s, k) >= n for s, k, n in wanted), 30)
    assert ok, {f"{s}:{k}": w.counter(s, k) for s, k, n in wanted if w.counter(s, k) < n}
    # the garbage map and the garbage coarse graph; not the answer to c: it was not decoded
    assert w.counter(reg_a, "malformed_message") == 2
    assert w.counter(agent_a, "bad_instance_map") == 6 and w.counter(reg_a, "small_map") == 1
    assert not alive(procs)
    # and registration goes on: a fresh verified transform arrives after the bad input
    before = len(w.transforms.get(("a", "b"), []))
    assert w.spin_until(lambda: len(w.transforms.get(("a", "b"), [])) > before, 60, publish_maps=maps)
    for (agent, peer), Ts in w.transforms.items():     # and nothing wrong was published
        assert all(two_agent_success(T, ground_truth(frames, agent, peer)) for T in Ts), (agent, peer)


def test_a_peer_that_never_answers(two):
    procs, w, maps, frames, coarse_b = two
    assert w.spin_until(lambda: coarse_b, 30, publish_maps=maps)
    pub_q = w.publisher(CoarseGraph, "/q/sgreg/coarse", qos.COARSE)
    seq = [0]

    def publish_q():
        m = copy.deepcopy(coarse_b[-1])
        seq[0] += 1
        m.agent_id, m.sequence = "q", seq[0]
        pub_q.publish(m)

    deadline = time.monotonic() + 60
    reg_a = "/a/registration"
    while time.monotonic() < deadline and w.counter(reg_a, "request_gave_up") < 1:
        publish_q()
        w.spin_until(lambda: False, 1.0, publish_maps=maps)
    assert w.counter(reg_a, "request_retry") >= 2
    assert w.counter(reg_a, "request_gave_up") >= 1
    assert not alive(procs)


def test_a_peer_that_restarts(two, tmp_path):
    procs, w, maps, frames, _ = two
    assert w.spin_until(lambda: verified_pairs_ok(w, frames, [("a", "b")]), 90, publish_maps=maps)
    for p in [p for p in procs if p.agent == "b"]:
        os.killpg(p.proc.pid, signal.SIGKILL)
        p.proc.wait()
        procs.remove(p)
    procs += processes.start_agents(["b"], overrides=FAST, log_dir=tmp_path)
    w.transforms.pop(("a", "b"), None)
    assert w.wait_ready(["b"]), f"restarted b did not start; dead: {alive(procs)}"
    assert w.spin_until(lambda: w.counter("/a/registration", "peer_restart") >= 1
                        and verified_pairs_ok(w, frames, [("a", "b")]), 120, publish_maps=maps), (
        # what a heard, for a failure that DDS discovery of the restarted b may cause
        w.diagnostics.get("/a/registration"),
        [(r.agent_id, r.peer_id, r.mode, r.reason) for r in w.results[-6:]])
    assert not alive(procs)


def test_an_agent_started_twice_is_reported(two, tmp_path):
    """A second agent node named b (a launch file run twice): both report ERROR on /diagnostics
    while it runs; its peers would take the two for one agent that keeps restarting."""
    procs, w, maps, _, _ = two
    twin = processes.start_agents(["b"], executables=("agent",), overrides=FAST, log_dir=tmp_path,
                                  log_suffix="_twin")
    try:
        def reporting_pids():
            return {re.search(r"process (\d+)", message).group(1)
                    for level, _, message in w.levels.get("/b/agent", [])
                    if level == 2 and "running twice" in message}

        # both twins, told apart by the process they name
        assert w.spin_until(lambda: len(reporting_pids()) == 2, 60, publish_maps=maps), \
            w.levels.get("/b/agent", [])[-3:]
        assert reporting_pids() == {str(p.proc.pid) for p in procs + twin
                                    if p.agent == "b" and p.executable == "agent"}
        assert not any("running twice" in m for _, _, m in w.levels.get("/a/agent", []))
    finally:
        processes.stop(twin)
    assert not alive(procs)
