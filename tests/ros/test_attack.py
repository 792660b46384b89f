"""The probes of a hostile process on the same DDS domain, against real nodes of a signed fleet
(a and b share a keystore; the attacker holds no key of theirs): forged and moved graphs on b's
topics and in b's name elsewhere, a PointCloud2 whose offsets lie past the point, a sequence
number at the end of the range, forged dense requests under fifty names, and fifty fake peers.
Every probe: refused and counted, no crash, nothing wrong verified, and a still registers b."""
import copy

import numpy as np
import pytest
import rclpy
from rclpy.serialization import deserialize_message
from sgreg_msgs.msg import CoarseGraph, DenseGraph, DenseRequest

from sgreg_core.bench.replay_score import ground_truth
from sgreg_core.geometry import yaw_transform
from sgreg_core.metrics import two_agent_success
from sgreg_core.runtime.auth import init_keystore
from sgreg_ros import qos

from .harness import FAST, Watcher, agent_maps, alive, processes, verified_pairs_ok

W = yaw_transform(np.pi / 2, (8.0, 3.0, 0.0))     # where the attacker moves b's graphs


def moved(msg: CoarseGraph) -> CoarseGraph:
    m = copy.deepcopy(msg)
    c = np.asarray(m.centers, np.float32).reshape(-1, 3)
    m.centers = (c @ W[:3, :3].T + W[:3, 3]).astype(np.float32).ravel().tolist()
    return m


@pytest.fixture(scope="module")
def fleet(tmp_path_factory):
    keys = tmp_path_factory.mktemp("keys")
    init_keystore(keys, ["a", "b"])
    rclpy.init()
    maps, frames = agent_maps(["a", "b"], seed=21)
    procs = processes.start_agents(["a", "b"], overrides={**FAST, "keystore": str(keys)},
                                   log_dir=tmp_path_factory.mktemp("logs"))
    w = Watcher(["a", "b"])
    seen = {"coarse": [], "dense": [], "dense_out_of_a": 0}     # b's genuine messages, captured
    capture = [w.node.create_subscription(CoarseGraph, "/b/sgreg/coarse", seen["coarse"].append,
                                          qos.COARSE_SUB, raw=True),
               w.node.create_subscription(DenseGraph, "/b/sgreg/dense", seen["dense"].append,
                                          qos.DENSE, raw=True)]

    def count_a(_):
        seen["dense_out_of_a"] += 1
    w.node.create_subscription(DenseGraph, "/a/sgreg/dense", count_a, qos.DENSE, raw=True)
    assert w.wait_ready(["a", "b"]), f"dead: {alive(procs)}"
    assert w.spin_until(lambda: verified_pairs_ok(w, frames, [("a", "b")]) and seen["dense"], 120,
                        publish_maps=maps), "the signed fleet did not register"
    for sub in capture:     # the probes publish on b's topics too: keep only what b sent
        w.node.destroy_subscription(sub)
    yield w, procs, maps, frames, seen
    processes.stop(procs)
    w.close()
    rclpy.try_shutdown()


def nothing_wrong(w, frames):
    for (agent, peer), Ts in w.transforms.items():
        assert all(two_agent_success(T, ground_truth(frames, agent, peer)) for T in Ts), (agent, peer)


def test_forged_and_moved_graphs_are_refused(fleet):
    w, procs, maps, frames, seen = fleet
    real = deserialize_message(seen["coarse"][-1], CoarseGraph)
    dense = deserialize_message(seen["dense"][-1], DenseGraph)
    # deeper queues than the nodes' own: every probe is delivered
    on_b = w.publisher(CoarseGraph, "/b/sgreg/coarse", qos.COARSE_SUB)
    dense_b = w.publisher(DenseGraph, "/b/sgreg/dense", qos.RESULTS)
    on_c = w.publisher(CoarseGraph, "/c/sgreg/coarse", qos.COARSE_SUB)
    for k in range(6):
        fake = moved(real)
        fake.sequence = real.sequence + 1 + k          # signed by b, but the content changed
        on_b.publish(fake)
        stripped = copy.deepcopy(fake)
        stripped.key_id, stripped.signature = "", b""
        on_b.publish(stripped)                         # no signature at all
        on_c.publish(fake)                             # in b's name on another agent's topic
        d = copy.deepcopy(dense)
        d.graph, d.sequence = moved(d.graph), d.sequence + 1 + k
        dense_b.publish(d)
        w.spin_until(lambda: False, 0.5, publish_maps=maps)
    assert w.spin_until(lambda: w.counter("/a/registration", "bad_signature") >= 6
                        and w.counter("/a/registration", "unsigned") >= 6, 30), w.diagnostics.get("/a/registration")
    w.transforms.clear()
    assert w.spin_until(lambda: verified_pairs_ok(w, frames, [("a", "b")]), 60, publish_maps=maps)
    nothing_wrong(w, frames)
    assert not alive(procs)


