"""The per-peer registration state machine (no ROS): the coarse-to-fine protocol and every
failure case of docs/ARCHITECTURE.md ("Failure behaviour") as a counter and a reason, never an exception."""
from dataclasses import replace

import numpy as np
import pytest

from sgreg_core.geometry import yaw_transform
from sgreg_core.metrics import rre, rte
from sgreg_core.net.model import load_model
from sgreg_core.net.testing import moved_graph, toy_graph
from sgreg_core.runtime.agent import AgentConfig, AgentCore, NotYet
from sgreg_core.runtime.peers import Hypothesis, Peers, PeersConfig
from sgreg_core.simulation.synth import SynthConfig, generate_scene
from sgreg_core.types import InstanceMap

T_GT = yaw_transform(np.radians(140.0), (3.0, -2.0, 0.1))   # maps a's frame into b's


@pytest.fixture(scope="module")
def model():
    return load_model()   # the shipped weights and the bundled MiniLM: what the nodes run


@pytest.fixture(scope="module")
def graphs():
    rng = np.random.default_rng(5)
    g = toy_graph(rng, n=24)
    return g, moved_graph(g, T_GT, rng, jitter=0.005)


def make_agents(model, graphs, cfg=None):
    ga, gb = graphs
    a = AgentCore(AgentConfig(name="a"), model)
    a.set_graph(ga, 1, 0)
    b = AgentCore(AgentConfig(name="b"), model)
    b.set_graph(gb, 1, 0)
    logs = []
    reg = Peers(cfg or PeersConfig(), a, model, log=logs.append)
    return a, b, reg, logs


def test_coarse_then_dense_then_confirmation_gives_a_verified_transform(model, graphs):
    """The second estimate a first link needs is the coarse estimate of the same graphs, made
    when the points arrive (coarse_with_dense), or else the next coarse graph's."""
    for at_once in (True, False):
        a, b, reg, _ = make_agents(model, graphs, PeersConfig(coarse_with_dense=at_once))
        est, req = reg.on_coarse(b.coarse_message(1), now=0.0)
        # nothing to check a pose against yet: the dense answer answers this query
        assert est is None and reg.counters["deferred_to_dense"] == 1
        assert req is not None and req.to_agent == "b" and req.from_agent == "a" and len(req.node_ids) >= 3
        dense = b.dense_message(1, req.node_ids, "a", req.sequence)
        est = reg.on_dense(dense, now=0.5)
        assert est.mode == "dense" and rte(est.T, T_GT) < 0.2 and est.confidence > 0.5
        assert reg.links["b"].pending is None
        if at_once:
            assert est.verified and est.link == "confirmed", est.reason
        else:
            assert not est.verified and est.reason == "awaiting_confirmation" and est.link == "candidate"
            # node centers of the next coarse graph are other evidence than the points: it confirms
            est, req = reg.on_coarse(b.coarse_message(2), now=1.0)
            assert est.verified and est.reason == "ok" and est.link == "confirmed", est.reason
        assert rte(est.T, T_GT) < 0.2 and rre(est.T, T_GT) < 2.0
        assert reg.counters["confirmed"] == 1
        # the next coarse message merges the dense inliers kept with the link, and is verified
        est, req = reg.on_coarse(b.coarse_message(3), now=2.0)
        assert est.mode == "merged" and est.verified
        assert rte(est.T, T_GT) < 0.2
        assert req is None   # min_request_interval_s has not passed


def test_the_coarse_estimate_of_the_same_graphs_confirms_a_first_dense_one_at_once(model, graphs):
    """coarse_with_dense: when the dense answer arrives, the coarse estimate of the peer's last
    coarse graph (node centers, now verifiable on the points) is the second estimate from
    other data, so a right first dense estimate is published as verified at once. A coarse
    estimate the verdict refuses confirms nothing, nor does one on a link already confirmed."""
    def first_dense(cfg):
        a, b, reg, _ = make_agents(model, graphs, cfg)
        est, req = reg.on_coarse(b.coarse_message(1), now=0.0)
        assert est is None
        return reg, b, req, reg.on_dense(b.dense_message(1, req.node_ids, "a", req.sequence), now=0.5)

    reg, b, req, est = first_dense(PeersConfig(coarse_with_dense=True))
    assert est.mode == "dense" and est.verified and est.link == "confirmed", est.reason
    assert rte(est.T, T_GT) < 0.2 and rre(est.T, T_GT) < 2.0
    assert reg.counters["coarse_with_dense"] == 1 and reg.counters["confirmed"] == 1
    # the link is confirmed: the next dense answer runs no coarse estimate beside it
    drift(b, graphs, 2, 1.0)
    reg.on_coarse(b.coarse_message(2), now=1.0)
    assert reg.on_dense(b.dense_message(2, req.node_ids, "a", req.sequence), now=9.0).verified
    assert reg.counters["coarse_with_dense"] == 1
    base = PeersConfig(coarse_with_dense=True)
    refuse = replace(base.pipeline.coarse_pose, verdict=replace(base.pipeline.coarse_pose.verdict,
                                                                  min_objects=10_000))
    reg, *_, est = first_dense(replace(base, pipeline=replace(base.pipeline, coarse_pose=refuse)))
    assert est.reason == "awaiting_confirmation" and reg.counters["coarse_with_dense"] == 1
    reg, *_, est = first_dense(PeersConfig(coarse_with_dense=False))
    assert est.reason == "awaiting_confirmation" and reg.counters["coarse_with_dense"] == 0
    # a coarse graph levelled otherwise than the points that answer it lies in another frame
    from scipy.spatial.transform import Rotation
    a, b, reg, _ = make_agents(model, graphs, base)
    msg = b.coarse_message(1)
    msg.level = Rotation.from_rotvec([0.02, 0.0, 0.0]).as_matrix()
    _, req = reg.on_coarse(msg, now=0.0)
    est = reg.on_dense(b.dense_message(1, req.node_ids, "a", req.sequence), now=0.5)
    assert est.reason == "awaiting_confirmation" and reg.counters["coarse_with_dense"] == 0


def test_the_coarse_estimate_beside_a_dense_one_confirms_it_or_nothing(model, graphs):
    """The unpublished coarse estimate changes no link state of its own: a wrong one neither
    replaces the link's candidate nor, with the peer's word, confirms a link that the dense
    estimate would then have to withdraw; a tie it finds is remembered; with confirm off or too
    few coarse matches it plays no part."""
    from sgreg_core.geometry import invert_transform
    off = yaw_transform(np.radians(30.0), (1.0, 0.0, 0.0)) @ invert_transform(T_GT)   # b -> a, wrong

    def wrong_beside(reg):
        made = reg._coarse_beside

        def beside(*args):
            hyp = made(*args)
            return None if hyp is None else replace(hyp, T=invert_transform(off))
        reg._coarse_beside = beside

    # a wrong coarse estimate beside each answer: the dense candidate stands, and the next
    # answer from new data confirms it
    a, b, reg, _ = make_agents(model, graphs, PeersConfig(min_request_interval_s=0.0))
    wrong_beside(reg)
    _, req = reg.on_coarse(b.coarse_message(1), now=0.0)
    assert reg.on_dense(b.dense_message(1, req.node_ids, "a", req.sequence), now=0.5).reason \
        == "awaiting_confirmation"
    drift(b, graphs, 2, 1.0)
    est = reg.on_dense(b.dense_message(2, req.node_ids, "a", req.sequence), now=1.0)
    assert est.verified and rte(est.T, T_GT) < 0.2, est.reason
    # the peer's confirmed link agrees with the wrong coarse estimate, not with the dense one:
    # nothing is confirmed, so nothing is contradicted
    a, b, reg, _ = make_agents(model, graphs)
    wrong_beside(reg)
    reg.on_peer_result("b", off, True, "merged", "ok", "confirmed", now=0.0)
    _, req = reg.on_coarse(b.coarse_message(1), now=0.0)
    est = reg.on_dense(b.dense_message(1, req.node_ids, "a", req.sequence), now=0.5)
    assert est.reason == "awaiting_confirmation" and reg.links["b"].state == "candidate"
    assert reg.counters["withdrawn"] == reg.counters["confirmed_by_peer"] == 0
    # a coarse estimate beside the answer that ties is a tie: only the peer's word confirms
    a, b, reg, _ = make_agents(model, graphs, PeersConfig(min_request_interval_s=0.0, tie_memory_s=10.0))
    shipped = reg._coarse_cfg
    reg._coarse_cfg = replace(shipped, coarse_pose=replace(
        shipped.coarse_pose, verdict=replace(shipped.coarse_pose.verdict, max_ambiguity=0.0)))
    _, req = reg.on_coarse(b.coarse_message(1), now=0.0)
    reg.on_dense(b.dense_message(1, req.node_ids, "a", req.sequence), now=0.5)
    drift(b, graphs, 2, 1.0)
    est = reg.on_dense(b.dense_message(2, req.node_ids, "a", req.sequence), now=1.0)
    assert est.reason == "awaiting_confirmation" and reg.counters["held_by_tie"] == 1, est.reason
    # no coarse estimate beside the answer without confirmation, nor with too few coarse matches
    a, b, reg, _ = make_agents(model, graphs, PeersConfig(confirm=False))
    _, req = reg.on_coarse(b.coarse_message(1), now=0.0)
    assert reg.on_dense(b.dense_message(1, req.node_ids, "a", req.sequence), now=0.5).verified
    assert reg.counters["coarse_with_dense"] == 0
    a, b, reg, _ = make_agents(model, graphs, PeersConfig(min_coarse_matches=1000))
    _, req = reg.on_coarse(b.coarse_message(1), now=0.0)
    assert reg.on_dense(b.dense_message(1, req.node_ids, "a", req.sequence), now=0.5).reason \
        == "awaiting_confirmation"


def drift(agent, graphs, map_sequence, now, dx=0.02):
    """The agent's map (the peer's graph of `graphs`) with other content: shifted by dx."""
    moved = moved_graph(graphs[1], yaw_transform(0.0, (dx, 0.0, 0.0)), np.random.default_rng(map_sequence))
    agent.set_graph(moved, map_sequence, int(now * 1e9))


def resting_on(reg, objects):
    """reg's estimates, as the link rules see them, rest on `objects[0]` inlier objects while
    that is set (None: their own count)."""
    rules = reg._link_rules

    def few(link, r, hyp, now, beside=None, vouched=False):
        return rules(link, r, hyp if objects[0] is None else replace(hyp, objects=objects[0]), now,
                     beside, vouched)
    reg._link_rules = few


