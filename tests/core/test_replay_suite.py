"""Replay suite files: expansion into bags, their tags, one-line refusals, and the summary."""
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from sgreg_cli.commands.make_bag import BagSpec

from sgreg_core.bench.replay_suite import (BagJob, PeersWord, ResultCache, Suite, SuiteError, format_summary,
                                           load_suite, missed, out_of_reach, summarize)

SUITES = Path(__file__).resolve().parents[2] / "config" / "suites"


def write(tmp_path, text):
    (tmp_path / "data" / "scans" / "x_scene0007_00").mkdir(parents=True, exist_ok=True)
    (tmp_path / "data" / "scans" / "x_scene0007_01").mkdir(parents=True, exist_ok=True)
    p = tmp_path / "suite.yaml"
    p.write_text(text)
    return p


SUITE = """
name: t
data: data
bag_dir: made
held_out: [scene0007]
seeds: [1, 2]
defaults: {voxel: 0.05}
walks:
  slow: {speed: 0.2, opposite: true}
  fast: {speed: 0.5, opposite: false}
scans:
  - scan: scans/x_scene0007_00
  - {scan: scans/x_scene0007_00, scan_b: scans/x_scene0007_01, gt: gt.json}
  - synth: {kind: office, rooms: 2, seed: 3}
"""


def test_every_scan_is_made_per_walk_and_seed(tmp_path):
    suite = load_suite(write(tmp_path, SUITE))
    assert len(suite.jobs) == 3 * 2 * 2
    names = {j.name for j in suite.jobs}
    assert "scene0007_00_slow_s1" in names and "scene0007_00x01_fast_s2" in names
    cross = [j for j in suite.jobs if j.capture == "cross"]
    assert len(cross) == 4 and all(j.spec["gt"].endswith("data/gt.json") for j in cross)
    job = next(j for j in suite.jobs if j.name == "scene0007_00_fast_s2")
    assert job.spec == {"voxel": 0.05, "speed": 0.5, "opposite": False, "seed": 2,
                        "scan": str((tmp_path / "data/scans/x_scene0007_00").resolve())}
    assert job.path == (tmp_path / "made" / job.name).resolve() and job.room == "scene0007"
    synth = [j for j in suite.jobs if j.capture == "synthetic"]
    assert len(synth) == 4 and synth[0].synth == {"kind": "office", "rooms": 2, "seed": 3}


@pytest.mark.parametrize("text,words", [
    ("name: t\nscans:\n  - scan: scans/nope\n", "not found"),
    ("name: t\nscans:\n  - {nothing: 1}\n", "needs 'scan' or 'synth'"),
    ("name: t\nwhatever: 1\n", "unknown keys"),
    ("name: t\n", "names no bags"),
    ("[1, 2", "cannot read"),
    # a misspelt held-out room would quietly be counted as a training one
    ("name: t\ndata: data\nheld_out: [scene0070]\nscans:\n  - scan: scans/x_scene0007_00\n",
     r"held_out names no room of the suite: scene0070 \(its rooms: scene0007\)"),
])
def test_bad_suites_are_refused_in_one_line(tmp_path, text, words):
    with pytest.raises(SuiteError, match=words):
        load_suite(write(tmp_path, text))


