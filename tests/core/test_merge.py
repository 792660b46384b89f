"""The merger (runtime/merge.py): pairwise links of N agents -> one consistent frame, a wrong
link refused by the cycles it breaks, the same tree whatever the order links arrive in."""
import itertools

import numpy as np
import pytest

from sgreg_core.geometry import invert_transform, yaw_transform
from sgreg_core.runtime.merge import Link, Links, MergeConfig, merge, to_4dof

S = 1_000_000_000   # ns per second

# each agent's map frame in the world: T_world<-agent
WORLD = {"a": yaw_transform(0.3, (1.0, 2.0, 0.0)), "b": yaw_transform(-1.2, (-4.0, 0.5, 0.1)),
         "c": yaw_transform(2.5, (3.0, -6.0, 0.0)), "d": yaw_transform(0.9, (8.0, 8.0, -0.1)),
         "e": yaw_transform(-2.0, (-7.0, -3.0, 0.0))}


def true_link(src: str, dst: str, noise: float = 0.0, rng=None) -> Link:
    """noise: yaw error (deg, std); the translation error is noise / 10 m per axis."""
    T = invert_transform(WORLD[dst]) @ WORLD[src]
    if noise:
        T = yaw_transform(rng.normal(0, np.radians(noise)), rng.normal(0, noise / 10, 3)) @ T
    return Link(src, dst, T, confidence=0.95)


def relative_to_anchor(poses: dict, anchor: str = "a") -> dict:
    """T_merged<-x should equal T_anchor<-x = inv(WORLD[anchor]) @ WORLD[x]."""
    return {x: invert_transform(WORLD[anchor]) @ WORLD[x] for x in poses}


def assert_poses(result, tol_m=0.05, tol_deg=0.5):
    expected = relative_to_anchor(result.poses, result.anchor)
    for x, T in result.poses.items():
        yaw, t = to_4dof(invert_transform(expected[x]) @ T)
        assert np.linalg.norm(t) < tol_m and abs(np.degrees(yaw)) < tol_deg, x


def test_a_chain_of_links_places_every_agent():
    result = merge([true_link("b", "a"), true_link("c", "b"), true_link("d", "c")])
    assert result.anchor == "a" and result.attached == ["a", "b", "c", "d"]
    assert not result.rejected and np.allclose(result.poses["a"], np.eye(4))
    assert_poses(result)


def test_an_injected_wrong_link_is_rejected_by_cycle_consistency():
    rng = np.random.default_rng(0)
    right = [true_link(s, d, noise=0.5, rng=rng) for s, d in itertools.permutations("abcd", 2)
             if (s, d) != ("d", "b")]
    wrong = Link("d", "b", yaw_transform(np.radians(40), (2.0, 1.0, 0.0)) @ true_link("d", "b").T,
                 confidence=0.99)        # most confident of all, and still refused
    result = merge(right + [wrong])
    assert [(l.src, l.dst) for l, _ in result.rejected] == [("d", "b")]
    assert "breaks the cycles" in result.rejected[0][1]
    assert result.attached == ["a", "b", "c", "d"]
    assert_poses(result, tol_m=0.1, tol_deg=1.0)


def test_every_order_of_arrival_gives_the_same_tree():
    rng = np.random.default_rng(1)
    links = [true_link(s, d, noise=1.0, rng=rng) for s, d in itertools.permutations("abcd", 2)
             if (s, d) != ("c", "a")]
    links.append(Link("c", "a", yaw_transform(2.0, (5.0, 0.0, 0.0)), confidence=0.9))   # wrong
    first = merge(links)
    assert [l.key for l, _ in first.rejected] == [("c", "a")]
    with pytest.raises(ValueError):     # one measurement per directed link, none of an agent to itself
        merge(links + [true_link("c", "a")])
    with pytest.raises(ValueError):
        merge(links + [Link("b", "b", np.eye(4))])
    for k in range(5):
        again = merge(list(np.random.default_rng(k).permutation(np.array(links, dtype=object))))
        assert again.attached == first.attached
        for x in first.poses:
            assert np.allclose(again.poses[x], first.poses[x], atol=1e-9)