def test_a_first_link_needs_its_estimates_on_enough_objects(model, graphs):
    """A dense estimate on three objects of two small maps and the coarse estimate of the next
    graph rest on the same few node matches: through real nodes they agreed on a pose 2 m off
    (real suite, scene0004). Below first_link_min_objects (4) neither confirms a first link,
    nor does the peer's word, heard before or after; an agreeing estimate on enough objects
    takes the candidate's place, and the next one from other data confirms it."""
    from sgreg_core.geometry import invert_transform
    peer_word = invert_transform(T_GT)
    a, b, reg, _ = make_agents(model, graphs)
    resting_on(reg, [3])
    reg.on_peer_result("b", peer_word, True, "dense", "ok", "confirmed", now=0.0)
    _, req = reg.on_coarse(b.coarse_message(1), now=0.0)
    est = reg.on_dense(b.dense_message(1, req.node_ids, "a", req.sequence), now=0.5)
    assert est.reason == "awaiting_confirmation" and reg.counters["coarse_with_dense"] == 1
    reg.on_peer_result("b", peer_word, False, "dense", "awaiting_confirmation", "candidate", now=0.6)
    reg.on_peer_result("b", peer_word, True, "dense", "ok", "confirmed", now=0.7)
    assert reg.links["b"].state == "candidate"
    assert reg.counters["confirmed"] == reg.counters["confirmed_by_peer"] == 0
    # the same estimates with the rule at the verdict's own minimum confirm at once
    a, b, reg, _ = make_agents(model, graphs, PeersConfig(first_link_min_objects=3))
    resting_on(reg, [3])
    _, req = reg.on_coarse(b.coarse_message(1), now=0.0)
    assert reg.on_dense(b.dense_message(1, req.node_ids, "a", req.sequence), now=0.5).verified
    # a candidate on too few objects gives way to an agreeing estimate on enough, never the
    # reverse
    a, b, reg, _ = make_agents(model, graphs, PeersConfig(min_request_interval_s=0.0, coarse_with_dense=False))
    objects = [3]
    resting_on(reg, objects)
    _, req = reg.on_coarse(b.coarse_message(1), now=0.0)
    assert reg.on_dense(b.dense_message(1, req.node_ids, "a", req.sequence), now=0.5).reason \
        == "awaiting_confirmation"
    objects[0] = None
    drift(b, graphs, 2, 1.0)
    est, asked = reg.on_coarse(b.coarse_message(2), now=1.0)
    cand = reg.links["b"].candidate
    assert est.reason == "awaiting_confirmation" and cand.mode == "coarse" and cand.objects >= 4
    # it keeps the dense inliers, and asks for points at once (prompt_request), not in 2 s
    assert cand.kept is not None and asked is not None
    objects[0] = 3
    drift(b, graphs, 3, 2.0)
    assert reg.on_dense(b.dense_message(2, req.node_ids, "a", req.sequence), now=2.0).reason \
        == "awaiting_confirmation"
    assert reg.links["b"].candidate is cand
    objects[0] = None
    drift(b, graphs, 4, 3.0)
    est = reg.on_dense(b.dense_message(3, req.node_ids, "a", req.sequence), now=3.0)
    assert est.verified and rte(est.T, T_GT) < 0.2, est.reason


def test_the_same_data_twice_does_not_confirm(model, graphs):
    # without the coarse estimate beside the dense ones, which is other data
    a, b, reg, _ = make_agents(model, graphs, PeersConfig(min_request_interval_s=0.0, coarse_with_dense=False))
    _, req = reg.on_coarse(b.coarse_message(1), now=0.0)
    for seq in (1, 2):   # two dense answers from the same maps
        est = reg.on_dense(b.dense_message(seq, req.node_ids, "a", req.sequence), now=seq)
        assert est.reason == "awaiting_confirmation", est.reason
    b.set_graph(graphs[1], 2, 3_000_000_000)    # b's map sequence moves on, its content does not
    est = reg.on_dense(b.dense_message(3, req.node_ids, "a", req.sequence), now=3.0)
    assert est.reason == "awaiting_confirmation"
    # new content (b's map drifted by 2 cm): new evidence
    drift(b, graphs, 3, 4.0)
    est = reg.on_dense(b.dense_message(4, req.node_ids, "a", req.sequence), now=4.0)
    assert est.verified, est.reason


def test_the_peers_own_estimates_witness_a_first_estimate(model, graphs):
    """b's estimates of the link, made from a's points against b's whole map, are other data:
    b's confirmed link (a transform b published as verified) confirms a's first estimate that
    agrees with it, and so does a dense estimate of b that passed b's verdict for a's dense one.
    One that disagrees, an old one, or a coarse one b did not verify confirms nothing."""
    from sgreg_core.geometry import invert_transform
    T_ba = invert_transform(T_GT)          # what b publishes: maps b's frame into a's
    off = yaw_transform(np.radians(30.0), (1.0, 0.0, 0.0)) @ T_ba
    alone = PeersConfig(coarse_with_dense=False)   # b's word is the only second estimate
    for witness, verified, mode, reason, age, confirmed in [
            (T_ba, True, "merged", "ok", 1.0, True),
            (T_ba, False, "dense", "awaiting_confirmation", 1.0, True),
            (off, True, "dense", "ok", 1.0, False),
            (T_ba, True, "dense", "ok", 30.0, False),
            (T_ba, False, "coarse", "awaiting_confirmation", 1.0, False),
            (T_ba, False, "dense", "verification_failed", 1.0, False)]:
        a, b, reg, _ = make_agents(model, graphs, alone)
        reg.on_peer_result("b", witness, verified, mode, reason, "confirmed" if verified else "candidate",
                           now=0.5 - age)   # before b's first graph
        _, req = reg.on_coarse(b.coarse_message(1), now=0.0)
        est = reg.on_dense(b.dense_message(1, req.node_ids, "a", req.sequence), now=0.5)
        assert est.verified is confirmed, (verified, mode, reason, age, est.reason)
        assert reg.counters["confirmed_by_peer"] == int(confirmed)
    # heard after a's dense candidate: the candidate is confirmed there and then
    a, b, reg, _ = make_agents(model, graphs, alone)
    _, req = reg.on_coarse(b.coarse_message(1), now=0.0)
    assert reg.on_dense(b.dense_message(1, req.node_ids, "a", req.sequence), now=0.5).link == "candidate"
    reg.on_peer_result("b", off, True, "dense", "ok", "confirmed", now=0.6)
    reg.on_peer_result("b", T_ba, False, "coarse", "awaiting_confirmation", "candidate", now=0.6)
    assert reg.links["b"].state == "candidate"
    reg.on_peer_result("b", T_ba, False, "dense", "awaiting_confirmation", "candidate", now=0.7)
    assert reg.links["b"].state == "confirmed" and reg.counters["confirmed_by_peer"] == 1
    est, _ = reg.on_coarse(b.coarse_message(2), now=1.0)
    assert est.verified and est.mode == "merged", est.reason
    # a coarse estimate needs b's confirmed link, not just its dense estimate
    a, b, reg, _ = make_agents(model, graphs, alone)
    reg.on_peer_result("b", T_ba, False, "dense", "ok", "candidate", now=0.0)
    assert not reg._witnessed(Hypothesis(T_GT, ("a1", "b1", "coarse"), "coarse", 10), "b", 0.5)
    assert reg._witnessed(Hypothesis(T_GT, ("a1", "b1", "dense"), "dense", 10), "b", 0.5)
    # a link b gives up (contradicted, disputed by its cycles, no longer confirmed) is taken back
    for reason, link_state in (("contradicted", "candidate"), ("disputed_by_cycles", "confirmed"),
                               ("too_few_inliers", "none")):
        a, b, reg, _ = make_agents(model, graphs, alone)
        reg.on_peer_result("b", T_ba, True, "merged", "ok", "confirmed", now=0.0)
        reg.on_peer_result("b", off, False, "coarse", reason, link_state, now=0.1)
        assert not reg._witnessed(Hypothesis(T_GT, ("a1", "b1", "coarse"), "coarse", 10), "b", 0.5), reason
    a, b, reg, _ = make_agents(model, graphs, replace(alone, confirm_with_peer=False))
    _, req = reg.on_coarse(b.coarse_message(1), now=0.0)
    reg.on_peer_result("b", T_ba, True, "dense", "ok", "confirmed", now=0.4)
    assert reg.on_dense(b.dense_message(1, req.node_ids, "a", req.sequence), now=0.5).reason \
        == "awaiting_confirmation"


def test_a_link_the_peers_word_confirmed_falls_back_when_the_peer_withdraws_its_own(model, graphs):
    """a's dense candidate is confirmed by b's confirmed link; b then says its link was
    contradicted: a's link is a candidate again, nothing is published until a's own estimate from
    other data confirms it. A link a confirmed on its own estimates stays."""
    from sgreg_core.geometry import invert_transform
    T_ba = invert_transform(T_GT)
    alone = PeersConfig(coarse_with_dense=False)
    a, b, reg, logs = make_agents(model, graphs, alone)
    reg.on_peer_result("b", T_ba, True, "merged", "ok", "confirmed", now=0.0)
    _, req = reg.on_coarse(b.coarse_message(1), now=0.0)
    assert reg.on_dense(b.dense_message(1, req.node_ids, "a", req.sequence), now=0.5).verified
    assert reg.on_peer_result("b", T_ba, False, "dense", "contradicted", "candidate", now=0.8)
    link = reg.links["b"]
    assert link.state == "candidate" and link.kept is None and reg.counters["withdrawn_with_peer"] == 1
    assert any("withdrew its link" in line for line in logs)
    est, _ = reg.on_coarse(b.coarse_message(2), now=1.0)      # a's own second estimate
    assert est.verified and est.link == "confirmed" and reg.counters["confirmed"] == 1
    assert not reg.on_peer_result("b", T_ba, False, "dense", "contradicted", "candidate", now=1.2)
    assert link.state == "confirmed" and reg.counters["withdrawn_with_peer"] == 1
    # kept on merged estimates since: those confirm nothing, so no candidate is left
    a, b, reg, _ = make_agents(model, graphs, alone)
    reg.on_peer_result("b", T_ba, True, "merged", "ok", "confirmed", now=0.0)
    _, req = reg.on_coarse(b.coarse_message(1), now=0.0)
    reg.on_dense(b.dense_message(1, req.node_ids, "a", req.sequence), now=0.5)
    est, _ = reg.on_coarse(b.coarse_message(2), now=1.0)
    assert est.verified and est.mode == "merged"
    assert reg.on_peer_result("b", T_ba, False, "dense", "contradicted", "candidate", now=1.2)
    assert reg.links["b"].state == "none"


def test_a_link_withdrawn_outside_an_estimate_leaves_the_merge(model, graphs):
    """Merger.drop, what the node and the offline replay call when on_peer_result withdrew a
    link, takes that one link out of the merge and leaves the others."""
    from sgreg_core.runtime.merge import MergeConfig, Merger
    merger = Merger(MergeConfig(), "a")
    merger.take("a", "b", T_GT, True, "ok", "confirmed", 0.99, 1)
    merger.take("a", "c", T_GT, True, "ok", "confirmed", 0.99, 1)
    merger.drop("a", "b")
    assert [(l.src, l.dst) for l in merger.links.current()] == [("a", "c")]


