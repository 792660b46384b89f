"""Scoring of replay results against ground truth, on hand-made records."""

import numpy as np
import pytest

from sgreg_core.geometry import invert_transform, yaw_transform
from sgreg_core.bench.replay_score import ResultRecord, check_ground_truth, ground_truth, score_replay

FRAMES = {"a": yaw_transform(0.3, (1.0, 2.0, 0.0)), "b": yaw_transform(-1.2, (-4.0, 0.5, 0.2))}


def rec(t, agent, peer, T, verified, mode="coarse", ms=10.0):
    return ResultRecord(t=t, agent=agent, peer=peer, T=T, verified=verified, mode=mode, reason="ok",
                        node_matches=5, inliers=4, total_ms=ms)


def test_ground_truth_maps_agent_into_peer():
    T_ab = ground_truth(FRAMES, "a", "b")
    p_scene = np.array([0.3, -2.0, 1.0, 1.0])
    p_a = invert_transform(FRAMES["a"]) @ p_scene
    p_b = invert_transform(FRAMES["b"]) @ p_scene
    assert np.allclose(T_ab @ p_a, p_b)
    assert np.allclose(ground_truth(FRAMES, "b", "a"), invert_transform(T_ab))


def test_success_rate_counts_verified_correct_frames_only():
    gt = ground_truth(FRAMES, "a", "b")
    off = gt.copy()
    off[0, 3] += 0.8                                   # 0.8 m off: fails RTE < 0.5
    slightly = gt.copy()
    slightly[1, 3] += 0.3                              # within tolerance
    records = [rec(1.0, "a", "b", np.eye(4), False),          # no estimate worth the name
               rec(2.0, "a", "b", slightly, False),           # right but not verified
               rec(3.0, "a", "b", gt, True, "dense", 120.0),  # success
               rec(4.0, "a", "b", off, True),                 # wrong and verified
               rec(5.0, "b", "a", invert_transform(gt), True, "merged", 14.0)]
    s = score_replay(records, FRAMES)
    assert s.query_frames == 5
    assert s.success_rate == 2 / 5
    assert s.success_rate_any == 3 / 5
    assert s.wrong_verified == 1 and s.verified == 3
    assert s.first_success_s == 3.0
    assert s.dense_latency_ms["n"] == 1 and s.dense_latency_ms["median"] == 120.0
    assert s.coarse_latency_ms["n"] == 4


def test_empty_replay():
    s = score_replay([], FRAMES)
    assert s.query_frames == 0 and s.success_rate == 0.0 and s.first_success_s is None


def test_registrable_frames_and_time_to_first_success():
    gt = ground_truth(FRAMES, "a", "b")
    # a holds objects 1-5 from t=0; b holds 7, 8 at first and 1, 2, 3 from bag time 4
    objects = {"a": [[0.0, [1, 2, 3, 4, 5]]], "b": [[0.0, [7, 8]], [4.0, [1, 2, 3, 7, 8]]]}
    records = [rec(t, "a", "b", gt if t >= 6 else np.eye(4), t >= 6) for t in (1.0, 3.0, 5.0, 6.0, 7.0)]
    for r in records:
        r.bag_t = r.t - 0.5            # frames fall half a second after the bag's clock
    s = score_replay(records, FRAMES, objects)
    assert [f.shared_objects for f in s.frames] == [0, 0, 3, 3, 3]
    assert s.registrable_frames == 3 and s.success_rate_registrable == 2 / 3
    link = s.links["a->b"]
    assert link["first_registrable_s"] == 5.0 and link["first_success_s"] == 6.0
    # from bag time 4, when b's map first shared 3 objects, to the success at bag time 5.5: the
    # link's silence before its first registrable frame counts
    assert link["registrable_since_bag_s"] == 4.0 and link["time_to_success_s"] == 1.5
    assert score_replay(records, FRAMES).registrable_frames is None     # bags without objects
    # registrable only after the link's last result: nothing was asked of it
    late = {"a": objects["a"], "b": [[0.0, [7, 8]], [9.0, [1, 2, 3]]]}
    assert score_replay(records, FRAMES, late).links["a->b"]["registrable_since_bag_s"] is None


def test_a_link_that_never_published_counts_as_never_registered():
    """b never published a result for a although both maps shared objects from bag time 4: the
    link is scored (and a suite row counts it never registered), not left out of the totals."""
    from sgreg_core.bench.replay_suite import _row

    gt = ground_truth(FRAMES, "a", "b")
    objects = {"a": [[0.0, [1, 2, 3, 4, 5]]], "b": [[0.0, [7, 8]], [4.0, [1, 2, 3, 7, 8]]]}
    records = [rec(t, "a", "b", gt, True) for t in (5.0, 6.0)]
    for r in records:
        r.bag_t = r.t
    s = score_replay(records, FRAMES, objects)
    silent = s.links["b->a"]
    assert silent["results"] == 0 and silent["registrable_since_bag_s"] == 4.0
    assert silent["first_success_s"] is None and silent["time_to_success_s"] is None
    report = {"frames": [vars(f) for f in s.frames], "links": s.links, "wrong_verified": 0,
              "coarse_latency_ms": s.coarse_latency_ms, "dense_latency_ms": s.dense_latency_ms}
    assert _row([report])["links_never_registered"] == 1
    # a link that published before the maps could be registered and then fell silent is
    # charged too: registrable while the replay went on (a's results), it never answered
    early = [rec(1.0, "b", "a", invert_transform(gt), False)] + records
    for r in early:
        r.bag_t = r.t
    quiet = score_replay(early, FRAMES, objects).links["b->a"]
    assert quiet["results"] == 1 and quiet["registrable_since_bag_s"] == 4.0
    assert quiet["time_to_success_s"] is None
    # maps that never share enough objects ask nothing of either link
    apart = {"a": [[0.0, [1, 2]]], "b": [[0.0, [7, 8]]]}
    assert score_replay(records, FRAMES, apart).links["b->a"]["registrable_since_bag_s"] is None