def test_several_paths_are_averaged():
    """Noisy links over cycles: the averaged poses are closer to the truth than the direct
    links to the anchor alone."""
    def error(x, T):
        return np.linalg.norm(to_4dof(invert_transform(relative_to_anchor({x: 0})[x]) @ T)[1])

    averaged, direct = [], []
    for seed in range(10):
        rng = np.random.default_rng(seed)
        links = [true_link(s, d, noise=0.5, rng=rng) for s, d in itertools.permutations("abcd", 2)]
        result = merge(links)
        assert not result.rejected and result.attached == ["a", "b", "c", "d"]
        for l in links:
            if "a" in l.key:
                x = l.src if l.dst == "a" else l.dst
                direct.append(error(x, l.towards("a")))
        averaged += [error(x, result.poses[x]) for x in "bcd"]
    assert np.mean(averaged) < 0.7 * np.mean(direct)


def test_agents_no_link_reaches_are_not_attached():
    result = merge([true_link("b", "a"), true_link("d", "c")], agents=["a", "b", "c", "d", "e"])
    assert result.attached == ["a", "b"] and set(result.poses) == {"a", "b"}
    assert result.groups == [["a", "b"], ["c", "d"], ["e"]]
    assert merge([]).anchor is None and merge([]).poses == {}


def test_links_follow_what_each_agent_says():
    links = Links()
    T = true_link("a", "b").T
    links.take("a", "b", T, verified=True, reason="ok", link_state="confirmed", confidence=0.9, stamp_ns=1 * S)
    links.take("a", "b", np.eye(4), verified=False, reason="verification_failed", link_state="confirmed", confidence=0.2, stamp_ns=2 * S)
    assert len(links.current()) == 1 and np.allclose(links.current()[0].T, T)   # a failed estimate keeps it
    links.take("a", "b", np.eye(4), verified=False, reason="contradicted", link_state="candidate", confidence=0.9, stamp_ns=3 * S)
    assert links.current() == []                                                # withdrawn
    links.take("b", "a", T, verified=True, reason="ok", link_state="confirmed", confidence=0.9, stamp_ns=4 * S)
    assert links.agents == {"a", "b"}
    # withheld only because the cycles dispute it: still the link's pose, for the cycles to re-judge
    T2 = true_link("b", "a", noise=1.0, rng=np.random.default_rng(0)).T
    links.take("b", "a", T2, verified=False, reason="disputed_by_cycles", link_state="confirmed",
               confidence=0.9, stamp_ns=5 * S)
    assert np.allclose(links.current()[0].T, T2)


def test_links_age_by_the_maps_not_by_a_clock():
    """max_link_age_s: a link made from maps much older than the newest maps its own pair's
    results name is left out (a failed estimate's newer maps count: the pair moved on without
    the link); another pair's stamps, however far ahead (a wrong clock), age nothing."""
    links = Links()
    T = true_link("a", "b").T
    links.take("a", "b", T, verified=True, reason="ok", link_state="confirmed", confidence=0.9, stamp_ns=100 * S)
    links.take("b", "c", T, verified=True, reason="ok", link_state="confirmed", confidence=0.9, stamp_ns=105 * S)
    assert len(links.current(max_age_s=10.0)) == 2
    links.take("b", "a", T, verified=False, reason="too_few_inliers", link_state="candidate",
               confidence=0.1, stamp_ns=111 * S)
    assert [l.key for l in links.current(max_age_s=10.0)] == [("b", "c")]   # a -> b's maps are 11 s old
    assert len(links.current()) == 2                                         # 0: links never age
    links.take("a", "b", T, verified=True, reason="ok", link_state="confirmed", confidence=0.9, stamp_ns=112 * S)
    assert len(links.current(max_age_s=10.0)) == 2                           # re-verified
    # an agent whose clock is far ahead, then silent, ages no other pair's links
    links.take("c", "x", T, verified=False, reason="too_few_inliers", link_state="none", confidence=0.0,
               stamp_ns=10_000 * S)
    assert len(links.current(max_age_s=10.0)) == 2
    # its own pair's stamp far ahead ages that pair's link until the pair's next result
    links.take("c", "b", T, verified=False, reason="too_few_inliers", link_state="confirmed", confidence=0.0,
               stamp_ns=10_000 * S)
    assert [l.key for l in links.current(max_age_s=10.0)] == [("a", "b")]
    links.take("c", "b", T, verified=False, reason="too_few_inliers", link_state="confirmed", confidence=0.0,
               stamp_ns=113 * S)
    assert len(links.current(max_age_s=10.0)) == 2
    with pytest.raises(TypeError):                                            # seconds are refused
        links.take("a", "b", T, verified=True, reason="ok", link_state="confirmed", confidence=0.9, stamp_ns=114.0)