def test_the_peers_confirmed_link_vouches_for_an_estimate_short_of_confidence(model, graphs):
    """An estimate refused only for its confidence is taken when b's confirmed link agrees with
    it (vouched_min_confidence); not when b's link disagrees, is only a dense estimate, or the
    confidence is under the floor."""
    from sgreg_core.geometry import invert_transform
    T_ba = invert_transform(T_GT)
    off = yaw_transform(np.radians(30.0), (1.0, 0.0, 0.0)) @ T_ba
    base = PeersConfig()
    strict = replace(base.pipeline.pose, verdict=replace(base.pipeline.pose.verdict, min_confidence=1.0))
    # the gates for unrepeated maps would take the estimate on their own (pose/repeats.py)
    cfg = replace(base, pipeline=replace(base.pipeline, pose=strict,
                                         repeats=replace(base.pipeline.repeats, enabled=False)))

    def first_dense(cfg, witness=None, verified=True, mode="merged"):
        a, b, reg, _ = make_agents(model, graphs, cfg)
        if witness is not None:
            reg.on_peer_result("b", witness, verified, mode, "ok" if verified else "awaiting_confirmation",
                               "confirmed" if verified else "candidate", now=0.0)
        _, req = reg.on_coarse(b.coarse_message(1), now=0.0)
        return reg, reg.on_dense(b.dense_message(1, req.node_ids, "a", req.sequence), now=0.5)

    reg, est = first_dense(cfg)
    assert est.reason == "low_confidence" and 0.5 < est.confidence < 1.0, (est.reason, est.confidence)
    reg, est = first_dense(cfg, T_ba)
    assert est.verified and est.link == "confirmed", est.reason
    assert reg.counters["vouched_by_peer"] == 1 and reg.counters["confirmed_by_peer"] == 1
    for witness, verified, mode in ((off, True, "merged"), (T_ba, False, "dense")):
        reg, est = first_dense(cfg, witness, verified, mode)
        assert est.reason == "low_confidence" and reg.counters["vouched_by_peer"] == 0, (verified, mode)
    reg, est = first_dense(replace(cfg, vouched_min_confidence=1.0), T_ba)
    assert est.reason == "low_confidence"
    # vouched for but not confirmed by b's link (too few objects for a first link): what the
    # verdict said, so that b does not take its own link's echo as a passing dense estimate,
    # and no candidate for a later estimate to be confirmed by
    reg, est = first_dense(replace(cfg, first_link_min_objects=1000), T_ba)
    assert est.reason == "low_confidence" and not est.verified and not est.registration.success
    assert reg.links["b"].candidate is None and reg.counters["vouched_by_peer"] == 0
    # under first_link_hold_s it waits like any first estimate: no held candidate, no link
    reg, est = first_dense(replace(cfg, first_link_hold_s=10.0), T_ba)
    assert est.reason == "low_confidence" and not est.verified and reg.counters["vouched_by_peer"] == 0


def test_after_a_tie_only_the_peers_word_confirms_for_a_while(model, graphs):
    """An estimate refused as ambiguous is remembered: for tie_memory_s the link's own agreeing
    estimates (a dense one, then a coarse one) do not confirm it, the peer's confirmed link does;
    after tie_memory_s they confirm as usual."""
    from sgreg_core.geometry import invert_transform

    def after_a_tie(tie_memory_s, witness=False):
        a, b, reg, _ = make_agents(model, graphs, PeersConfig(min_request_interval_s=0.0,
                                                              tie_memory_s=tie_memory_s,
                                                              coarse_with_dense=False))
        _, req = reg.on_coarse(b.coarse_message(1), now=0.0)
        shipped = reg._dense_cfg
        verdict = replace(shipped.pose.verdict, max_ambiguity=0.0)   # every dense estimate ties
        reg._dense_cfg = replace(shipped, pose=replace(shipped.pose, verdict=verdict))
        est = reg.on_dense(b.dense_message(1, req.node_ids, "a", req.sequence), now=0.5)
        assert est.reason == "ambiguous"
        reg._dense_cfg = shipped
        if witness:
            reg.on_peer_result("b", invert_transform(T_GT), True, "merged", "ok", "confirmed", now=0.8)
        drift(b, graphs, 2, 1.0)
        dense = reg.on_dense(b.dense_message(2, req.node_ids, "a", req.sequence), now=1.0)
        coarse, _ = reg.on_coarse(b.coarse_message(3), now=2.0)
        return reg, dense, coarse

    reg, dense, coarse = after_a_tie(10.0)
    assert dense.reason == coarse.reason == "awaiting_confirmation", (dense.reason, coarse.reason)
    assert reg.counters["held_by_tie"] == 1 and rte(coarse.T, T_GT) < 0.2
    reg, dense, coarse = after_a_tie(10.0, witness=True)
    assert dense.verified and reg.counters["confirmed_by_peer"] == 1
    reg, dense, coarse = after_a_tie(1.0)      # the tie is older than the memory
    assert dense.reason == "awaiting_confirmation" and coarse.verified, coarse.reason


def test_a_first_link_waits_until_its_candidate_has_stood_first_link_hold_s(model, graphs):
    """With first_link_hold_s, agreeing estimates from other data (and the peer's confirmed
    link) confirm a link only once its candidate has stood that long; off, the second confirms."""
    from sgreg_core.geometry import invert_transform

    def coarse_after_dense(cfg, witness_at=None):
        a, b, reg, _ = make_agents(model, graphs, cfg)
        _, req = reg.on_coarse(b.coarse_message(1), now=0.0)
        dense = reg.on_dense(b.dense_message(1, req.node_ids, "a", req.sequence), now=0.5)
        assert dense.reason == "awaiting_confirmation", dense.reason
        if witness_at is not None:
            reg.on_peer_result("b", invert_transform(T_GT), True, "merged", "ok", "confirmed", now=witness_at)
        return reg, [reg.on_coarse(b.coarse_message(seq), now=t)[0] for seq, t in ((2, 1.0), (3, 3.0))]

    reg, (early, late) = coarse_after_dense(PeersConfig(first_link_hold_s=2.0))
    assert early.reason == "awaiting_confirmation" and late.verified, (early.reason, late.reason)
    assert rte(late.T, T_GT) < 0.2
    reg, (early, late) = coarse_after_dense(PeersConfig(first_link_hold_s=2.0), witness_at=0.8)
    assert early.reason == "awaiting_confirmation", early.reason   # the peer agreed at 0.8: too early
    assert late.verified and reg.counters["confirmed_by_peer"] == 1
    reg, (early, late) = coarse_after_dense(PeersConfig(coarse_with_dense=False))
    assert early.verified and late.verified


def test_a_dense_estimate_stands_for_the_coarse_candidate_it_agrees_with(model, graphs):
    """Under first_link_hold_s: a coarse candidate, then a dense estimate that agrees but may
    not confirm yet; the next coarse graph, the same data as the coarse candidate, is other data
    than the dense one and confirms once the candidate has stood long enough."""
    a, b, reg, _ = make_agents(model, graphs, PeersConfig(first_link_hold_s=2.0, coarse_with_dense=False,
                                                          min_request_interval_s=0.0))
    _, req = reg.on_coarse(b.coarse_message(1), now=0.0)
    shipped = reg._dense_cfg
    reg._dense_cfg = replace(shipped, pose=replace(shipped.pose, verdict=replace(
        shipped.pose.verdict, min_objects=10_000)))          # the first dense estimate is refused
    assert reg.on_dense(b.dense_message(1, req.node_ids, "a", req.sequence), now=0.5).reason == "too_few_objects"
    reg._dense_cfg = shipped
    coarse, _ = reg.on_coarse(b.coarse_message(2), now=1.0)
    assert coarse.reason == "awaiting_confirmation" and reg.links["b"].candidate.mode == "coarse"
    dense = reg.on_dense(b.dense_message(2, req.node_ids, "a", req.sequence), now=1.5)
    assert dense.reason == "awaiting_confirmation" and reg.links["b"].candidate.mode == "dense"
    est, _ = reg.on_coarse(b.coarse_message(3), now=3.5)
    assert est.verified and rte(est.T, T_GT) < 0.2, est.reason


def test_a_coarse_candidate_asks_for_the_dense_estimate_that_confirms_it_promptly(model, graphs):
    """prompt_request: only a dense estimate confirms a coarse candidate, so it is asked for as
    soon as the peer answers again (dense_min_interval_s, 1 s, after the last request), not
    after the search interval (2 s), once per candidate; without it the link waits the interval
    out, each coarse estimate meanwhile awaiting confirmation."""
    def coarse_candidate(cfg, at):
        a, b, reg, _ = make_agents(model, graphs, cfg)
        _, req = reg.on_coarse(b.coarse_message(1), now=0.0)
        shipped = reg._dense_cfg
        reg._dense_cfg = replace(shipped, pose=replace(shipped.pose, verdict=replace(
            shipped.pose.verdict, min_objects=10_000)))          # dense estimates are refused
        assert reg.on_dense(b.dense_message(1, req.node_ids, "a", req.sequence), now=0.5).reason \
            == "too_few_objects"
        drift(b, graphs, 2, at)
        est, req = reg.on_coarse(b.coarse_message(2), now=at)
        assert est.reason == "awaiting_confirmation" and reg.links["b"].candidate.mode == "coarse"
        return b, reg, req, shipped

    for prompt, at in ((True, 1.0), (True, 0.6), (False, 1.0)):
        b, reg, req, shipped = coarse_candidate(PeersConfig(prompt_request=prompt,
                                                            coarse_with_dense=False), at)
        reg._dense_cfg = shipped
        if prompt and at < 1.0:
            # the peer answers one request per second: asked on the tick once it would
            assert req is None and reg.on_tick(0.9) == []
            [req] = reg.on_tick(1.0)
        if not prompt:
            assert req is None and reg.on_tick(1.5) == []       # the search interval holds it
            assert reg.on_coarse(b.coarse_message(3), now=1.9)[0].reason == "awaiting_confirmation"
            [req] = reg.on_tick(2.0)
        assert req is not None and reg.counters["requests"] == 2
        est = reg.on_dense(b.dense_message(2, req.node_ids, "a", req.sequence), now=2.2)
        assert est.verified and rte(est.T, T_GT) < 0.2, est.reason
    # once per candidate: after its request was answered (refused), new coarse graphs that
    # agree with it wait for the search interval
    b, reg, req, _ = coarse_candidate(PeersConfig(coarse_with_dense=False), 1.0)
    assert reg.on_dense(b.dense_message(2, req.node_ids, "a", req.sequence), now=1.2).reason \
        == "too_few_objects"
    drift(b, graphs, 3, 2.5, dx=0.03)
    est, req = reg.on_coarse(b.coarse_message(3), now=2.5)
    assert est.reason == "awaiting_confirmation" and req is None and reg.counters["requests"] == 2
    assert reg.on_tick(2.9) == [] and len(reg.on_tick(3.0)) == 1


def test_two_coarse_estimates_alone_do_not_confirm(model, graphs):
    """Successive coarse graphs share most node matches: one of the two must be dense."""
    T = np.eye(4)
    coarse1 = Hypothesis(T, ("a1", "b1", "coarse"), "coarse", 10)
    coarse2 = Hypothesis(T, ("a1", "b2", "coarse"), "coarse", 10)
    dense = Hypothesis(T, ("a1", "b2", "dense"), "dense", 10)
    reg = make_agents(model, graphs)[2]
    assert not reg._independent(coarse1, coarse2)
    assert reg._independent(coarse1, dense) and reg._independent(dense, coarse1)
    assert not reg._independent(dense, Hypothesis(T, dense.data, "dense", 10))
    lenient = make_agents(model, graphs, PeersConfig(confirm_with_dense=False))[2]
    assert lenient._independent(coarse1, coarse2)