@pytest.mark.parametrize("text,words", [
    ("data: 5\nscans: [{scan: s}]\n", "data must be a string"),
    ("bags: [5]\n", "bags must be a list, each a string"),
    ("seeds: 3\nscans: [{synth: {}}]\n", "seeds must be a list"),
    ("seeds: [abc]\nscans: [{synth: {}}]\n", "seeds must be a list, each an integer"),
    ("held_out: 5\nscans: [{synth: {}}]\n", "held_out must be a list"),
    ("walks: [a, b]\nscans: [{synth: {}}]\n", "walks must be a mapping"),
    ("defaults: [1]\nscans: [{synth: {}}]\n", "defaults must be a mapping"),
    ("scans: [5]\n", "scans must be a list, each a mapping"),
    ("scans: [{synth: 5}]\n", r"scans\[0\]: synth must be a mapping"),
    ("scans: [{synth: null}]\n", r"scans\[0\]: synth must be a mapping"),
    ("scans: [{synth: {roomz: 2}}]\n", r"scans\[0\]: synth: unknown keys \['roomz'\]"),
    ("scans: [{synth: {rooms: two}}]\n", r"synth: rooms must be an integer, got 'two'"),
    ("scans: [{synth: {seed: 1.5}}]\n", r"synth: seed must be an integer"),
    ("scans: [{synth: {noise: {drop: x}}}]\n", r"synth: noise: drop must be a finite number"),
    ("defaults: {speeed: 1}\nscans: [{synth: {}}]\n", r"defaults: unknown keys \['speeed'\]"),
    ("defaults: {speed: fast}\nscans: [{synth: {}}]\n", "defaults: speed must be a finite number, got 'fast'"),
    ("walks: {w: {opposite: 1}}\nscans: [{synth: {}}]\n", "walks: w: opposite must be true or false"),
    ("scans: [{synth: {}, start_a: [1]}]\n", r"scans\[0\]: start_a must be a list of 2"),
    ("scans: [{scan: 5}]\n", r"scans\[0\]: scan must be a string"),
    # ranges too, for every bag before any is made (here the second walk's)
    ("walks: {ok: {speed: 0.5}, bad: {speed: 0}}\nscans: [{synth: {}}]\n",
     r"synth_apartment1_0_bad_s0: speed \(--speed\) must be a number in"),
])
def test_values_of_the_wrong_type_and_unknown_keys_are_refused_by_name(tmp_path, text, words):
    with pytest.raises(SuiteError, match=words):
        load_suite(write(tmp_path, text), bag_spec=BagSpec)


def test_every_synth_setting_names_the_scene(tmp_path):
    """A setting other than kind, rooms and seed makes another scene, bag and cache key; the
    shipped suites, which set none, keep their names; the room stays the one held_out names."""
    def jobs(synth):
        return load_suite(write(tmp_path, f"scans: [{{synth: {synth}}}]\n"), bag_spec=BagSpec).jobs

    plain = jobs("{kind: office, rooms: 2, seed: 3}")[0]
    assert plain.name == "synth_office2_3_default_s0" and plain.spec["scan"].endswith("scenes/synth_office2_3")
    assert jobs("{kind: office, rooms: 2, seed: 3, density: 650}")[0].name == plain.name   # the default
    sparse, dense = jobs("{kind: office, rooms: 2, seed: 3, density: 200}")[0], \
        jobs("{kind: office, rooms: 2, seed: 3, density: 1000}")[0]
    noisy = jobs("{kind: office, rooms: 2, seed: 3, noise: {drop: 0.1}}")[0]
    assert len({plain.name, sparse.name, dense.name, noisy.name}) == 4
    assert len({j.spec["scan"] for j in (plain, sparse, dense, noisy)}) == 4
    assert {j.room for j in (plain, sparse, dense, noisy)} == {"synth_office2_3"}
    assert sparse.name.startswith("synth_office2_3_") and sparse.synth["density"] == 200
    # YAML's 1000 and 1000.0 are one setting: one scene folder and bag, not two
    same = jobs("{kind: office, rooms: 2, seed: 3, density: 1000.0}")[0]
    assert (same.name, same.spec["scan"]) == (dense.name, dense.spec["scan"])


def test_shipped_suites_keep_their_bag_names():
    for path in sorted(SUITES.glob("*.yaml")):
        if "data:" in path.read_text():
            continue                  # the real suite needs ../shared/data
        suite = load_suite(path, bag_spec=BagSpec)
        synth = [j for j in suite.jobs if j.synth is not None]
        assert synth and all(j.name == f"{j.room}_{j.walk}_s{j.seed}" for j in synth), path
        assert all(j.spec["scan"].endswith(f"scenes/{j.room}") for j in synth), path


def frame(correct, verified, registrable, confidence):
    return {"correct": correct, "verified": verified, "success": correct and verified,
            "registrable": registrable, "confidence": confidence}


def report(frames, wrong, links):
    return {"frames": frames, "wrong_verified": wrong, "links": links, "kb_per_query_frame": None,
            "coarse_latency_ms": {"median": 10.0}, "dense_latency_ms": {"median": 50.0}}