def test_the_merger_names_disputed_and_settled_peers():
    from sgreg_core.runtime.merge import Merger

    m = Merger(MergeConfig(), "a")
    rng = np.random.default_rng(3)
    for s, d in itertools.permutations("abc", 2):
        l = true_link(s, d, noise=0.3, rng=rng)
        if (s, d) == ("a", "c"):        # a's own link to c is wrong
            l = Link("a", "c", yaw_transform(0.0, (4.0, 0.0, 0.0)) @ l.T)
        m.take(l.src, l.dst, l.T, True, "ok", "confirmed", 0.9, 1 * S)
    news = m.update()
    assert any("link a -> c rejected" in line for line in news)
    assert any("c/map attached" in line for line in news)
    assert m.disputed_peers() == {"c"} and m.settled_peers() == {"b"}
    assert m.update() == []             # nothing new the second time


def test_two_agents_that_disagree_about_their_pair_attach_nothing_and_dispute_nothing():
    from sgreg_core.runtime.merge import Merger

    m = Merger(MergeConfig(), "a")
    right, wrong = true_link("a", "b"), Link("b", "a", yaw_transform(0.5, (3.0, 0.0, 0.0)) @ true_link("b", "a").T)
    m.take("a", "b", right.T, True, "ok", "confirmed", 0.90, 1 * S)
    m.take("b", "a", wrong.T, True, "ok", "confirmed", 0.99, 1 * S)
    m.update()
    assert m.result.attached in (["a"], ["b"]) and not m.result.accepted
    assert {l.key for l, _ in m.result.rejected} == {("a", "b"), ("b", "a")}
    assert m.disputed_peers() == set()            # each link's own rules judge it
    # a third agent decides: its links agree with a -> b, so b -> a is the wrong one
    for s_, d in (("c", "a"), ("c", "b")):
        m.take(s_, d, true_link(s_, d).T, True, "ok", "confirmed", 0.9, 3 * S)
    m.update()
    assert [l.key for l, _ in m.result.rejected] == [("b", "a")] and ("b", "a") in m.result.disputed
    assert m.result.attached == ["a", "b", "c"] and m.disputed_peers() == set()


def test_links_between_tilted_maps_are_merged_upright():
    """Each map leans by its own gravity error: the merger takes links between the levelled
    frames, and the published poses put the tilt back."""
    from scipy.spatial.transform import Rotation

    from sgreg_core.runtime.merge import Merger

    rng = np.random.default_rng(4)
    lean = {x: Rotation.from_rotvec(np.r_[rng.normal(size=2), 0.0] * np.radians(1.5)).as_matrix() for x in "abc"}
    L = {x: np.eye(4) for x in "abc"}
    for x in "abc":
        L[x][:3, :3] = lean[x]
    raw = {x: WORLD[x] @ L[x] for x in "abc"}    # p_world = WORLD p_levelled, p_levelled = L p_map
    m = Merger(MergeConfig(), "a")
    for x in "abc":
        m.set_level(x, lean[x])
    for s_, d in itertools.permutations("abc", 2):
        m.take(s_, d, np.linalg.inv(raw[d]) @ raw[s_], True, "ok", "confirmed", 0.9, 1 * S)
    m.update()
    assert not m.result.rejected and m.result.attached == ["a", "b", "c"]
    for x, T in m.raw_poses().items():       # T_merged<-map, the merged frame a's levelled frame
        truth = np.linalg.inv(WORLD["a"]) @ raw[x]
        assert np.allclose(T, truth, atol=1e-6), x
    # b levels its map anew (as upright, turned 30 deg): links taken before stay right
    m.set_level("b", Rotation.from_euler("z", 30, degrees=True).as_matrix() @ lean["b"])
    m.update()
    for x, T in m.raw_poses().items():
        assert np.allclose(T, np.linalg.inv(WORLD["a"]) @ raw[x], atol=1e-6), x


def test_the_anchor_is_the_largest_group_not_a_lone_low_id():
    result = merge([true_link("c", "b"), true_link("d", "c")], agents=["a", "b", "c", "d"])
    assert result.anchor == "b" and result.attached == ["b", "c", "d"]
    assert ["a"] in result.groups