def confirmed_link(model, graphs, cfg=None):
    """a's peers with a confirmed link to b (a dense candidate, then a coarse estimate)."""
    a, b, reg, logs = make_agents(model, graphs, cfg)
    _, req = reg.on_coarse(b.coarse_message(1), now=0.0)
    reg.on_dense(b.dense_message(1, req.node_ids, "a", req.sequence), now=0.5)
    est, _ = reg.on_coarse(b.coarse_message(2), now=1.0)
    assert est.verified, est.reason
    return a, b, reg, logs


def test_a_contradicting_estimate_withdraws_the_link(model, graphs):
    a, b, reg, logs = confirmed_link(model, graphs, PeersConfig(min_request_interval_s=0.0))
    # no kept pairs or peer points left to show the move itself (that withdraws the link at
    # once: test_a_map_that_moves_under_a_confirmed_link_withdraws_it)
    reg.links["b"].kept, reg.links["b"].dense_cloud = None, None
    # b's map frame moves (e.g. its SLAM re-anchored): a well-supported estimate from new data
    # now disagrees with the published link
    W = yaw_transform(np.radians(60.0), (2.0, 1.0, 0.0))
    rng = np.random.default_rng(9)
    moved = moved_graph(graphs[1], W, rng, jitter=0.002)
    b.set_graph(moved, 3, 2_000_000_000)
    reg.on_coarse(b.coarse_message(3), now=2.0)
    req = reg.links["b"].pending         # a's outstanding request, answered from b's new map
    assert req is not None
    est = reg.on_dense(b.dense_message(2, req.node_ids, "a", req.sequence), now=2.5)
    assert est.reason == "contradicted" and not est.verified and est.link == "candidate"
    assert reg.counters["withdrawn"] == 1 and any("withdrawn" in line for line in logs)
    assert reg.links["b"].kept is None
    # the new pose is published once other evidence (here node centers) confirms it
    est, _ = reg.on_coarse(b.coarse_message(4), now=3.0)
    assert est.verified and est.mode == "coarse" and rte(est.T, W @ T_GT) < 0.2


def test_a_withdrawn_link_forgets_the_peers_word_heard_before(model, graphs):
    """b's confirmed link may rest on a's word alone (b confirmed it on a's link): once a's link
    is withdrawn, that word must not vouch for a's next estimate of the same pose."""
    from sgreg_core.geometry import invert_transform
    a, b, reg, _ = confirmed_link(model, graphs, PeersConfig(min_request_interval_s=0.0))
    reg.on_peer_result("b", invert_transform(reg.links["b"].confirmed.T), True, "merged", "ok",
                       "confirmed", now=1.2)
    anything = Hypothesis(reg.links["b"].confirmed.T, ("a1", "b1", "coarse"), "coarse", 10)
    assert reg._witnessed(anything, "b", 1.5)
    reg.links["b"].kept, reg.links["b"].dense_cloud = None, None
    b.set_graph(moved_graph(graphs[1], yaw_transform(np.radians(60.0), (2.0, 1.0, 0.0)),
                            np.random.default_rng(9), jitter=0.002), 3, 2_000_000_000)
    reg.on_coarse(b.coarse_message(3), now=2.0)
    req = reg.links["b"].pending
    assert reg.on_dense(b.dense_message(2, req.node_ids, "a", req.sequence), now=2.5).reason == "contradicted"
    assert not reg._witnessed(anything, "b", 2.6) and "b" not in reg._witnesses
    # what b says from now on counts again
    reg.on_peer_result("b", invert_transform(anything.T), True, "merged", "ok", "confirmed", now=2.7)
    assert reg._witnessed(anything, "b", 2.8)


def test_the_peers_word_ages_from_when_it_was_said_and_a_failed_dense_result_takes_one_back(model, graphs):
    from sgreg_core.geometry import invert_transform
    T_ba = invert_transform(T_GT)
    dense = Hypothesis(T_GT, ("a1", "b1", "dense"), "dense", 10)
    a, b, reg, _ = make_agents(model, graphs, PeersConfig(coarse_with_dense=False))
    reg.on_peer_result("b", T_ba, True, "dense", "ok", "confirmed", now=5.0, age_s=8.0)
    assert reg._witnessed(dense, "b", 6.0) and not reg._witnessed(dense, "b", 7.5)   # 10 s after signing
    reg.on_peer_result("b", T_ba, True, "dense", "ok", "confirmed", now=5.0, age_s=float("inf"))
    assert not reg._witnessed(dense, "b", 5.0)      # signed before this node started
    # b's passing dense estimate, then a dense one of b that ties: the first one no longer counts
    reg.on_peer_result("b", T_ba, False, "dense", "awaiting_confirmation", "candidate", now=10.0)
    assert reg._witnessed(dense, "b", 10.1)
    reg.on_peer_result("b", T_ba, False, "dense", "ambiguous", "candidate", now=10.2)
    assert not reg._witnessed(dense, "b", 10.3) and "b" not in reg._witnesses


def test_a_tie_from_new_data_withdraws_a_confirmed_link_with_withdraw_on_tie(model, graphs):
    """withdraw_on_tie: a dense estimate from new data refused as ambiguous takes a confirmed
    link back (nothing published until it is confirmed again); off, the link stays."""
    def tie_after_confirmation(withdraw):
        a, b, reg, logs = confirmed_link(model, graphs, PeersConfig(min_request_interval_s=0.0,
                                                                    withdraw_on_tie=withdraw))
        shipped = reg._dense_cfg
        verdict = replace(shipped.pose.verdict, max_ambiguity=0.0)   # every dense estimate ties
        reg._dense_cfg = replace(shipped, pose=replace(shipped.pose, verdict=verdict))
        drift(b, graphs, 3, 2.0)
        _, req = reg.on_coarse(b.coarse_message(3), now=2.0)
        req = req or reg.links["b"].pending
        est = reg.on_dense(b.dense_message(2, req.node_ids, "a", req.sequence), now=2.5)
        assert est.reason == "ambiguous" and not est.verified, est.reason
        return reg, est, logs

    reg, est, logs = tie_after_confirmation(True)
    assert est.link == "none" and reg.links["b"].kept is None
    assert reg.counters["withdrawn_by_tie"] == 1 and any("competing pose" in line for line in logs)
    reg, est, _ = tie_after_confirmation(False)
    assert est.link == "confirmed" and reg.counters["withdrawn_by_tie"] == 0


def test_a_merged_estimate_weighs_the_pose_its_kept_correspondences_came_from(model, graphs,
                                                                            monkeypatch):
    """Each coarse graph after a link is confirmed is estimated with the kept dense inliers and
    the dense estimate's own pose as one more candidate: the kept points alone, or mixed with
    confident wrong node matches, can settle decimetres or a turn away from it (docs/VERDICT.md,
    section 14)."""
    from scipy.spatial.transform import Rotation

    import sgreg_core.maps.level as level_mod
    import sgreg_core.pipeline as pipeline_mod
    import sgreg_core.runtime.peers as peers_mod

    a, b, reg, _ = make_agents(model, graphs)
    # b levelled its map by 3 deg: the pose between the levelled graphs, which the kept pairs
    # and the centers of a merged estimate are in, is not the pose between the maps
    b.level = level_mod.Levelling.from_rotation(Rotation.from_rotvec([0.05, 0.0, 0.0]).as_matrix())
    _, req = reg.on_coarse(b.coarse_message(1), now=0.0)
    reg.on_dense(b.dense_message(1, req.node_ids, "a", req.sequence), now=0.5)
    est, _ = reg.on_coarse(b.coarse_message(2), now=1.0)
    assert est.verified, est.reason
    kept = reg.links["b"].kept
    assert kept is not None

    def residual(T):
        moved = T[:3, :3] @ kept.corr.src_xyz.T + T[:3, 3:4]
        return np.median(np.linalg.norm(moved.T - kept.corr.ref_xyz, axis=1))

    assert residual(kept.pose) < 0.1 < residual(np.linalg.inv(est.T))
    seen, bounds = [], []
    real, real_pose = peers_mod.register_features, pipeline_mod.estimate_pose

    def spy(*args, **kwargs):
        seen.append(kwargs)
        return real(*args, **kwargs)

    def spy_pose(*args, **kwargs):
        bounds.append(kwargs["noise_bounds"])
        return real_pose(*args, **kwargs)

    monkeypatch.setattr(peers_mod, "register_features", spy)
    monkeypatch.setattr(pipeline_mod, "estimate_pose", spy_pose)
    est, _ = reg.on_coarse(b.coarse_message(3), now=2.0)
    assert est.mode == "merged" and est.verified, est.reason
    assert seen[-1]["kept"] is kept.corr and seen[-1]["kept_pose"] is kept.pose
    # kept point pairs count as inliers within their own bound, node centers within theirs
    cfg = reg.cfg.pipeline
    n = len(kept.corr)
    assert np.all(bounds[0][-n:] == cfg.kept_noise_bound) and cfg.kept_noise_bound < cfg.coarse_pose.noise_bound
    assert bounds[0].size > n and np.all(bounds[0][:-n] == cfg.coarse_pose.noise_bound)


def test_a_map_that_moves_under_a_confirmed_link_withdraws_it(model, graphs):
    """b's map jumps (its front end re-anchored it): the kept correspondences, and the dense
    cloud they were verified on, no longer describe b's map, nor does the link's T. The link is
    withdrawn at once, and the estimate says so (link none), so that no merger keeps placing
    b's moved map on /tf while new points are awaited (a peer that never answers again would
    keep it there for good)."""
    a, b, reg, logs = confirmed_link(model, graphs)
    assert reg.links["b"].kept is not None
    jumped = moved_graph(graphs[1], yaw_transform(1.0, (3.0, 0.0, 0.0)), np.random.default_rng(3))
    b.set_graph(jumped, 2, 1_500_000_000)
    est, req = reg.on_coarse(b.coarse_message(3), now=1.5)
    link = reg.links["b"]
    assert link.kept is None and link.dense_cloud is None and link.confirmed is None
    assert est is not None and not est.verified and est.reason == "contradicted" and est.link != "confirmed", est
    assert reg.counters["withdrawn_map_moved"] == 1 and any("withdrawn: the nodes it was verified on moved"
                                                            in line for line in logs)
    # the counters say what the result says, not the pipeline's reason (no points to verify on)
    assert reg.counters["contradicted"] == 1 and reg.counters["no_peer_cloud_to_verify"] == 0, reg.counters
    # new points are asked for at once (prompt_request), and the next coarse graph waits for them
    assert req is not None and reg.counters["kept_dropped"] == 1
    est, req = reg.on_coarse(b.coarse_message(4), now=1.6)
    assert not (est is not None and est.verified)
    # without prompt_request: new points are asked for after the search interval (2 s), not
    # the confirmed link's (5 s), and the same two graphs may be asked again
    a, b, reg, _ = confirmed_link(model, graphs, PeersConfig(prompt_request=False))
    b.set_graph(jumped, 2, 1_500_000_000)
    est, req = reg.on_coarse(b.coarse_message(3), now=1.5)
    assert est.mode == "coarse" and not est.verified and est.link != "confirmed"
    assert reg.links["b"].dense_cloud is None and req is None    # asked 1.5 s ago
    est, req = reg.on_coarse(b.coarse_message(4), now=2.0)
    assert est is None and req is not None and reg.counters["deferred_to_dense"] == 2