def test_replayed_signed_messages_change_nothing(fleet):
    """b's own signed graphs, captured and sent again: valid signatures, old sequence numbers."""
    w, procs, maps, frames, seen = fleet
    pub = w.publisher(CoarseGraph, "/b/sgreg/coarse", qos.COARSE_SUB)
    def refused():   # played again within max_age_s: replayed; older: stale
        return sum(w.counter("/a/registration", k) for k in ("replayed", "stale_message"))

    before = refused()
    assert w.spin_until(lambda: pub.get_subscription_count() >= 1, 10)   # a's registration
    # one at a time, sent again until it is counted: a busy node keeps only the newest few of a
    # burst (depth 4), and every copy of a captured message is refused alike
    for n, raw in enumerate(seen["coarse"][:3] + seen["coarse"][-3:], start=1):
        msg = deserialize_message(raw, CoarseGraph)
        for _ in range(10):
            pub.publish(msg)
            if w.spin_until(lambda: refused() >= before + n, 2.0, publish_maps=maps):
                break
        assert refused() >= before + n, (n, w.diagnostics.get("/a/registration"))
    assert w.counter("/a/registration", "replayed") >= 1
    assert w.counter("/a/registration", "peer_restart") == 0
    w.transforms.clear()
    assert w.spin_until(lambda: verified_pairs_ok(w, frames, [("a", "b")]), 60, publish_maps=maps)
    nothing_wrong(w, frames)


def test_a_point_cloud_with_offsets_past_the_point_crashes_nothing(fleet):
    w, procs, maps, frames, seen = fleet
    bad = deserialize_message(seen["dense"][-1], DenseGraph)
    for f in bad.points.fields:
        f.offset += 64 if f.name == "z" else 0
    bad.sequence += 100
    w.publisher(DenseGraph, "/b/sgreg/dense", qos.DENSE).publish(bad)
    w.spin_until(lambda: False, 3.0, publish_maps=maps)
    assert not alive(procs)


def test_sequence_at_the_end_of_the_range_locks_nobody_out(fleet):
    w, procs, maps, frames, seen = fleet
    last = deserialize_message(seen["coarse"][-1], CoarseGraph)
    for seq in (2**32 - 1, 0):
        forged = copy.deepcopy(last)
        forged.sequence = seq
        w.publisher(CoarseGraph, "/b/sgreg/coarse", qos.COARSE).publish(forged)
    w.transforms.clear()
    assert w.spin_until(lambda: verified_pairs_ok(w, frames, [("a", "b")]), 60, publish_maps=maps)
    assert w.counter("/a/registration", "peer_restart") == 0
    nothing_wrong(w, frames)


def test_forged_requests_get_no_dense_answers(fleet):
    w, procs, maps, frames, seen = fleet
    pub = w.publisher(DenseRequest, "/a/sgreg/dense_request", qos.DENSE_REQUEST)
    before = seen["dense_out_of_a"]
    weights = deserialize_message(seen["coarse"][-1], CoarseGraph).weights_id
    for k in range(50):
        pub.publish(DenseRequest(from_agent=f"x{k}", to_agent="a", sequence=1, weights_id=weights))
        w.spin_until(lambda: False, 0.03)       # within the request queue's depth
    w.spin_until(lambda: False, 4.0, publish_maps=maps)
    assert w.counter("/a/agent", "unsigned") >= 50
    assert seen["dense_out_of_a"] - before <= 3        # b's own requests may still be answered


def test_fake_peers_leave_no_state(fleet):
    w, procs, maps, frames, seen = fleet
    last = deserialize_message(seen["coarse"][-1], CoarseGraph)
    pubs = [w.publisher(CoarseGraph, f"/fake{k}/sgreg/coarse", qos.COARSE) for k in range(50)]
    for _ in range(3):
        for k, pub in enumerate(pubs):
            m = copy.deepcopy(last)
            m.agent_id = f"fake{k}"
            pub.publish(m)
        w.spin_until(lambda: False, 1.5, publish_maps=maps)
    w.spin_until(lambda: False, 3.0, publish_maps=maps)        # a discovery period or more
    # the registration nodes listen to no agent outside the fleet's keystore
    assert all(w.node.count_subscribers(f"/fake{k}/sgreg/coarse") == 0 for k in range(50))
    for pub in pubs:
        w.node.destroy_publisher(pub)
    assert not alive(procs)