def test_summary_pools_frames_and_reports_held_out_rooms_apart(tmp_path):
    suite = load_suite(write(tmp_path, SUITE))
    held, seen = suite.jobs[0].name, suite.jobs[-1].name       # scene0007 and a synthetic one
    results = {
        held: report([frame(True, True, True, 0.9), frame(False, False, True, 0.2),
                      frame(False, False, False, 0.1)], 0,
                     {"a->b": {"first_registrable_s": 1.0, "first_success_s": 3.0, "time_to_success_s": 2.0}}),
        seen: report([frame(True, True, True, 0.9), frame(False, True, True, 0.8)], 1,
                     {"a->b": {"first_registrable_s": 2.0, "first_success_s": None, "time_to_success_s": None}}),
    }
    s = summarize(results, suite)
    assert s["rows"]["all"]["registrable_frames"] == 4
    assert s["rows"]["all"]["success_rate_registrable"] == 0.5
    assert s["rows"]["all"]["wrong_verified"] == 1 and s["rows"]["all"]["links_never_registered"] == 1
    assert s["rows"]["held-out rooms (scene0007)"]["success_rate_registrable"] == 0.5
    assert s["rows"]["held-out rooms (scene0007)"]["median_time_to_success_s"] == 2.0
    assert s["rows"]["rooms seen in training"]["wrong_verified"] == 1
    # generated scenes held out of tuning (not of the network's training) say so
    synth_held = load_suite(write(tmp_path, SUITE.replace("held_out: [scene0007]",
                                                          f"held_out: [{suite.jobs[-1].room}]")))
    rows = summarize(results, synth_held)["rows"]
    assert rows["the other scenes"]["registrable_frames"] == 2 and "rooms seen in training" not in rows
    only_held = summarize({held: results[held]}, suite)["rows"]     # sgreg bench-replay --only
    assert list(only_held)[:2] == ["all", "held-out rooms (scene0007)"]
    assert "rooms seen in training" not in only_held
    assert s["rows"]["all"]["dense_requests"] is None      # no bag reports counters
    # of the two registrable misses, the wrong estimate verified is wrong_verified, not a miss
    assert s["rows"]["all"]["missed"] == {"wrong_estimate": {"unknown": 1}, "right_refused": {},
                                          "right_held": {}}


def test_latencies_are_medians_of_the_pooled_frames_not_of_each_bags_median():
    from sgreg_core.bench.replay_suite import _row

    def timed(mode, ms):
        return {**frame(True, True, True, 0.9), "mode": mode, "total_ms": ms}
    busy = report([timed("coarse", 10.0)] * 3 + [timed("dense", 60.0)] * 3, 0, {})
    slow = report([timed("merged", 100.0), timed("dense", 300.0)], 0, {})
    row = _row([busy, slow])
    assert row["coarse_latency_ms"] == 10.0 and row["dense_latency_ms"] == 60.0


def test_kb_per_frame_is_the_bytes_of_every_bag_over_its_frames():
    """Not a median of per-bag ratios: a short bag's heavy frames weigh as many frames as it has;
    bags replayed without metering (offline) are left out."""
    from sgreg_core.bench.replay_suite import _row

    def metered(n_frames, n_bytes):
        r = report([frame(True, True, True, 0.9)] * n_frames, 0, {})
        return {**r, "query_frames": n_frames, "bytes_per_topic": {"/a/sgreg/coarse": n_bytes}}

    rows = [metered(1, 9000), metered(9, 9000), metered(90, 90000)]
    assert _row(rows)["kb_per_query_frame"] == 108.0 / 100         # the median ratio says 1.0
    assert _row(rows + [report([frame(True, True, True, 0.9)], 0, {})])["kb_per_query_frame"] == 1.08
    assert _row([report([frame(True, True, True, 0.9)], 0, {})])["kb_per_query_frame"] is None


def test_misses_tell_the_estimator_from_the_verdict_and_the_runtime_rules():
    def f(correct, reason, registrable=True):
        return {**frame(correct, reason == "ok", registrable, 0.5), "reason": reason}

    frames = [f(True, "ok"), f(False, "too_few_inliers"), f(False, "too_few_inliers"),
              f(True, "low_confidence"), f(True, "awaiting_confirmation"), f(True, "disputed_by_cycles"),
              f(True, "no_peer_cloud_to_verify"), f(False, "awaiting_confirmation"),
              f(False, "ok"), f(True, "low_confidence", registrable=False)]
    assert missed(frames) == {
        "wrong_estimate": {"too_few_inliers": 2, "awaiting_confirmation": 1},
        "right_refused": {"low_confidence": 1},
        "right_held": {"awaiting_confirmation": 1, "disputed_by_cycles": 1, "no_peer_cloud_to_verify": 1}}
    suite = Suite("t", Path("t.yaml"), [BagJob("b", Path("b"))])
    text = format_summary(summarize({"b": report(frames, 1, {})}, suite))
    assert ("registrable frames not verified:\n"
            "  wrong estimate: 3 (too_few_inliers 2, awaiting_confirmation 1)\n"
            "  right, refused by the verdict: 1 (low_confidence 1)\n"
            "  right, held by the runtime's rules: 3 (awaiting_confirmation 1, disputed_by_cycles 1, "
            "no_peer_cloud_to_verify 1)") in text