def test_the_merge_score_ages_links_by_their_maps_stamps_as_the_nodes_do():
    """With max_link_age_s, a link ages against its pair's newest maps (the results' stamps),
    not the time results come: re-estimates of unchanged maps that fail keep it."""
    from dataclasses import replace

    from sgreg_core.bench.merge_score import merge_report
    from sgreg_core.runtime.merge import MergeConfig

    gt = ground_truth(FRAMES, "a", "b")
    records = [replace(rec(float(t), "a", "b", gt, t == 1), stamp_ns=1_000_000_000, link="confirmed",
                       reason="ok" if t == 1 else "too_few_inliers") for t in range(1, 11)]
    merged, score = merge_report(records, FRAMES, cfg=MergeConfig(max_link_age_s=3.0))
    assert merged.attached == ["a", "b"] and score["links_kept"] == 1
    assert score["max_pose_error_m"] < 0.5
    # nothing verified: only the anchor is placed, and no pose error was measured (not 0 m)
    _, score = merge_report([replace(r, verified=False, link="none") for r in records], FRAMES)
    assert score["attached"] == 1 and score["max_pose_error_m"] is None, score


def test_merge_timeline_counts_the_seconds_a_wrong_link_held_the_merged_frame():
    """A wrong verified link of a -> b from t=2 until b's result at t=5 says the link is gone
    (contradicted, link "none"), then a right one: the merged frame was wrong at t=2, 3, 4."""
    from dataclasses import replace

    from sgreg_core.bench.merge_score import merge_report

    def merge_timeline(records, frames):
        return merge_report(records, frames)[1]["while_replayed"]

    gt = ground_truth(FRAMES, "a", "b")
    off = gt.copy()
    off[0, 3] += 3.8                                   # one identical room over
    records = [rec(1.0, "a", "b", np.eye(4), False),
               rec(2.0, "a", "b", off, True),
               rec(3.0, "a", "b", off, True, "merged"),
               replace(rec(5.0, "a", "b", gt, False, "dense"), reason="contradicted", link="none"),
               rec(6.0, "a", "b", gt, True),
               rec(8.0, "a", "b", gt, True, "merged")]
    tl = merge_timeline(records, FRAMES)
    assert tl["wrong_s"] == 3.0 and tl["wrong_windows"] == [[2.0, 5.0]], tl
    assert tl["seconds"] == 8.0
    # held for less than a second between two results: still counted, to the result that ended it
    brief = [rec(1.0, "a", "b", gt, False), rec(1.2, "a", "b", off, True),
             replace(rec(1.8, "a", "b", gt, False, "dense"), reason="contradicted", link="none"),
             rec(3.0, "a", "b", gt, True)]
    tl = merge_timeline(brief, FRAMES)
    assert np.isclose(tl["wrong_s"], 0.6) and np.allclose(tl["wrong_windows"], [[1.2, 1.8]]), tl
    # a wrong link still held at the last result counts for one merge period after it
    assert np.isclose(merge_timeline(brief[:2], FRAMES)["wrong_s"], 1.0)
    assert merge_timeline([r for r in records if r.T is not off], FRAMES)["wrong_s"] == 0.0
    assert merge_timeline([], FRAMES) == {"seconds": 0.0, "wrong_s": 0.0, "wrong_windows": []}


def gt_with(**changes):
    """A well-formed ground truth of FRAMES, with top-level entries changed (None: left out)."""
    gt = {"T_scene_map": {a: T.tolist() for a, T in FRAMES.items()}, "t_origin": 1.7e9,
          "objects": {"a": [[0.0, [1, 2]], [1.0, [1, 2, 3]]], "b": []}}
    gt.update(changes)
    return {k: v for k, v in gt.items() if v is not None}


def test_a_well_formed_ground_truth_is_taken_as_it_is():
    assert check_ground_truth(gt_with()) == gt_with()
    assert check_ground_truth(gt_with(t_origin=None, objects=None)) == gt_with(t_origin=None, objects=None)


@pytest.mark.parametrize("gt, words", [
    ([], "expected a JSON object, got list"),
    (gt_with(T_scene_map=None), "T_scene_map: expected"),
    (gt_with(T_scene_map=[]), "T_scene_map: expected"),
    (gt_with(T_scene_map={"a": np.eye(4).tolist(), "b": (2 * np.eye(4)).tolist()}), "T_scene_map of b: not a rigid"),
    (gt_with(T_scene_map={"a": "x"}), "T_scene_map of a: not a rigid"),
    (gt_with(t_origin="now"), "t_origin"),
    (gt_with(t_origin=10 ** 400), "t_origin"),
    (gt_with(objects=[1]), "objects"),
    (gt_with(objects={"a": [[0.0, [[1]]]]}), "objects"),
])
def test_a_ground_truth_scoring_cannot_read_is_refused_by_name(gt, words):
    with pytest.raises(ValueError, match=words):
        check_ground_truth(gt)