def test_a_peer_map_that_only_grows_keeps_its_link_and_points(model, graphs):
    a, b, reg, logs = confirmed_link(model, graphs)
    drift(b, graphs, 2, 1.5)
    est, _ = reg.on_coarse(b.coarse_message(3), now=1.5)
    assert est.verified and reg.links["b"].kept is not None and reg.counters["withdrawn_map_moved"] == 0


def test_the_peers_points_are_dropped_when_its_map_jumps_with_no_kept_correspondences(model, graphs):
    """A confirmed link whose kept correspondences are gone (a refused merged estimate drops
    them) still holds the peer's points: when the peer's frame jumps they go too, with the
    link, and new ones are asked for at once."""
    a, b, reg, logs = confirmed_link(model, graphs)
    link = reg.links["b"]
    link.kept = None
    jumped = moved_graph(graphs[1], yaw_transform(1.0, (3.0, 0.0, 0.0)), np.random.default_rng(3))
    b.set_graph(jumped, 2, 1_500_000_000)
    est, req = reg.on_coarse(b.coarse_message(3), now=1.5)
    assert link.dense_cloud is None and any("dense points of b dropped: their nodes moved" in line
                                            for line in logs)
    assert est is not None and est.reason == "contradicted" and est.link != "confirmed" and req is not None
    assert reg.counters["withdrawn_map_moved"] == 1
    # a peer map that only grows keeps its points
    a, b, reg, logs = confirmed_link(model, graphs)
    reg.links["b"].kept = None
    drift(b, graphs, 2, 1.5)
    reg.on_coarse(b.coarse_message(3), now=1.5)
    assert reg.links["b"].dense_cloud is not None and reg.counters["kept_dropped"] == 0


def test_a_coarse_estimate_that_withdraws_a_link_asks_for_points_promptly(model, graphs):
    """The contradicting coarse estimate becomes the candidate, which only a dense estimate
    confirms (confirm_with_dense): its request goes out as soon as the peer answers again."""
    a, b, reg, _ = confirmed_link(model, graphs)
    reg.links["b"].kept = None
    # a's own map is re-anchored: b's points stay valid, the link's pose does not
    a.set_graph(moved_graph(graphs[0], yaw_transform(0.8, (2.0, 1.0, 0.0)), np.random.default_rng(7)),
                2, 2_000_000_000)
    # 1.2 s after the last request: within the search interval (2 s), past the time the peer
    # takes to answer again (AgentConfig.dense_min_interval_s, 1 s)
    est, req = reg.on_coarse(b.coarse_message(3), now=1.2)
    assert est.reason == "contradicted" and reg.links["b"].candidate.mode == "coarse"
    requests = ([req] if req is not None else []) + reg.on_tick(1.3)
    assert len(requests) == 1, "the coarse candidate waits for no search interval"


def test_duplicate_out_of_order_and_restart(model, graphs):
    a, b, reg, logs = make_agents(model, graphs)
    reg.on_coarse(b.coarse_message(5), now=0.0)
    assert reg.on_coarse(b.coarse_message(5), now=0.1) == (None, None)
    assert reg.counters["duplicate_sequence"] == 1
    assert reg.on_coarse(b.coarse_message(3), now=0.2) == (None, None)
    assert reg.counters["out_of_order_sequence"] == 1
    # b restarted: its first number is held, the next one that continues it is a new stream
    assert reg.on_coarse(b.coarse_message(1), now=0.3) == (None, None)
    est, req = reg.on_coarse(b.coarse_message(2), now=1.3)
    # taken: the restarted peer is asked for dense data (its old cloud is forgotten)
    assert reg.counters["peer_restart"] == 1 and req is not None
    assert any("restarted" in line for line in logs)


def test_a_restart_is_seen_even_when_the_new_stream_reaches_the_old_last_number(model, graphs):
    """Old stream 1, 2; new stream 1, 2: the held 1 went back, so the 2 after it is a new
    stream, not the old one going on with a link to a map that is gone."""
    a, b, reg, logs = make_agents(model, graphs)
    forgotten = []
    reg.on_restart = forgotten.append
    reg.on_coarse(b.coarse_message(1), now=0.0)
    reg.on_coarse(b.coarse_message(2), now=1.0)
    old = reg.links["b"]
    assert reg.on_coarse(b.coarse_message(1), now=2.0) == (None, None)      # held
    reg.on_coarse(b.coarse_message(2), now=3.0)
    assert reg.counters["peer_restart"] == 1 and reg.links["b"] is not old and forgotten == ["b"]


def test_a_restart_after_one_message_is_seen_by_its_new_maps(model, graphs):
    """b sent one coarse graph and restarted: its new stream starts at the same number. A true
    duplicate repeats the map stamp; the new stream's first graph comes from other maps (a new
    stamp), so the next number that continues it starts a new stream."""
    a, b, reg, logs = make_agents(model, graphs)
    reg.on_coarse(b.coarse_message(1), now=0.0)
    assert reg.on_coarse(b.coarse_message(1), now=0.1) == (None, None)       # a duplicate
    reg.on_coarse(b.coarse_message(2), now=1.0)
    assert reg.counters["duplicate_sequence"] == 1 and reg.counters["peer_restart"] == 0
    a, b, reg, logs = make_agents(model, graphs)
    reg.on_coarse(b.coarse_message(1), now=0.0)
    old = reg.links["b"]
    b.set_graph(graphs[1], 1, 5_000_000_000)          # restarted: the same number, new maps
    assert reg.on_coarse(b.coarse_message(1), now=5.0) == (None, None)
    reg.on_coarse(b.coarse_message(2), now=6.0)
    assert reg.counters["peer_restart"] == 1 and reg.links["b"] is not old


def test_a_restarted_peer_leaves_the_merge_before_its_new_map_is_estimated(model, graphs):
    """The merger held a's confirmed link to b (and b's to a); b restarts with a map in a new
    frame. on_restart (the node's merger.forget) takes every link of b's old map out at once:
    before, the merger kept placing b's new map with the old link."""
    from sgreg_core.runtime.merge import MergeConfig, Merger

    a, b, reg, _ = confirmed_link(model, graphs)
    merger = Merger(MergeConfig(), "a")
    reg.on_restart = merger.forget
    merger.take("a", "b", T_GT, True, "ok", "confirmed", 0.95, 1_000_000_000)
    merger.take("b", "a", np.linalg.inv(T_GT), True, "ok", "confirmed", 0.95, 1_000_000_000)
    merger.update()
    assert "b" in merger.result.attached
    b.set_graph(moved_graph(graphs[1], yaw_transform(1.2, (5.0, -3.0, 0.0)), np.random.default_rng(11)),
                1, 3_000_000_000)
    reg.on_coarse(b.coarse_message(1), now=3.0)          # held: it goes back
    est, _ = reg.on_coarse(b.coarse_message(2), now=4.0)
    assert reg.counters["peer_restart"] == 1 and merger.links.current() == []
    merger.update()
    assert "b" not in merger.result.attached and not (est is not None and est.verified)


def test_one_forged_sequence_neither_locks_out_nor_restarts(model, graphs):
    a, b, reg, _ = make_agents(model, graphs)
    reg.on_coarse(b.coarse_message(7), now=0.0)
    link = reg.links["b"]
    assert reg.on_coarse(b.coarse_message(2**32 - 1), now=0.1) == (None, None)   # a jump
    assert reg.on_coarse(b.coarse_message(0), now=0.2) == (None, None)           # a "restart"
    assert reg.counters["sequence_jump"] == 1 and reg.counters["peer_restart"] == 0
    est, _ = reg.on_coarse(b.coarse_message(8), now=1.0)                          # the real peer goes on
    assert est is not None and reg.links["b"] is link


def test_a_quiet_link_takes_the_dense_answers_of_a_peer_busy_with_others(model, graphs):
    """b numbers its answers to every requester: after ten minutes in which b answered others
    1500 times, its next answer to a is taken; a number that far ahead a second later is not."""
    a, b, reg, _ = make_agents(model, graphs)
    assert reg._accept(b.dense_message(1, None, "a", 1), "dense", 0.0) is not None
    assert reg._accept(b.dense_message(1501, None, "a", 1), "dense", 600.0) is not None
    assert reg._accept(b.dense_message(1501 + 2000, None, "a", 1), "dense", 601.0) is None
    assert reg.counters["sequence_jump"] == 1
    assert reg._accept(b.dense_message(1502, None, "a", 1), "dense", 602.0) is not None


def test_dense_graphs_only_in_reply_and_peers_bounded(model, graphs):
    a, b, reg, _ = make_agents(model, graphs, PeersConfig(max_peers=1, peer_timeout_s=10.0))
    assert reg.on_dense(b.dense_message(1, None, "a", 99), now=0.0) is None       # nobody asked
    _, req = reg.on_coarse(b.coarse_message(1), now=0.0)
    assert reg.on_dense(b.dense_message(2, None, "x", req.sequence), now=0.1) is None   # asked by x
    # b's answer to x reaches every agent that listens to b: not a refusal (diagnostics stay OK)
    assert reg.counters["unrequested_dense"] == 1 and reg.counters["dense_for_others"] == 1
    assert a.refused == 1
    assert reg.on_dense(b.dense_message(3, req.node_ids, "a", req.sequence), now=0.2) is not None
    c = b.coarse_message(1)
    c.agent_id = "c"
    assert reg.on_coarse(c, now=0.3) == (None, None) and reg.counters["too_many_peers"] == 1
    assert reg.expire(now=5.0) == [] and reg.expire(now=20.0) == ["b"] and not reg.links
    _, req = reg.on_coarse(c, now=21.0)                                          # room again
    assert "c" in reg.links and req is not None


def test_other_weights_are_refused_and_said_once(model, graphs):
    a, b, reg, logs = make_agents(model, graphs)
    for seq in (1, 2, 3):
        msg = b.coarse_message(seq)
        msg.weights_id = "000000000000"
        assert reg.on_coarse(msg, now=float(seq)) == (None, None)
    assert reg.counters["rejected_weights"] == 3
    assert sum("weights" in line for line in logs) == 1


def cut(m, keep):
    """The message with only the nodes `keep` selects (or repeats)."""
    m.nodes = replace(m.nodes, node_ids=m.nodes.node_ids[keep], centers=m.nodes.centers[keep],
                      descriptor=m.nodes.descriptor[keep])
    m.extents = m.extents[keep]


