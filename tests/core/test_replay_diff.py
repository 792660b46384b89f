"""sgreg bench-diff: two bench-replay runs of one suite compared bag by bag."""
import json
import subprocess
import sys

import pytest

from sgreg_core.bench.replay_diff import BagOutcome, compare, load_run

SGREG = [sys.executable, "-m", "sgreg_cli.main"]


def bag(verified, registrable, wrong=0, missed=None):
    return {"registrable_frames": registrable, "wrong_verified": wrong,
            "success_rate_registrable": verified / registrable if registrable else None,
            "missed": missed or {"wrong_estimate": {}, "right_refused": {}, "right_held": {}}}


def run_of(bags, **context):
    return {"suite": "s", "bags": bags, "context": {"backend": "offline", "weights_id": "w", **context}}


BEFORE = run_of({"x": bag(9, 10, missed={"right_refused": {"low_confidence": 1}}), "y": bag(3, 4),
                 "z": bag(0, 0), "gone": bag(5, 5)})
AFTER = run_of({"x": bag(10, 10), "y": bag(3, 4, wrong=2), "z": bag(0, 0), "new": bag(1, 1)},
               overrides=["peers.confirm=false"])


def test_bags_that_moved_and_the_totals_over_the_bags_both_ran():
    c = compare(BEFORE, AFTER)
    assert c.common == 3
    assert c.changed == {"x": (BagOutcome(9, 10, 0), BagOutcome(10, 10, 0)),
                         "y": (BagOutcome(3, 4, 0), BagOutcome(3, 4, 2))}
    assert c.only_before == ["gone"] and c.only_after == ["new"]
    assert c.totals == (BagOutcome(12, 14, 0), BagOutcome(13, 14, 2))     # "gone" and "new" left out
    assert c.bags_with_wrong == (0, 1) and c.new_wrong == ["y"]
    assert c.missed[0][("right_refused", "low_confidence")] == 1 and not c.missed[1]
    assert c.context == {"overrides": (None, ["peers.confirm=false"])}
    assert c.within_reach == (None, None)        # runs from before the bound was reported


def test_what_the_link_rules_could_reach_is_summed_over_the_bags_both_ran():
    """Only where both runs report it."""
    def reach(verified, registrable, out):
        return {**bag(verified, registrable), "out_of_reach": out}
    c = compare(run_of({"x": reach(8, 10, 1), "y": reach(3, 4, 0), "gone": reach(5, 5, 5)}),
                run_of({"x": reach(9, 10, 1), "y": reach(3, 4, 1)}))
    assert c.within_reach == (13, 12)
    assert compare(run_of({"x": reach(8, 10, 1)}), run_of({"x": bag(8, 10)})).within_reach == (9, None)


def test_a_wrong_merged_frame_breaks_the_rule_like_a_wrong_verified_frame():
    """A link kept in the merge but not verified can still put a map in the wrong place on /tf."""
    merged = {**bag(3, 4), "merged_wrong_s": 5.0}
    c = compare(run_of({"y": bag(3, 4)}), run_of({"y": merged}))
    assert c.new_wrong == ["y"] and c.bags_with_wrong == (0, 1)
    assert c.totals[1] == BagOutcome(3, 4, 0, 5.0)


def test_runs_of_two_suites_or_of_no_common_bag_are_refused():
    with pytest.raises(ValueError, match="two suites"):
        compare(BEFORE, {**AFTER, "suite": "other"})
    with pytest.raises(ValueError, match="share no bag"):
        compare(BEFORE, run_of({"new": bag(1, 1)}))


def test_a_folder_that_holds_no_run_is_named(tmp_path):
    with pytest.raises(ValueError, match="no bench-replay results.json"):
        load_run(tmp_path)
    (tmp_path / "results.json").write_text("{not json")
    with pytest.raises(ValueError, match="not readable JSON"):
        load_run(tmp_path)
    (tmp_path / "results.json").write_text(json.dumps({"rows": {}}))
    with pytest.raises(ValueError, match="not a bench-replay result"):
        load_run(tmp_path)


def test_the_command_prints_the_change_and_fails_on_a_new_wrong_frame_when_asked(tmp_path):
    for name, r in (("before", BEFORE), ("after", AFTER)):
        (tmp_path / name).mkdir()
        (tmp_path / name / "results.json").write_text(json.dumps(r))
    args = SGREG + ["bench-diff", str(tmp_path / "before"), str(tmp_path / "after")]
    res = subprocess.run(args + ["--json", str(tmp_path / "d.json")], capture_output=True, text=True, timeout=60)
    assert res.returncode == 0, res.stderr
    assert "85.7 % (12 of 14) -> 92.9 % (13 of 14)" in res.stdout
    assert "y" in res.stdout and "0 -> 2   0 s -> 0 s   NEW WRONG" in res.stdout and "only in before" in res.stdout
    assert "right_refused / low_confidence: 1 -> 0" in res.stdout
    d = json.loads((tmp_path / "d.json").read_text())
    assert d["totals"]["after"] == {"verified": 13, "registrable": 14, "wrong_verified": 2, "merged_wrong_s": 0.0}
    assert subprocess.run(args + ["--fail-on-new-wrong"], capture_output=True, timeout=60).returncode == 1
    swapped = subprocess.run(SGREG + ["bench-diff", str(tmp_path / "after"), str(tmp_path / "before"),
                                      "--fail-on-new-wrong"], capture_output=True, timeout=60)
    assert swapped.returncode == 0          # fewer wrong frames is no failure
    bad = subprocess.run(SGREG + ["bench-diff", str(tmp_path), str(tmp_path / "after")],
                         capture_output=True, text=True, timeout=60)
    assert bad.returncode == 2 and "Traceback" not in bad.stderr and "results.json" in bad.stderr