def test_an_agent_two_equally_backed_paths_place_apart_waits_unattached():
    """b and d agree on a wrong link (a slide by one room width), c and d on the right one, and
    no link of a reaches d: nothing but the order would decide, so d is attached by neither
    until a's link settles it."""
    slide = yaw_transform(0.0, (4.04, 0.0, 0.0))
    base = [true_link(s, d) for s, d in itertools.permutations("abc", 2)]
    b_d = [Link("b", "d", slide @ true_link("b", "d").T, 0.99),
           Link("d", "b", invert_transform(slide @ true_link("b", "d").T), 0.99)]
    c_d = [true_link("c", "d"), true_link("d", "c")]
    for confidence in (0.5, 0.999):      # whichever is the more confident, neither wins
        result = merge(base + b_d + [Link(l.src, l.dst, l.T, confidence) for l in c_d])
        assert result.attached == ["a", "b", "c"] and "d" not in result.poses
        contested = {l.key for l, why in result.rejected if why.startswith("contested")}
        assert contested == {("b", "d"), ("d", "b"), ("c", "d"), ("d", "c")}
        assert contested <= result.disputed
        assert_poses(result)
    settled = merge(base + b_d + c_d + [true_link("a", "d")])
    assert settled.attached == ["a", "b", "c", "d"]
    assert {l.key for l, _ in settled.rejected} == {("b", "d"), ("d", "b")}
    assert_poses(settled)


def test_one_wrong_link_in_a_ring_of_weak_links_leaves_the_rest_attached():
    """A ring a-b-c-d-e measured one way each (no pair agreement, no triangle) and a wrong,
    less confident a -> e: the cycle cannot single out one link, so the order of confidence
    stands and the wrong link alone is rejected (nothing is contested)."""
    ring = [Link(s_, d, true_link(s_, d).T, 0.9) for s_, d in ("ab", "bc", "cd", "de")]
    wrong = Link("a", "e", yaw_transform(0.3, (2.0, 0.0, 0.0)) @ true_link("a", "e").T, 0.5)
    result = merge(ring + [wrong])
    assert result.attached == ["a", "b", "c", "d", "e"]
    assert [(l.key, why.startswith("breaks")) for l, why in result.rejected] == [(("a", "e"), True)]
    assert_poses(result)


def test_a_withheld_link_does_not_push_out_the_links_that_placed_the_frame():
    """Right a -> c and c -> b place b; a's wrong a -> b (as sure, measured one way: no link
    closes a cycle) is withheld by a as disputed_by_cycles, and kept so the cycles can re-judge
    it. Ordered by name, ('a', 'b') came first: it was accepted, c's right link rejected, the
    merged frame then agreed with it, and a published it as verified. A withheld link now
    comes after the published ones as well backed and as sure: it stays rejected and
    disputed, however often it is taken again."""
    from sgreg_core.runtime.merge import Merger

    m = Merger(MergeConfig(), "a")
    for s_, d in ("ac", "cb"):
        m.take(s_, d, true_link(s_, d).T, True, "ok", "confirmed", 0.9, S)
    m.update()
    wrong = yaw_transform(np.radians(25.0), (3.0, 0.0, 0.0)) @ true_link("a", "b").T
    for k in range(3):
        m.take("a", "b", wrong, False, "disputed_by_cycles", "confirmed", 0.9, (2 + k) * S)
        m.update()
        assert sorted(l.key for l in m.result.accepted) == [("a", "c"), ("c", "b")]
        assert "b" in m.disputed_peers()
    assert_poses(m.result)


def test_an_agent_whose_links_two_others_contradict_as_strongly_waits_unattached():
    """b's two links share one wrong 4 m slide (b misplaced itself), a -> b and c -> b are right,
    a and c agree. {a -> b, c -> b, a - c} and {b -> a, b -> c, a - c} each close a consistent
    triangle: every disagreeing pair is as well backed on both sides. Ordered by confidence, a
    surer b was placed 4 m off and a's and c's right links were disputed; now b waits."""
    slide = yaw_transform(0.0, (4.0, 0.0, 0.0))
    right = [Link(s_, d, true_link(s_, d).T, 0.95) for s_, d in ("ab", "cb", "ac", "ca")]
    wrong = [Link("b", d, true_link("b", d).T @ slide, 0.99) for d in "ac"]
    result = merge(right + wrong)
    assert result.attached == ["a", "c"] and sorted(l.key for l in result.accepted) == [("a", "c"), ("c", "a")]
    assert all(why.startswith("contested") for _, why in result.rejected) and len(result.rejected) == 4
    assert_poses(result)
    # one more agent's word settles it: d agrees with a and c about b
    settled = merge(right + wrong + [Link(s_, d, true_link(s_, d).T, 0.95) for s_, d in ("db", "da", "ad")])
    assert "b" in settled.attached and ("b", "a") in [l.key for l, _ in settled.rejected]
    assert_poses(settled)


