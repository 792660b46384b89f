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
from sgreg_msgs.msg import CoarseGraph, DenseGraph, DenseRequest, RegistrationResult

from sgreg_core.bench.replay_score import ground_truth
from sgreg_core.geometry import yaw_transform
from sgreg_core.metrics import two_agent_success
from sgreg_core.runtime.auth import AuthConfig, init_keystore
from sgreg_ros import convert, qos
from sgreg_ros.signing import MessageAuth

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
    seen = {"coarse": [], "dense": [], "dense_out_of_a": 0, "keys": keys}     # b's genuine messages, captured
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


def refusals(w, *counters):
    return sum(w.counter("/a/registration", c) for c in counters)


def send_until_counted(w, maps, pub, msg, *counters, tries=10):
    """Publish `msg` until a's refusal counters (summed) rise by one: a busy node keeps only the
    newest few of a burst (depth 4), and every copy of a probe is refused alike."""
    at_least = refusals(w, *counters) + 1
    for _ in range(tries):
        pub.publish(msg)
        if w.spin_until(lambda: refusals(w, *counters) >= at_least, 2.0, publish_maps=maps):
            return
    raise AssertionError((counters, at_least, w.diagnostics.get("/a/registration")))


def test_forged_and_moved_graphs_are_refused(fleet):
    w, procs, maps, frames, seen = fleet
    real = deserialize_message(seen["coarse"][-1], CoarseGraph)
    dense = deserialize_message(seen["dense"][-1], DenseGraph)
    on_b = w.publisher(CoarseGraph, "/b/sgreg/coarse", qos.COARSE_SUB)
    dense_b = w.publisher(DenseGraph, "/b/sgreg/dense", qos.RESULTS)
    on_c = w.publisher(CoarseGraph, "/c/sgreg/coarse", qos.COARSE_SUB)
    assert w.spin_until(lambda: on_b.get_subscription_count() >= 1, 10)   # a's registration
    for k in range(3):
        fake = moved(real)
        fake.sequence = real.sequence + 1 + k          # signed by b, but the content changed
        stripped = copy.deepcopy(fake)
        stripped.key_id, stripped.signature = "", b""  # no signature at all
        d = copy.deepcopy(dense)
        d.graph, d.sequence = moved(d.graph), d.sequence + 1 + k
        for pub, msg, counter in ((on_b, fake, "bad_signature"), (on_b, stripped, "unsigned"),
                                  (dense_b, d, "bad_signature")):
            send_until_counted(w, maps, pub, msg, counter)
        on_c.publish(fake)                             # in b's name, as agent c
    # c holds no key of the fleet's: a never listens to it (discovery runs every 2 s)
    w.spin_until(lambda: False, 5.0, publish_maps=maps)
    assert on_c.get_subscription_count() == 0
    w.transforms.clear()
    assert w.spin_until(lambda: verified_pairs_ok(w, frames, [("a", "b")]), 60, publish_maps=maps)
    nothing_wrong(w, frames)
    assert not alive(procs)


def genuine_from_b(w, maps, keys, seconds=4.0):
    """b's coarse graphs as sent now, checked against the fleet keystore: the probes of the
    test before published forgeries on b's topic with transient durability, and a late
    subscription receives those too."""
    got = []
    sub = w.node.create_subscription(CoarseGraph, "/b/sgreg/coarse", got.append, qos.COARSE_SUB)
    w.spin_until(lambda: False, seconds, publish_maps=maps)
    w.node.destroy_subscription(sub)
    auth = MessageAuth(AuthConfig(keystore=str(keys)), "a", w.node.get_logger())   # as a checks
    return [m for m in got if auth.check(m, "/b/sgreg/coarse", "b") is None]


def test_replayed_signed_messages_change_nothing(fleet):
    """b's own signed graphs, captured and sent again: valid signatures, old signing times. Sent
    within max_age_s of signing they are refused as replayed, older ones as stale."""
    w, procs, maps, frames, seen = fleet
    pub = w.publisher(CoarseGraph, "/b/sgreg/coarse", qos.COARSE_SUB)
    assert w.spin_until(lambda: pub.get_subscription_count() >= 1, 10)   # a's registration
    fresh = genuine_from_b(w, maps, seen["keys"])
    assert fresh, "no genuine graph of b received in 4 s"
    old = [deserialize_message(raw, CoarseGraph) for raw in seen["coarse"][:2]]   # from setup
    for msg in fresh[-2:]:
        send_until_counted(w, maps, pub, msg, "replayed")
    for msg in old:     # replayed, or stale once max_age_s has passed since setup
        send_until_counted(w, maps, pub, msg, "replayed", "stale_message")
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
    send_until_counted(w, maps, w.publisher(DenseGraph, "/b/sgreg/dense", qos.DENSE), bad, "malformed_message")
    assert not alive(procs)


def test_sequence_at_the_end_of_the_range_locks_nobody_out(fleet):
    """The sequence number is signed: in a signed fleet a forged one is refused before the link
    sees it (how a link takes one that comes unsigned: test_runtime_peers.py,
    test_one_forged_sequence_neither_locks_out_nor_restarts)."""
    w, procs, maps, frames, seen = fleet
    last = deserialize_message(seen["coarse"][-1], CoarseGraph)
    pub = w.publisher(CoarseGraph, "/b/sgreg/coarse", qos.COARSE)
    for seq in (2**32 - 1, 0):
        forged = copy.deepcopy(last)
        forged.sequence = seq
        send_until_counted(w, maps, pub, forged, "bad_signature", "stale_message")
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


def test_links_to_made_up_agents_are_left_out_of_the_merge(fleet):
    """b's key in the wrong hands: signed results that claim verified links to a hundred
    agents nobody listens to. a leaves each out (counted) instead of growing its merge with
    them, and still registers b."""
    w, procs, maps, frames, seen = fleet
    keys = seen["keys"]
    as_b = MessageAuth(AuthConfig(keystore=str(keys)), "b", w.node.get_logger())
    pub = w.publisher(RegistrationResult, "/b/sgreg/registration", qos.RESULTS)
    before = w.counter("/a/registration", "result_names_unknown_agent")
    for k in range(100):
        msg = RegistrationResult(agent_id="b", peer_id=f"ghost{k}", sequence=10_000 + k,
                                 verified=True, mode="dense", reason="ok", link="confirmed",
                                 confidence=0.99)
        msg.header.stamp = convert.ns_to_stamp(w.node.get_clock().now().nanoseconds)
        msg.transform.transform.rotation.w = 1.0
        pub.publish(as_b.sign(msg, "/b/sgreg/registration"))
        w.spin_until(lambda: False, 0.02)
    assert w.spin_until(lambda: w.counter("/a/registration", "result_names_unknown_agent") > before,
                        10.0, publish_maps=maps)
    w.transforms.clear()
    assert w.spin_until(lambda: verified_pairs_ok(w, frames, [("a", "b")]), 60, publish_maps=maps)
    nothing_wrong(w, frames)
    assert not alive(procs)
