"""sgreg bench-replay: a suite file of two tiny generated bags, made, replayed through real nodes,
summarised (JSON, table, PNG) and cached."""
import json
import subprocess
import sys

SGREG = [sys.executable, "-m", "sgreg_cli.main"]

SUITE = """
name: tiny
bag_dir: bags
seeds: [1, 2]
defaults: {voxel: 0.06, random_start: true}
walks:
  quick: {speed: 0.8, opposite: true}
scans:
  - synth: {kind: apartment, rooms: 1, seed: 5}
"""


def bench(suite, out, *extra):
    res = subprocess.run(SGREG + ["bench-replay", str(suite), "--out", str(out), *extra],
                         capture_output=True, text=True, timeout=600)
    assert res.returncode == 0, res.stdout[-3000:] + res.stderr[-3000:]
    return res.stdout


def test_suite_runner_makes_replays_summarises_and_caches(tmp_path):
    suite = tmp_path / "tiny.yaml"
    suite.write_text(SUITE)
    out = tmp_path / "out"
    stdout = bench(suite, out)
    summary = json.loads((out / "results.json").read_text())
    names = sorted(summary["bags"])
    assert names == ["synth_apartment1_5_quick_s1", "synth_apartment1_5_quick_s2"]
    for name in names:
        assert (tmp_path / "bags" / name / "ground_truth.json").exists()     # made on the fly
        report = json.loads((out / "bags" / f"{name}.json").read_text())
        assert report["query_frames"] > 0 and report["config"]["backend"] == "ros"
        assert report["registrable_frames"] is not None
    row = summary["rows"]["all"]
    assert row["bags"] == 2 and row["query_frames"] == sum(summary["bags"][n]["query_frames"] for n in names)
    assert row["wrong_verified"] == 0
    assert summary["reliability"]["n"] == row["query_frames"]
    assert summary["machine"]["reference_ms"]["before"] > 0 and "reference workload" in stdout
    assert (out / "summary.png").stat().st_size > 10_000
    assert json.loads((out / "config.json").read_text())["weights_id"]
    assert "success (registrable)" in stdout and "suite tiny" in stdout
    assert row["dense_requests"]["sent"] > 0 and "dense requests:" in stdout

    again = bench(suite, out)                     # nothing changed: every result is cached
    assert again.count(": cached") == 2
    # the offline backend replays the same bags in-process; --set changes its settings
    offline = bench(suite, tmp_path / "off", "--backend", "offline", "--set", "peers.confirm=false")
    assert "suite tiny" in offline and "dense requests:" in offline
    off = json.loads((tmp_path / "off" / "results.json").read_text())["rows"]["all"]["dense_requests"]
    assert off["sent"] > 0 and off["refused_over_budget"] == 0      # two agents never reach the budget
    bad = subprocess.run(SGREG + ["bench-replay", str(suite), "--set", "peers.confirm=false"],
                         capture_output=True, text=True, timeout=60)
    assert bad.returncode == 2 and "offline" in bad.stderr


def test_a_broken_suite_is_refused_in_one_line(tmp_path):
    suite = tmp_path / "bad.yaml"
    suite.write_text("name: bad\nscans:\n  - scan: nowhere/scene0001_00\n")
    res = subprocess.run(SGREG + ["bench-replay", str(suite)], capture_output=True, text=True, timeout=60)
    assert res.returncode == 2 and "not found" in res.stderr and "Traceback" not in res.stderr