def test_peers_placed_through_a_triangle_are_placed_by_others():
    from sgreg_core.runtime.merge import Merger

    m = Merger(MergeConfig(), "a")
    m.take("b", "c", true_link("b", "c").T, True, "ok", "confirmed", 0.9, 1 * S)
    m.take("a", "b", true_link("a", "b").T, True, "ok", "confirmed", 0.9, 1 * S)
    m.update()
    assert m.settled_peers() == {"b", "c"} and m.placed_by_others() == set()   # a chain: bridges
    m.take("a", "c", true_link("a", "c").T, True, "ok", "confirmed", 0.9, 3 * S)
    m.update()
    assert m.placed_by_others() == {"b", "c"}


def test_a_link_that_is_no_rigid_transform_or_has_no_confidence_is_not_taken():
    """A NaN transform or confidence attached both agents with NaN poses (every pose averaged
    with it); a 3x3 "transform" or levelling raised."""
    from sgreg_core.runtime.merge import Merger

    m = Merger(MergeConfig(), "a")
    good = true_link("a", "b")
    assert m.take("a", "b", good.T, True, "ok", "confirmed", 0.9, 1 * S)
    assert not m.take("b", "c", np.full((4, 4), np.nan), True, "ok", "confirmed", 0.9, 1 * S)
    assert not m.take("b", "c", true_link("b", "c").T, True, "ok", "confirmed", float("nan"), 1 * S)
    assert not m.take("b", "c", np.eye(3), True, "ok", "confirmed", 0.9, 1 * S)
    assert not m.set_level("b", np.eye(4)) and not m.set_level("b", np.diag([1.0, 1.0, -1.0]))
    m.update()
    assert set(m.result.poses) == {"a", "b"} and "c" not in m.result.attached
    assert all(np.isfinite(T).all() for T in m.result.poses.values())


def test_a_link_to_itself_one_beyond_any_map_or_a_levelling_on_its_side_is_not_taken():
    """Checks the ROS layer makes, in the core for its other callers: a self-link gathered
    triangle support and counted its agent as checked; a 1e308 m translation made NaN poses."""
    from sgreg_core.runtime.merge import Merger

    m = Merger(MergeConfig(), "a")
    assert m.take("a", "b", true_link("a", "b").T, True, "ok", "confirmed", 0.9, 1 * S)
    assert not m.take("b", "b", np.eye(4), True, "ok", "confirmed", 0.9, 1 * S)
    far = true_link("b", "c").T.copy()
    far[0, 3] = 1e308
    assert not m.take("b", "c", far, True, "ok", "confirmed", 0.9, 1 * S)
    tilted = np.array([[1.0, 0, 0], [0, 0, -1], [0, 1, 0]])    # 90 deg about x
    assert not m.set_level("b", tilted)
    m.update()
    assert set(m.result.poses) == {"a", "b"} and m.result.checked == set()
    assert all(np.isfinite(T).all() for T in m.result.poses.values())


def test_the_merged_frame_expects_a_pose_only_where_other_agents_links_join_the_pair():
    """In a chain a - b - c, a's own link is all that places b for a: no expectation (a's new
    estimate of b was withheld as disputed_by_cycles with no cycle). Closing the triangle
    through c makes one."""
    from sgreg_core.runtime.merge import Merger

    m = Merger(MergeConfig(), "a")
    for s_, d in ("ab", "bc"):
        m.take(s_, d, true_link(s_, d).T, True, "ok", "confirmed", 0.9, 1 * S)
    m.update()
    assert m.result.attached == ["a", "b", "c"] and m.expected("b") is None
    m.take("c", "a", true_link("c", "a").T, True, "ok", "confirmed", 0.9, 2 * S)
    m.take("d", "e", true_link("d", "e").T, True, "ok", "confirmed", 0.9, 2 * S)   # a group of its own
    m.update()
    assert m.result.attached == ["a", "b", "c"]
    T = m.expected("b")
    assert T is not None and np.allclose(T, true_link("a", "b").T, atol=1e-6)
    assert m.expected("d") is None


