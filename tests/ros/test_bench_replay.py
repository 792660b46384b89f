"""sgreg bench-replay: a suite file of two tiny generated bags, made, replayed through real nodes,
summarised (JSON, table, PNG) and cached."""
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np

SGREG = [sys.executable, "-m", "sgreg_cli.main"]
BAGS = Path(__file__).resolve().parents[2] / "bags"

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
    # the bound any link rule meets on these estimates, with the peer's word the nodes read
    assert summary["peers_word"] == {"vouched_min_confidence": 0.5, "agree_deg": 3.0}
    assert 0 <= row["out_of_reach"] <= row["registrable_frames"] and "within reach of the link rules" in stdout

    again = bench(suite, out)                     # nothing changed: every result is cached
    assert again.count(": cached") == 2
    # the offline backend replays the same bags in-process; --set changes its settings
    lower = "peers.vouched_min_confidence=0.8"
    offline = bench(suite, tmp_path / "off", "--backend", "offline", "--set", "peers.confirm=false", "--set", lower)
    assert "suite tiny" in offline and "dense requests:" in offline
    assert json.loads((tmp_path / "off" / "results.json").read_text())["peers_word"]["vouched_min_confidence"] == 0.8
    off = json.loads((tmp_path / "off" / "results.json").read_text())["rows"]["all"]["dense_requests"]
    assert off["sent"] > 0 and off["refused_over_budget"] == 0      # two agents never reach the budget
    # a bag whose ground truth changed under the same name is replayed, not taken from the cache
    gt_file = tmp_path / "bags" / names[0] / "ground_truth.json"
    gt_file.write_text(json.dumps(json.loads(gt_file.read_text()), indent=1))
    again = bench(suite, tmp_path / "off", "--backend", "offline", "--set", "peers.confirm=false", "--set", lower)
    assert again.count(": cached") == 1 and f"{names[1]}: cached" in again
    bad = subprocess.run(SGREG + ["bench-replay", str(suite), "--set", "peers.confirm=false"],
                         capture_output=True, text=True, timeout=60)
    assert bad.returncode == 2 and "offline" in bad.stderr
    # the two runs compared bag by bag: what was run differently, the totals of both
    diff = subprocess.run(SGREG + ["bench-diff", str(out), str(tmp_path / "off"), "--json", str(tmp_path / "d.json")],
                          capture_output=True, text=True, timeout=60)
    assert diff.returncode == 0 and "backend: ros -> offline" in diff.stdout, diff.stdout + diff.stderr
    d = json.loads((tmp_path / "d.json").read_text())
    assert d["bags_in_both"] == 2 and d["totals"]["before"]["registrable"] == row["registrable_frames"]
    assert d["totals"]["before"]["wrong_verified"] == row["wrong_verified"]


def test_a_broken_suite_is_refused_in_one_line(tmp_path):
    suite = tmp_path / "bad.yaml"
    suite.write_text("name: bad\nscans:\n  - scan: nowhere/scene0001_00\n")
    res = subprocess.run(SGREG + ["bench-replay", str(suite)], capture_output=True, text=True, timeout=60)
    assert res.returncode == 2 and "not found" in res.stderr and "Traceback" not in res.stderr


TINY = """
name: tiny
bag_dir: bags
defaults: {voxel: 0.1, speed: 1.0, mapping_period: 3.0}
scans:
  - synth: {kind: apartment, rooms: 1, seed: 5, density: 150}
"""


def make_only(suite, tmp_path):
    return subprocess.run(SGREG + ["bench-replay", str(suite), "--make-only", "--out", str(tmp_path / "out")],
                          capture_output=True, text=True, timeout=300)