@pytest.mark.parametrize("corrupt,counter", [
    (lambda m: setattr(m, "nodes", replace(m.nodes, descriptor=m.nodes.descriptor[:, :-3])), "bad_feature_size"),
    (lambda m: m.nodes.centers.__setitem__((0, 1), np.nan), "invalid_values"),
    (lambda m: cut(m, slice(0, 2)), "too_few_nodes"),
    (lambda m: cut(m, np.repeat(np.arange(m.num_nodes), 200)), "oversized_message"),
    (lambda m: setattr(m, "agent_id", ""), "bad_agent_id"),
])
def test_bad_coarse_messages_are_counted_not_raised(model, graphs, corrupt, counter):
    a, b, reg, logs = make_agents(model, graphs)
    msg = b.coarse_message(1)
    msg.nodes = replace(msg.nodes, centers=msg.nodes.centers.copy())
    corrupt(msg)
    assert reg.on_coarse(msg, now=0.0) == (None, None)
    assert reg.counters[counter] == 1
    assert logs and "refused" in logs[0]


@pytest.mark.parametrize("corrupt,counter", [
    (lambda m: setattr(m, "level", np.diag([1.0, 1.0, -1.0])), "bad_level"),     # a reflection
    (lambda m: setattr(m, "level", -np.eye(3)), "bad_level"),
    (lambda m: setattr(m, "level", np.array([[1.0, 0, 0], [0, 0, -1.0], [0, 1.0, 0]])), "bad_level"),  # on its side
    (lambda m: setattr(m, "level", [[1.0, 0.0], [0.0, 1.0, 0.0]]), "bad_level"),  # ragged
    (lambda m: setattr(m, "level", tilted(31.0)), "bad_level"),                  # past 30 deg
    (lambda m: setattr(m, "extents", None), "malformed_message"),
    (lambda m: setattr(m, "nodes", replace(m.nodes, node_ids=m.nodes.node_ids[:, None])), "malformed_message"),
    (lambda m: setattr(m, "nodes", replace(m.nodes, centers=m.nodes.centers.astype(object))), "malformed_message"),
])
def test_coarse_messages_the_ros_layer_could_not_make_are_refused_too(model, graphs, corrupt, counter):
    """A reflection as levelling came out as a verified transform with det -1; wrong types or
    ranks raised in the middle of an estimate."""
    a, b, reg, _ = make_agents(model, graphs)
    msg = b.coarse_message(1)
    corrupt(msg)
    assert reg.on_coarse(msg, now=0.0) == (None, None)
    assert reg.counters[counter] == 1
    assert "b" not in reg.links or reg.links["b"].coarse is None
    ok = b.coarse_message(2)
    ok.level = tilted(29.0)          # a levelling within the bound is taken
    reg.on_coarse(ok, now=1.0)
    assert reg.counters[counter] == 1 and reg.links["b"].coarse is ok


def tilted(deg: float) -> np.ndarray:
    """A levelling rotation that tilts a map by deg about x."""
    c, s = np.cos(np.radians(deg)), np.sin(np.radians(deg))
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


@pytest.mark.parametrize("corrupt,counter", [
    (lambda m: setattr(m, "point_node", m.point_node.astype(np.float64)), "malformed_message"),
    (lambda m: setattr(m, "points", m.points[:, :2].copy()), "bad_points"),
    (lambda m: (setattr(m, "points", np.repeat(m.points, 40, axis=0)),
                setattr(m, "point_node", np.repeat(m.point_node, 40))), "oversized_message"),
])
def test_bad_dense_answers_are_refused_and_asked_for_again(model, graphs, corrupt, counter):
    """An answer that raised half-way had marked the exchange done: the link never asked for
    the same graphs again. One with far more points than its nodes sample (40 times here; 500 000
    points cost 17 s) is refused as oversized."""
    a, b, reg, _ = make_agents(model, graphs, PeersConfig(search_request_interval_s=1.0))
    _, req = reg.on_coarse(b.coarse_message(1), now=0.0)
    dense = b.dense_message(1, req.node_ids, "a", req.sequence)
    corrupt(dense)
    assert reg.on_dense(dense, now=0.5) is None
    assert reg.counters[counter] == 1 and reg.links["b"].dense_cloud is None
    again = reg.on_coarse(b.coarse_message(2), now=3.0)[1] or (reg.on_tick(3.1) or [None])[0]
    assert again is not None


def test_dense_points_naming_unknown_nodes_are_refused(model, graphs):
    a, b, reg, _ = make_agents(model, graphs)
    _, req = reg.on_coarse(b.coarse_message(1), now=0.0)
    dense = b.dense_message(1, None, "a", req.sequence)
    dense.point_node = dense.point_node + 1000
    assert reg.on_dense(dense, now=0.0) is None
    assert reg.counters["bad_points"] == 1


def test_silent_peer_retries_with_backoff_then_gives_up(model, graphs):
    cfg = PeersConfig(request_timeout_s=1.0, retry_backoff=2.0, max_retries=2, min_request_interval_s=5.0)
    a, b, reg, logs = make_agents(model, graphs, cfg)
    _, req = reg.on_coarse(b.coarse_message(1), now=0.0)
    assert req is not None
    assert reg.on_tick(0.9) == []
    retry1 = reg.on_tick(1.0)
    assert len(retry1) == 1 and retry1[0].sequence != req.sequence
    assert reg.on_tick(2.9) == []            # second wait is 2 s
    retry2 = reg.on_tick(3.0)
    assert len(retry2) == 1
    assert reg.on_tick(6.9) == []            # third wait is 4 s
    assert reg.on_tick(7.0) == []            # gives up instead of a third retry
    assert reg.counters["request_gave_up"] == 1 and reg.counters["request_retry"] == 2
    assert any("giving up" in line for line in logs)
    # a new request only after the minimum interval since giving up, even for a coarse estimate
    # that passes the verdict with no points to check it on (prompt_request does not hurry it)
    assert reg.on_coarse(b.coarse_message(2), now=8.0)[1] is None
    assert reg.links["b"].prompt and reg.links["b"].gave_up
    assert reg.on_coarse(b.coarse_message(3), now=12.5)[1] is not None


def test_no_estimate_before_own_map(model, graphs):
    _, b, _, _ = make_agents(model, graphs)
    a = AgentCore(AgentConfig(name="a"), model)
    reg = Peers(PeersConfig(), a, model, log=lambda s: None)
    assert reg.on_coarse(b.coarse_message(1), now=0.0) == (None, None)
    assert reg.counters["own_map_not_ready"] == 1


def test_a_request_size_that_no_answer_could_meet_is_refused(model):
    """max_request_nodes below min_nodes: no request would ever go out, and the link would
    wait in silence (the node refuses it at start and live, by this check)."""
    from sgreg_core.bench.offline_replay import OfflineReplayConfig
    from sgreg_core.runtime.peers import check_request_size

    own = AgentCore(AgentConfig(name="a", min_nodes=10), model)
    with pytest.raises(ValueError, match=r"max_request_nodes \(8\) must not be below min_nodes \(10\)"):
        Peers(PeersConfig(max_request_nodes=8), own, model)
    with pytest.raises(ValueError, match="no dense request would ever be sent"):
        OfflineReplayConfig(agent=AgentConfig(min_nodes=60))
    check_request_size(PeersConfig(max_request_nodes=10), own.cfg)     # equal is enough


def test_a_malformed_graph_before_the_own_map_is_refused_not_raised(model, graphs):
    _, b, _, _ = make_agents(model, graphs)
    own = AgentCore(AgentConfig(name="a"), model)
    reg = Peers(PeersConfig(), own, model, log=lambda s: None)
    msg = b.coarse_message(1)
    msg.nodes = replace(msg.nodes, descriptor=msg.nodes.descriptor[:, 0])
    assert reg.on_coarse(msg, now=0.0) == (None, None)
    assert reg.counters["bad_feature_size"] == 1
    # descriptors of another width: refused now, not kept to fail every estimate once the own
    # map is there
    narrow = b.coarse_message(2)
    narrow.nodes = replace(narrow.nodes, descriptor=narrow.nodes.descriptor[:, :7].copy())
    assert reg.on_coarse(narrow, now=1.0) == (None, None)
    assert reg.counters["bad_feature_size"] == 2 and ("b" not in reg.links or reg.links["b"].coarse is None)
    own.set_graph(graphs[0], 1, 0)
    assert reg.on_own_map(now=4.0) == []


def test_node_ids_past_int64_are_refused(model, graphs):
    """The wire carries uint32 ids; a direct caller's uint64 past int64 would overflow where
    node centers are compared."""
    a, b, reg, _ = make_agents(model, graphs)
    msg = b.coarse_message(1)
    msg.nodes = replace(msg.nodes, node_ids=np.uint64(2**64 - 1) - msg.nodes.node_ids.astype(np.uint64))
    assert reg.on_coarse(msg, now=0.0) == (None, None)
    assert reg.counters["bad_nodes"] == 1


def test_a_peer_result_that_is_not_a_rigid_transform_is_no_witness(model, graphs):
    a, b, reg, _ = make_agents(model, graphs)
    for T in (np.full((4, 4), np.nan), "T", [[1.0, 0.0]], np.diag([1.0, 1.0, -1.0, 1.0])):
        reg.on_peer_result("b", T, True, "dense", "ok", "confirmed", now=0.0)
    assert "b" not in reg._witnesses and reg.counters["bad_result"] == 4


def test_witnesses_taken_back_leave_the_bound_on_peers_working(model, graphs):
    """b takes back what it said (its link contradicted): with max_peers 1, c's verified
    result then takes b's place instead of failing on b's emptied record."""
    from sgreg_core.geometry import invert_transform
    a, b, reg, _ = make_agents(model, graphs, PeersConfig(max_peers=1))
    T_ba = invert_transform(T_GT)
    reg.on_peer_result("b", T_ba, True, "merged", "ok", "confirmed", now=0.0)
    reg.on_peer_result("b", T_ba, False, "dense", "contradicted", "none", now=1.0)
    reg.on_peer_result("c", T_ba, True, "merged", "ok", "confirmed", now=2.0)
    assert reg._witness_agrees("c", T_GT, 2.5, ("confirmed",))
    assert not reg._witness_agrees("b", T_GT, 2.5, ("confirmed", "dense"))


def test_own_messages_are_ignored(model, graphs):
    a, _, reg, _ = make_agents(model, graphs)
    assert reg.on_coarse(a.coarse_message(1), now=0.0) == (None, None)
    assert not reg.links


def test_own_reference_cloud_is_built_once_per_map(model, graphs):
    a, _, reg, _ = make_agents(model, graphs)
    pose = reg.cfg.pipeline.pose
    first = a.reference_cloud(pose)
    assert first.valid and a.reference_cloud(pose) is first
    a.set_graph(graphs[0], 2, 1_000_000_000)   # a new map: a new reference
    assert a.reference_cloud(pose) is not first


def test_one_map_intake_for_both_nodes_counts_every_refusal(model):
    scene = generate_scene(1, SynthConfig(rooms=1))
    agent = AgentCore(AgentConfig(name="a"), model)
    peers = Peers(PeersConfig(), agent, model, log=lambda s: None)
    assert peers.counters is agent.counters                  # one table per node
    assert peers.take_own_map(scene, 1, 0) is None and agent.ready
    reference = agent._reference                             # built with the map, not per estimate
    assert reference is not None and agent.reference_cloud(peers.cfg.pipeline.pose) is reference[1]
    assert "twice" in peers.take_own_map(scene, 1, 1_000_000_000)
    empty = InstanceMap(points=np.zeros((0, 3), np.float32), instance=np.zeros(0, np.int32), labels={})
    assert "refused" in agent.take_map(empty, 2, 2_000_000_000)
    assert agent.counters["duplicate_map"] == 1 and agent.counters["bad_instance_map"] == 1
    assert agent.map_sequence == 1                           # the refused map changed nothing