def test_poses_are_averaged_to_a_fixed_point_in_yaw_too():
    """The averaging stopped when no translation moved, though yaws still did: with maps whose
    origins coincide, after one sweep."""
    world = {k: yaw_transform(y, (0.0, 0.0, 0.0)) for k, y in zip("abcd", (0.0, 0.5, 1.0, 1.5))}
    rng = np.random.default_rng(0)
    links = [Link(s_, d, yaw_transform(rng.normal(0, np.radians(2)), (0, 0, 0))
                  @ invert_transform(world[d]) @ world[s_], 0.9) for s_, d in itertools.permutations("abcd", 2)]
    r = merge(links, cfg=MergeConfig(average_iters=200))
    for x in "bcd":     # each pose is the weighted circular mean of what its links say
        says = [to_4dof(r.poses[l.dst if l.src == x else l.src] @ l.towards(l.dst if l.src == x else l.src))[0]
                for l in r.accepted if x in l.key]
        mean = np.arctan2(np.mean(np.sin(says)), np.mean(np.cos(says)))
        assert abs(np.degrees(mean - to_4dof(r.poses[x])[0])) < 1e-3, x


def test_a_peer_gone_silent_is_forgotten_by_the_merger():
    """An agent's node stops listening to a silent peer; its merger kept the peer's last links
    (on /tf for good, links never age by default) and refused every later result about it."""
    from sgreg_core.runtime.merge import Merger

    m = Merger(MergeConfig(), "a")
    for s_, d in ("ab", "bc", "ca"):
        m.take(s_, d, true_link(s_, d).T, True, "ok", "confirmed", 0.9, 1 * S)
    m.update()
    assert m.result.attached == ["a", "b", "c"]
    m.forget("c")
    m.update()
    assert m.result.attached == ["a", "b"] and not any("c" in l.key for l in m.links.current())
    assert "c" not in m.links.agents


def test_both_links_of_a_pair_get_the_same_answer_whatever_the_names():
    """Two measurements of one pair, 20 m apart and 3 deg off each other: compared in one
    agent's frame only, the lever arm made one link agree and the other not, and the names'
    order decided whether the pair attached."""
    from sgreg_core.runtime.merge import _support

    X = yaw_transform(0.4, (20.0, 0.0, 0.0))
    T_qp = invert_transform(X) @ yaw_transform(np.radians(3.0), (0.0, 0.0, 0.0))
    outcomes = []
    for p, q in (("a", "b"), ("b", "a")):
        pair, _ = _support([Link(p, q, X), Link(q, p, T_qp)], MergeConfig())
        assert len(set(pair.values())) == 1, pair
        outcomes.append(merge([Link(p, q, X, 0.9), Link(q, p, T_qp, 0.9)]).attached)
    assert outcomes[0] == outcomes[1]


@pytest.mark.parametrize("noise", [0.0, 2.0])
def test_the_forest_gives_every_path_transform_and_its_links(noise):
    """_Forest: after links join trees in any order, path_T(a, b) is the pair's own link where
    it has one, else the product along the forest (the smaller tree re-posed into the larger's
    root): T_a^b for exact links, None across trees; path_links walks the links of that
    product (with noisy links another path would give another product)."""
    from sgreg_core.runtime.merge import _Forest
    rng = np.random.default_rng(5)
    names = sorted(WORLD)
    for _ in range(20):
        forest = _Forest(names)
        pairs = list(itertools.permutations(names, 2))
        for i in rng.permutation(len(pairs))[:7]:
            forest.add(true_link(*pairs[i], noise=noise, rng=rng))
        for a, b in pairs:
            T = forest.path_T(a, b)
            if forest.root[a] != forest.root[b]:
                assert T is None
                continue
            if noise == 0.0:
                assert np.allclose(T, invert_transform(WORLD[b]) @ WORLD[a], atol=1e-9)
            if b in forest.graph[a]:
                assert np.allclose(T, forest.graph[a][b].towards(b))
                continue
            at, composed = a, np.eye(4)
            for l in forest.path_links(a, b):
                assert at in l.key
                nxt = l.dst if l.src == at else l.src
                composed, at = l.towards(nxt) @ composed, nxt
            assert at == b and np.allclose(composed, T, atol=1e-9)