def test_only_a_bag_the_suite_made_is_replaced(tmp_path):
    suite = tmp_path / "tiny.yaml"
    suite.write_text(TINY)
    assert make_only(suite, tmp_path).returncode == 0
    [bag] = (tmp_path / "bags").glob("synth_*_s0")
    suite.write_text(TINY.replace("speed: 1.0", "speed: 0.8"))
    res = make_only(suite, tmp_path)
    assert res.returncode == 0 and f"replacing {bag.name}: made with other settings (speed)" in res.stdout
    assert json.loads((bag / "ground_truth.json").read_text())["config"]["speed"] == 0.8
    shutil.rmtree(bag)
    bag.mkdir()
    (bag / "notes.txt").write_text("mine")
    res = make_only(suite, tmp_path)
    assert res.returncode == 2 and f"{bag} is in the way: not a bag made by sgreg make-bag" in res.stderr
    assert "Traceback" not in res.stderr and (bag / "notes.txt").read_text() == "mine"
    # what an interrupted make-bag leaves (the ground truth is written last): a run resumes
    shutil.rmtree(bag)
    bag.mkdir()
    (bag / f"{bag.name}_0.mcap").write_bytes(b"\x89MCAP0\r\n")
    res = make_only(suite, tmp_path)
    assert res.returncode == 0 and f"replacing {bag.name}: its making was interrupted" in res.stdout
    assert (bag / "ground_truth.json").exists()
    # a recording (sgreg record names its MCAP after itself) put in a bag's place stays
    shutil.rmtree(bag)
    bag.mkdir()
    (bag / "metadata.yaml").write_text("rosbag2_bagfile_information: {}\n")
    (bag / "rec1.mcap").write_bytes(b"\x89MCAP0\r\n")
    res = make_only(suite, tmp_path)
    assert res.returncode == 2 and f"{bag} is in the way" in res.stderr and (bag / "rec1.mcap").exists()
    shutil.rmtree(bag)
    assert make_only(suite, tmp_path).returncode == 0
    # a scan regenerated in place after the bag was made: the bag describes the old one
    made = (bag / "ground_truth.json").stat().st_mtime_ns
    points = next(p for p in (tmp_path / "bags" / "scenes").glob("*/points.npy"))
    os.utime(points, ns=(made + 10**9, made + 10**9))
    res = make_only(suite, tmp_path)
    assert res.returncode == 0 and f"replacing {bag.name}: " in res.stdout, res.stdout
    assert f"{points.name} changed after the bag was made" in res.stdout
    assert (bag / "ground_truth.json").stat().st_mtime_ns > made


def test_a_subset_run_does_not_overwrite_the_summary_of_a_whole_run(tmp_path):
    suite = tmp_path / "tiny.yaml"
    suite.write_text(TINY)
    out = tmp_path / "out"
    out.mkdir()
    (out / "results.json").write_text(json.dumps({"bags": {"synth_other_s0": {}, "synth_more_s1": {}}}))
    res = subprocess.run(SGREG + ["bench-replay", str(suite), "--only", "synth", "--out", str(out),
                                  "--backend", "offline"], capture_output=True, text=True, timeout=120)
    assert res.returncode == 2 and "holds the summary of 2 bags" in res.stderr, res.stderr
    assert json.loads((out / "results.json").read_text())["bags"].keys() == {"synth_other_s0", "synth_more_s1"}


def test_a_changed_synth_setting_makes_a_new_scene_and_bag(tmp_path):
    from sgreg_core.simulation.synth import SynthConfig, generate_scene

    suite = tmp_path / "tiny.yaml"
    for density in (150, 300):
        suite.write_text(TINY.replace("density: 150", f"density: {density}"))
        assert make_only(suite, tmp_path).returncode == 0
    scenes = sorted((tmp_path / "bags" / "scenes").iterdir())
    assert len(scenes) == 2 and len(list((tmp_path / "bags").glob("synth_*_s0"))) == 2
    made = {len(np.load(s / "points.npy")) for s in scenes}
    assert made == {len(generate_scene(5, SynthConfig(density=d)).points) for d in (150, 300)}