def test_a_map_whose_graph_peers_would_refuse_is_refused_by_its_agent(model):
    """Peers refuse graphs of more than max_nodes nodes; an agent that sent them anyway was
    never registered, and its own diagnostics said nothing. Both nodes read one max_nodes."""
    scene = generate_scene(1, SynthConfig(rooms=1))
    agent = AgentCore(AgentConfig(name="a", max_nodes=10), model)
    why = agent.take_map(scene, 1, 0)
    assert "max_nodes=10" in why and agent.counters["bad_instance_map"] == 1 and not agent.ready
    as_lists = InstanceMap(points=scene.points.tolist(), instance=scene.instance, labels=scene.labels)
    assert "refused" in agent.take_map(as_lists, 2, 1)          # a refusal, not an AttributeError


def test_a_map_that_levelling_takes_past_max_coord_is_refused_by_its_agent(model):
    """Peers refuse centers beyond MAX_COORD_M; a map just inside it that levelling moves
    outside was taken by its agent and then refused by every peer."""
    from sgreg_core.geometry import MAX_COORD_M
    from sgreg_core.simulation.noise import tilt_rotation

    scene = generate_scene(6, SynthConfig(rooms=2))
    p = scene.points.astype(np.float64)
    p[:, 0] += MAX_COORD_M - p[:, 0].max() + 3.0          # levelled, the map reaches x = 10003 m
    raw = p @ tilt_rotation(3.0, 90.0)[:3, :3].T          # as a robot with 3 deg of tilt maps it
    assert np.abs(raw).max() <= MAX_COORD_M
    agent = AgentCore(AgentConfig(name="b"), model)
    why = agent.take_map(InstanceMap(raw.astype(np.float32), scene.instance, scene.labels), 1, 0)
    assert why is not None and "levelled map" in why and not agent.ready


def test_no_request_for_fewer_nodes_than_an_answer_needs(model, graphs):
    """Node matches are each node's top 3: three matches can name two of the peer's nodes, and
    an answer on two is refused (too_few_nodes). Such a wish is not made."""
    from types import SimpleNamespace

    a, b, reg, _ = make_agents(model, graphs, PeersConfig(search_request_interval_s=1.0))
    reg.on_coarse(b.coarse_message(1), now=0.0)
    link = reg.links["b"]
    link.pending, link.wanted, link.exchanged = None, None, None
    ids = b.features.node_ids
    two = SimpleNamespace(node_matches=3, node_scores=np.array([0.9, 0.8, 0.7]),
                          node_pairs=np.array([[ids[0], 1], [ids[0], 2], [ids[1], 3]]))
    assert reg._maybe_request(link, two, now=5.0) is None and link.wanted is None


def test_peer_graphs_far_away_or_with_too_many_points_per_node_are_refused(model, graphs):
    """As the own map: centers or points beyond MAX_COORD_M are refused (every such graph had
    one digest); a dense answer has at most the model's points per node (more were cut
    silently)."""
    a, b, reg, _ = make_agents(model, graphs)
    far = b.coarse_message(1)
    far.nodes = replace(far.nodes, centers=far.nodes.centers + np.float32(1e30))
    assert reg.on_coarse(far, now=0.0) == (None, None) and reg.counters["invalid_values"] == 1
    _, req = reg.on_coarse(b.coarse_message(2), now=0.5)
    dense = b.dense_message(1, req.node_ids, "a", req.sequence)
    dense.point_node = np.zeros_like(dense.point_node)          # every point names node 0
    assert reg.on_dense(dense, now=1.0) is None and reg.counters["bad_points"] == 1


def test_a_map_too_small_to_register_is_waited_out_not_refused(model):
    """A front end's first maps hold the floor and an object or two: fewer nodes than min_nodes.
    Such a map is no bad input (no refusal, so no warning and no WARN), it changes nothing the
    agent holds, and the first map large enough is taken."""
    scene = generate_scene(1, SynthConfig(rooms=1))
    first = scene.instance == scene.instance[scene.instance > 0][0]
    small = InstanceMap(points=scene.points[first], instance=scene.instance[first], labels=scene.labels)
    agent = AgentCore(AgentConfig(name="a"), model)
    peers = Peers(PeersConfig(), agent, model, log=lambda s: None)
    why = peers.take_own_map(small, 1, 0)
    assert isinstance(why, NotYet) and "min_nodes=3" in why and not agent.ready
    assert agent.counters["small_map"] == 1 and agent.refused == 0
    assert peers.take_own_map(scene, 2, 1_000_000_000) is None and agent.ready
    assert isinstance(agent.take_map(small, 3, 2_000_000_000), NotYet)
    assert agent.map_sequence == 2 and agent.counters["small_map"] == 2 and agent.refused == 0


def test_a_front_end_that_starts_over_drops_the_old_map(model):
    """Its sequence goes back (and its first maps are small): the old graph must not go on
    standing for the agent's map, sent on every heartbeat, nor block the new sequence."""
    scene = generate_scene(1, SynthConfig(rooms=1))
    first = scene.instance == scene.instance[scene.instance > 0][0]
    small = InstanceMap(points=scene.points[first], instance=scene.instance[first], labels=scene.labels)
    agent = AgentCore(AgentConfig(name="a"), model)
    assert agent.take_map(scene, 57, 1_000_000_000) is None and agent.ready
    why = agent.take_map(small, 0, 2_000_000_000)
    assert isinstance(why, NotYet) and "restarted" in why and not agent.ready
    assert not agent.coarse_due(100.0) and agent.counters["front_end_restarts"] == 1
    assert agent.take_map(small, 1, 3_000_000_000) is not None      # still waiting, no refusal
    assert agent.take_map(scene, 2, 4_000_000_000) is None and agent.map_sequence == 2
    assert agent.refused == 0


def test_no_dense_request_for_graphs_already_exchanged(model, graphs):
    """The same two graphs give the same dense estimate: once answered, they are not asked for
    again; a changed map is, once the interval allows (on_tick asks for a held-back wish)."""
    a, b, reg, _ = make_agents(model, graphs, PeersConfig(search_request_interval_s=1.0,
                                                          min_request_interval_s=1.0))
    _, req = reg.on_coarse(b.coarse_message(1), now=0.0)
    reg.on_dense(b.dense_message(1, req.node_ids, "a", req.sequence), now=0.2)
    for k in range(2, 6):          # b keeps sending the same graph
        assert reg.on_coarse(b.coarse_message(k), now=float(k))[1] is None
        assert reg.on_tick(float(k) + 0.5) == []
    assert reg.counters["requests"] == 1
    moved = moved_graph(graphs[1], yaw_transform(0.0, (0.03, 0.0, 0.0)), np.random.default_rng(2))
    b.set_graph(moved, 2, 6_000_000_000)
    _, req = reg.on_coarse(b.coarse_message(6), now=6.0)
    assert req is not None                                  # new content: asked at once
    reg.on_dense(b.dense_message(2, req.node_ids, "a", req.sequence), now=6.1)
    b.set_graph(graphs[1], 3, 6_500_000_000)
    assert reg.on_coarse(b.coarse_message(7), now=6.5)[1] is None    # within the interval ...
    [held] = reg.on_tick(7.2)                                        # ... asked once it passed
    assert held.to_agent == "b" and reg.counters["requests"] == 3


def test_an_unanswered_request_is_asked_again(model, graphs):
    a, b, reg, _ = make_agents(model, graphs, PeersConfig(search_request_interval_s=1.0, max_retries=0,
                                                          request_timeout_s=0.5))
    _, req = reg.on_coarse(b.coarse_message(1), now=0.0)
    assert req is not None
    assert reg.on_tick(1.0) == [] and reg.counters["request_gave_up"] == 1
    [again] = reg.on_tick(2.1)
    assert again.sequence != req.sequence


def test_a_late_answer_to_a_retried_request_answers_it(model, graphs):
    """On a slow link the answer to a request's first sending can arrive after its retry went
    out: it answers the request (nothing is left pending to give up on)."""
    a, b, reg, _ = make_agents(model, graphs, PeersConfig(request_timeout_s=0.5, max_retries=1))
    _, req = reg.on_coarse(b.coarse_message(1), now=0.0)
    [retry] = reg.on_tick(0.5)
    assert retry.sequence != req.sequence
    reg.on_dense(b.dense_message(1, req.node_ids, "a", req.sequence), now=0.7)
    link = reg.links["b"]
    assert link.pending is None and link.dense_cloud is not None
    assert reg.on_tick(5.0) == [] and reg.counters["request_gave_up"] == 0 and not link.gave_up


def test_own_map_change_is_estimated_against_a_quiet_peer(model, graphs):
    a, b, reg, _ = make_agents(model, graphs)
    reg.on_coarse(b.coarse_message(1), now=0.0)
    assert reg.on_own_map(now=1.0) == []            # b's next graph is due anyway
    assert reg.on_own_map(now=3.0) == []            # quiet peer, but nothing new on either side
    a.set_graph(moved_graph(graphs[0], yaw_transform(0.0, (0.02, 0.0, 0.0)), np.random.default_rng(3)), 2, 3_000_000_000)
    [(est, _)] = reg.on_own_map(now=3.5)
    assert est.peer_id == "b" and est.mode == "coarse"
    assert est.stamp_ns == max(a.stamp_ns, b.stamp_ns)


def test_coarse_graphs_drop_to_a_heartbeat_when_nothing_changes(model, graphs):
    agent = AgentCore(AgentConfig(name="a", quiet_after_s=3.0, heartbeat_period_s=10.0), model)
    assert not agent.coarse_due(0.0)                 # no map yet
    agent.set_graph(graphs[0], 1, 0)
    sent = [t for t in np.arange(0.0, 30.0, 1.0) if agent.coarse_due(t) and agent.broadcast(t)]
    assert sent == [0.0, 1.0, 2.0, 12.0, 22.0]      # the rate for quiet_after_s, then heartbeats
    agent.set_graph(moved_graph(graphs[0], yaw_transform(0.0, (0.05, 0, 0)), np.random.default_rng(4)), 2, 30_000_000_000)
    assert agent.coarse_due(30.0) and agent.broadcast(30.0) and agent.coarse_due(31.0)


def test_a_link_the_cycles_dispute_is_withheld(model, graphs):
    a, b, reg, _ = confirmed_link(model, graphs)
    reg.disputed = {"b"}             # the merger rejected a's link with b around a cycle
    est, _ = reg.on_coarse(b.coarse_message(3), now=2.0)
    assert not est.verified and est.reason == "disputed_by_cycles" and est.link == "confirmed"
    reg.disputed = set()
    est, _ = reg.on_coarse(b.coarse_message(4), now=3.0)
    assert est.verified