def test_the_suite_plot_draws_each_bags_frames_by_outcome(tmp_path, monkeypatch):
    """The stacked bars add up to each bag's registrable frames, wrong verified ones included."""
    import matplotlib.axes

    from sgreg_core.plots.replay import plot_suite

    def f(correct, reason, verified=False):
        return {**frame(correct, verified, True, 0.5), "reason": reason}

    frames = [f(True, "ok", True), f(True, "low_confidence"), f(True, "awaiting_confirmation"),
              f(False, "too_few_inliers"), f(False, "ok", True)]
    suite = Suite("t", Path("t.yaml"), [BagJob("b", Path("b"))])
    summary = summarize({"b": report(frames, 1, {})}, suite)
    drawn = []
    barh = matplotlib.axes.Axes.barh

    def recording(self, y, width, *args, **kwargs):
        if "left" in kwargs:
            drawn.append((kwargs["label"], float(np.asarray(width)[0])))
        return barh(self, y, width, *args, **kwargs)

    monkeypatch.setattr(matplotlib.axes.Axes, "barh", recording)
    plot_suite(summary, tmp_path / "s.png")
    assert (tmp_path / "s.png").stat().st_size > 10_000
    assert [w for _, w in drawn] == [20.0] * 5 and drawn[-1][0] == "wrong, verified"


def test_the_suite_plot_tells_a_bag_with_nothing_to_register_from_one_never_registered(tmp_path,
                                                                                      monkeypatch):
    import matplotlib.axes

    from sgreg_core.plots.replay import plot_suite

    never = [frame(False, False, True, 0.1)]
    nothing = [frame(False, False, False, 0.1)]
    suite = Suite("t", Path("t.yaml"), [BagJob("never", Path("n")), BagJob("nothing", Path("m"))])
    summary = summarize({"never": report(never, 0, {"a->b": {"first_registrable_s": 1.0, "first_success_s":
                                                                None, "time_to_success_s": None}}),
                         "nothing": report(nothing, 0, {})}, suite)
    said = []
    text = matplotlib.axes.Axes.text

    def recording(self, x, y, s, *args, **kwargs):
        said.append((s, round(float(y))))
        return text(self, x, y, s, *args, **kwargs)

    monkeypatch.setattr(matplotlib.axes.Axes, "text", recording)
    plot_suite(summary, tmp_path / "s.png")
    assert ("never", 0) in said and ("no registrable frame", 1) in said
    assert ("never", 1) not in said and ("no registrable frame", 0) not in said


def test_summary_adds_up_dense_requests_over_agents_and_bags(tmp_path):
    suite = load_suite(write(tmp_path, SUITE))
    one, two = suite.jobs[0].name, suite.jobs[-1].name
    results = {one: report([frame(True, True, True, 0.9)], 0, {}), two: report([], 0, {})}
    results[one]["counters"] = {"a": {"requests": 3, "request_retry": 1, "request_rate_limited": 2},
                                "b": {"requests": 4, "request_over_budget": 1, "verified": 9}}
    results[two]["counters"] = {"a": {"requests": 1, "request_gave_up": 1}}
    s = summarize(results, suite)
    assert s["rows"]["all"]["dense_requests"] == {"sent": 8, "retried": 1, "gave_up": 1,
                                                  "refused_within_interval": 2, "refused_over_budget": 1}
    assert s["bags"][two]["dense_requests"]["sent"] == 1
    assert "dense requests: 8 sent, 1 retried, 1 given up" in format_summary(s)