def test_bad_suite_values_and_run_inputs_are_refused_in_one_line(tmp_path):
    (tmp_path / "a_file").write_text("not a folder")
    bad_gt = tmp_path / "bad_gt"
    shutil.copytree(BAGS / "apartment_opposite", bad_gt)
    (bad_gt / "ground_truth.json").write_text("[]")
    shipped = f"bags: [{BAGS / 'apartment_opposite'}]\n"
    bad_params = tmp_path / "bad.yaml"      # a value the nodes refuse: refused before any replay
    bad_params.write_text("/**:\n  ros__parameters:\n    vouched_min_confidence: 2.0\n")
    for text, extra, words in [
        ("defaults: {speed: fast}\nscans: [{synth: {}}]\n", [], "defaults: speed must be a finite number"),
        ("scans: [{synth: {roomz: 2}}]\n", [], "synth: unknown keys ['roomz']"),
        (f"bags: [{bad_gt}]\n", [], "bag bad_gt: "),
        (shipped, ["--params-file", str(tmp_path / "none.yaml")], "cannot read --params-file"),
        (shipped, ["--backend", "offline", "--params-file", "config/profiles/distinct_rooms.yaml"],
         "--params-file needs --backend ros"),
        (shipped, ["--params-file", str(bad_params)], "vouched_min_confidence"),
        (shipped, ["--weights", str(tmp_path / "none.safetensors")], "cannot load weights"),
        (shipped, ["--out", str(tmp_path / "a_file" / "out")], "--out: cannot create folder"),
    ]:
        suite = tmp_path / "s.yaml"
        suite.write_text(text)
        res = subprocess.run(SGREG + ["bench-replay", str(suite), "--out", str(tmp_path / "out"), *extra],
                             capture_output=True, text=True, timeout=120)
        assert res.returncode == 2 and words in res.stderr and res.stderr.count("\n") == 1, res.stderr
    # weights that cannot be loaded are said before any bag is made, not after making them all
    suite.write_text("scans: [{synth: {}}]\n")
    res = subprocess.run(SGREG + ["bench-replay", str(suite), "--out", str(tmp_path / "out"),
                                  "--weights", str(tmp_path / "none.safetensors")],
                         capture_output=True, text=True, timeout=120)
    assert res.returncode == 2 and "cannot load weights" in res.stderr
    assert not (tmp_path / "generated").exists() and "making" not in res.stdout


def test_a_synthetic_scene_whose_writing_was_interrupted_is_made_again(tmp_path, monkeypatch):
    """Not taken as made by the next run (whose bag would then fail on a scene of half its
    files): the scene is written beside its folder and renamed when whole."""
    from sgreg_cli.commands.bench_replay import _ensure_bag
    from sgreg_core.bench.replay_suite import load_suite
    from sgreg_core.maps import instance_map
    from sgreg_cli.commands.make_bag import BagSpec

    suite = tmp_path / "tiny.yaml"
    suite.write_text(SUITE.replace("seeds: [1, 2]", "seeds: [1]"))
    [job] = load_suite(suite, bag_spec=BagSpec).jobs
    write = instance_map.write_instance_map

    def cut_short(imap, path):
        Path(path).mkdir(parents=True)
        np.save(Path(path) / "points.npy", imap.points)
        raise KeyboardInterrupt

    monkeypatch.setattr(instance_map, "write_instance_map", cut_short)
    try:
        _ensure_bag(job, print)
    except KeyboardInterrupt:
        pass
    assert not Path(job.spec["scan"]).exists()
    # what an older run left when interrupted: the folder with the first array only
    Path(job.spec["scan"]).mkdir(parents=True)
    np.save(Path(job.spec["scan"]) / "points.npy", np.zeros((3, 3), np.float32))
    monkeypatch.setattr(instance_map, "write_instance_map", write)
    gt = _ensure_bag(job, print)
    assert (Path(job.spec["scan"]) / "instances.json").exists() and gt["objects"]
    assert not Path(job.spec["scan"] + ".partial").exists()