def test_a_peer_the_merged_frame_places_is_asked_for_dense_data_rarely(model, graphs):
    cfg = PeersConfig(min_request_interval_s=5.0, attached_request_interval_s=30.0)
    for attached, expect in ((set(), True), ({"b"}, False)):
        a, b, reg, _ = confirmed_link(model, graphs, cfg)
        reg.attached = attached
        drift(b, graphs, 5, 9.0)                       # new content: worth a request, if due
        _, req = reg.on_coarse(b.coarse_message(3), now=10.0)
        assert (req is not None) == expect


def test_a_peer_other_agents_place_is_searched_rarely(model, graphs):
    """No link of a's own to b yet: a searches b every search interval, unless other agents'
    links place b through a consistent triangle (Peers.placed, from the merger); a bridge no
    cycle checks, or any two-agent link, is searched as before."""
    cfg = PeersConfig(search_request_interval_s=2.0, attached_request_interval_s=30.0)
    for attached, placed, asks in ((set(), set(), True), ({"b"}, set(), True), ({"b"}, {"b"}, False)):
        a, b, reg, _ = make_agents(model, graphs, cfg)
        reg.attached, reg.placed = attached, placed
        _, first = reg.on_coarse(b.coarse_message(1), now=0.0)
        assert first is not None                 # the last request was long ago
        reg.on_dense(b.dense_message(1, first.node_ids, "a", first.sequence), now=0.5)
        link = reg.links["b"]
        link.candidate = link.confirmed = link.kept = None   # still searching: no link of a's own
        drift(b, graphs, 5, 9.0)
        _, req = reg.on_coarse(b.coarse_message(2), now=10.0)
        assert (req is not None) == asks, (attached, placed)


def test_a_peer_other_agents_place_is_not_asked_promptly(model, graphs):
    """prompt_request hurries a new coarse candidate's dense request, but not to a peer that
    other agents' links place (its interval is attached_request_interval_s)."""
    for placed in (set(), {"b"}):
        a, b, reg, _ = make_agents(model, graphs, PeersConfig(attached_request_interval_s=30.0))
        reg.attached, reg.placed = {"b"}, placed
        _, first = reg.on_coarse(b.coarse_message(1), now=0.0)
        reg.on_dense(b.dense_message(1, first.node_ids, "a", first.sequence), now=0.5)
        link = reg.links["b"]
        link.candidate = link.confirmed = link.kept = None   # still searching: no link of a's own
        drift(b, graphs, 5, 1.5)
        est, req = reg.on_coarse(b.coarse_message(2), now=1.5)
        assert est.reason == "awaiting_confirmation" and link.candidate.mode == "coarse"
        assert (req is not None) == (not placed), placed


def test_kept_correspondences_go_when_the_peer_levels_its_map_anew(model, graphs):
    from scipy.spatial.transform import Rotation

    a, b, reg, logs = confirmed_link(model, graphs)
    assert reg.links["b"].kept is not None and reg.links["b"].dense_cloud is not None
    msg = b.coarse_message(3)
    msg.level = Rotation.from_rotvec([0.02, 0.0, 0.0]).as_matrix()    # b's gravity estimate moved
    reg.on_coarse(msg, now=2.0)
    assert reg.links["b"].kept is None and reg.counters["kept_dropped"] == 1
    assert any("levelled anew" in line for line in logs)


def test_kept_correspondences_go_when_a_dense_answer_comes_at_a_new_levelling(model, graphs):
    """The answer replaces the peer's points; the kept pairs of the old levelling go with them
    even when the answer's own estimate is refused (the next coarse graph, at the new
    levelling like the answer, would not notice)."""
    from scipy.spatial.transform import Rotation

    a, b, reg, _ = confirmed_link(model, graphs)
    link = reg.links["b"]
    assert link.kept is not None
    dense = b.dense_message(2, None, "a", link.asked[-1])
    dense.level = Rotation.from_rotvec([0.02, 0.0, 0.0]).as_matrix()
    reg.on_dense(dense, now=2.0)
    assert reg.counters["kept_dropped"] == 1
    assert link.kept is None or np.allclose(link.kept.peer_level, dense.level)


def test_kept_pairs_of_an_old_levelling_go_whichever_way_they_came_back(model, graphs):
    """Kept pairs of the peer's old levelling (a candidate's, confirmed after an answer at the
    new one) go at the next coarse graph; the peer's points of now stay."""
    from scipy.spatial.transform import Rotation

    a, b, reg, _ = confirmed_link(model, graphs)
    link = reg.links["b"]
    link.kept = replace(link.kept, peer_level=Rotation.from_rotvec([0.0, 0.02, 0.0]).as_matrix())
    reg.on_coarse(b.coarse_message(3), now=2.0)
    assert reg.counters["kept_dropped"] == 1 and link.dense_cloud is not None


def test_the_peers_points_stay_when_only_the_own_map_is_levelled_anew(model, graphs):
    """The kept pairs are in both levelled frames of then and go; the peer's points are in
    its frame, which did not change: dropping them left coarse estimates nothing to verify on
    (no_peer_cloud_to_verify) until a new dense exchange."""
    from scipy.spatial.transform import Rotation

    a, b, reg, logs = confirmed_link(model, graphs)
    link = reg.links["b"]
    cloud = link.dense_cloud
    assert link.kept is not None and cloud is not None
    a.level = replace(a.level, R=Rotation.from_rotvec([0.02, 0.0, 0.0]).as_matrix())
    est, _ = reg.on_coarse(b.coarse_message(3), now=2.0)
    assert link.kept is None and reg.counters["kept_dropped"] == 1
    assert link.dense_cloud is cloud and est.reason != "no_peer_cloud_to_verify"
    assert any("own map was levelled anew" in line for line in logs)


def test_an_answer_without_the_nodes_asked_for_answers_the_request(model, graphs):
    """The peer's front end renumbered its nodes after the coarse graph the request named:
    the answer holds none of them and is refused (too_few_nodes), and asking again for the
    same nodes would get the same answer; the request is done, and the peer's next graph (the
    new ids) is asked for when the interval allows."""
    a, b, reg, _ = make_agents(model, graphs, PeersConfig(search_request_interval_s=1.0))
    _, req = reg.on_coarse(b.coarse_message(1), now=0.0)
    gb = graphs[1]
    b.set_graph(replace(gb, node_ids=gb.node_ids + 1000), 2, 1)         # renumbered
    answer = b.dense_message(1, req.node_ids, "a", req.sequence)
    assert answer.num_nodes == 0
    assert reg.on_dense(answer, now=0.5) is None
    assert reg.counters["too_few_nodes"] == 1 and reg.counters["answer_too_few_nodes"] == 1
    assert reg.links["b"].pending is None and reg.on_tick(3.0) == []   # no retry of stale ids
    _, again = reg.on_coarse(b.coarse_message(2), now=3.0)
    assert again is not None and set(again.node_ids) <= set(gb.node_ids + 1000)


def test_an_estimate_off_the_merged_frame_of_three_agents_is_withheld(model, graphs):
    a, b, reg, _ = confirmed_link(model, graphs)
    truth = T_GT                                      # T_a^b: a's map into b's
    reg.expected = lambda peer: yaw_transform(0.0, (4.0, 0.0, 0.0)) @ truth   # others put b 4 m away
    est, _ = reg.on_coarse(b.coarse_message(3), now=2.0)
    assert not est.verified and est.reason == "disputed_by_cycles"
    reg.expected = lambda peer: truth                 # the merged frame agrees
    est, _ = reg.on_coarse(b.coarse_message(4), now=3.0)
    assert est.verified


def test_the_merged_frame_is_held_to_the_cycle_tolerance_of_the_merger_followed(model, graphs):
    """Offline replays and the node alike: the merger's cycle_m / cycle_deg, not a copy of them."""
    from sgreg_core.runtime.merge import MergeConfig, Merger
    a, b, reg, _ = confirmed_link(model, graphs)
    reg.follow(Merger(MergeConfig(cycle_m=5.0, cycle_deg=10.0), "a"))
    reg.expected = lambda peer: yaw_transform(0.0, (4.0, 0.0, 0.0)) @ T_GT   # 4 m off: within 5 m
    est, _ = reg.on_coarse(b.coarse_message(3), now=2.0)
    assert est.verified
    reg.follow(Merger(MergeConfig(), "a"))                                     # 0.5 m: disputed
    reg.expected = lambda peer: yaw_transform(0.0, (4.0, 0.0, 0.0)) @ T_GT
    est, _ = reg.on_coarse(b.coarse_message(4), now=3.0)
    assert not est.verified and est.reason == "disputed_by_cycles"


def test_dense_requests_from_no_agent_or_for_too_many_nodes_are_not_answered(model, graphs):
    """A requester's name must be an agent id (it is kept, and echoed in the answer); an answer
    larger than max_answer_nodes is refused (the budget counts answers, not bytes); and what the
    agent remembers of requesters stays bounded."""
    from sgreg_core.runtime.messages import DenseRequestMessage
    b = make_agents(model, graphs)[1]
    n = b.graph.num_nodes

    def ask(who, now, ids=np.zeros(0, np.int64)):
        return b.answer_request(DenseRequestMessage(who, "b", 1, 1, b.weights_id, ids), now)

    assert ask("x" * 11_000, 1.0)[0] is None and ask("a/../c", 1.0)[0] is None
    assert b.counters["bad_request"] == 2
    b.cfg = AgentConfig(name="b", max_answer_nodes=n - 1, dense_answers_per_s=100.0)
    msg, why = ask("a", 2.0)                                  # "all nodes"
    assert msg is None and "max_answer_nodes" in why and b.counters["request_too_large"] == 1
    msg, _ = ask("a", 2.0, b.features.node_ids[:3])
    assert msg is not None and msg.num_nodes == 3
    for k in range(300):
        ask(f"r{k}", 10.0 + k * 0.02, b.features.node_ids[:3])
    assert len(b._last_answer) <= 65


def test_dense_answers_are_rate_limited_per_requester_and_overall(model, graphs):
    """One answer per requester per dense_min_interval_s, a request on a timer of that same
    period answered despite jitter; many requesters together stay within the token budget."""
    from sgreg_core.runtime.messages import DenseRequestMessage
    b = make_agents(model, graphs)[1]
    b.cfg = AgentConfig(name="b", dense_min_interval_s=1.0, dense_answers_per_s=2.0)

    def ask(who, now):
        return b.answer_request(DenseRequestMessage(who, "b", 1, 1, b.weights_id, np.zeros(0, np.int64)), now)

    assert ask("a", 10.0)[0] is not None
    msg, why = ask("a", 10.5)
    assert msg is None and "within" in why and b.counters["request_rate_limited"] == 1
    assert ask("a", 10.85)[0] is None                      # more than a tenth early
    assert ask("a", 10.0 + 0.95)[0] is not None            # the requester's 1 Hz timer, jittered
    assert ask("c", 10.96)[0] is not None                 # another requester: its own interval
    msg, why = ask("d", 10.97)                            # but not past the budget of all
    assert msg is None and b.counters["request_over_budget"] == 1
    assert b.refused == 0       # the agent's own limits at work, no sign of trouble to warn on