def test_results_are_reused_only_under_their_key_and_never_with_another_fleet(tmp_path):
    cache = ResultCache(tmp_path / "bags")
    cache.save("a", {"query_frames": 3}, "k1")
    assert cache.load("a", "k1") == {"query_frames": 3, "cache_key": "k1"}
    assert cache.load("a", "k2") is None and cache.load("b", "k1") is None
    # a result another fleet took part in is kept for reading, never for the next run
    cache.save("a", {"query_frames": 4, "foreign": {"publishers": ["/a/mapping/instances"]}}, "k1")
    assert '"query_frames": 4' in cache.path("a").read_text()
    assert cache.load("a", "k1") is None
    cache.path("c").write_text("{not json")
    assert cache.load("c", "k1") is None


def test_other_walk_seeds_make_other_bags_of_the_same_scans(tmp_path):
    path = write(tmp_path, SUITE + "bags:\n  - shipped_bag\n")
    assert [j.name for j in load_suite(path).jobs].count("shipped_bag") == 1
    suite = load_suite(path, seeds=[7])
    assert len(suite.jobs) == 3 * 2 and {j.seed for j in suite.jobs} == {7}    # no shipped bag
    assert all(j.name.endswith("_s7") and j.spec["seed"] == 7 for j in suite.jobs)


def test_a_bag_rerecorded_under_the_same_name_is_not_taken_for_the_cached_one(tmp_path):
    """The cache key's bag digest covers the messages, not only the ground truth and counts."""
    from sgreg_cli.commands.bench_replay import _bag_digest

    for name, data in (("ground_truth.json", b"{}"), ("metadata.yaml", b"count: 3"),
                       ("b.mcap", bytes(range(256)) * 64)):
        (tmp_path / name).write_bytes(data)
    before = _bag_digest(tmp_path)
    assert _bag_digest(tmp_path) == before
    with open(tmp_path / "b.mcap", "r+b") as f:
        f.seek(1000)
        f.write(b"\xff" * 8)
    assert _bag_digest(tmp_path) != before


def test_frames_out_of_reach_of_the_link_rules_come_before_an_estimate_a_rule_could_publish():
    """A pair's first link rests on an estimate that passed the verdict (near enough the truth to
    agree with a right one); a direction may then publish right from its own first right
    estimate that passed, or that the verdict refused for its confidence alone at no less than
    the confidence the peer's word vouches for; every later frame is within reach (a link by
    then would have made it from its kept pairs). Wrong or otherwise refused estimates open
    nothing; frames not registrable are not counted."""
    def f(agent, t, reason, confidence=0.95, off=(0.0, 0.0), registrable=True):
        rte, rre = off
        correct = rte < 0.5 and rre < 5.0
        return {**frame(correct, reason == "ok" and correct, registrable, confidence), "agent": agent,
                "peer": "b" if agent == "a" else "a", "t": t, "reason": reason, "rte": rte, "rre": rre}

    frames = [f("a", 0.5, "ok", off=(2.0, 90.0), registrable=False),  # wrong, passed: opens nothing
              f("a", 1.0, "ambiguous"),               # right, but refused for a tie
              f("a", 2.0, "low_confidence", 0.6),     # the peer's word may vouch for it from 1.5
              f("a", 3.0, "ok"),
              f("b", 1.2, "low_confidence", 0.8),     # right, refused for its confidence, no link yet
              f("b", 1.5, "awaiting_confirmation"),   # passed the verdict: opens the pair
              f("b", 2.5, "low_confidence", 0.4)]
    word = PeersWord(vouched_min_confidence=0.5, agree_deg=3.0)
    assert out_of_reach(frames, word) == 2          # a at 1.0, b at 1.2
    assert out_of_reach(frames, replace(word, vouched_min_confidence=0.7)) == 3    # a waits for 3.0
    assert out_of_reach([fr for fr in frames if fr["agent"] == "a"], word) == 2    # a alone: its 3.0
    # the peer's word may be off by up to the agreement beyond the criterion, no further
    near = [*frames[1:5], f("b", 1.5, "ok", off=(0.3, 6.0))]
    assert out_of_reach(near, word) == 2 and out_of_reach(near, replace(word, agree_deg=0.5)) == 4
    suite = Suite("t", Path("t.yaml"), [BagJob("b", Path("b"))])
    summary = summarize({"b": report(frames, 0, {})}, suite, word)
    assert summary["rows"]["all"]["out_of_reach"] == 2 and summary["bags"]["b"]["out_of_reach"] == 2
    assert "at most 4 of 6 registrable frames (66.67 %)" in format_summary(summary)
    assert summarize({"b": report(frames, 0, {})}, suite)["rows"]["all"]["out_of_reach"] is None
