"""The synth, graph and pairs subcommands: output, files, exit codes on bad input."""
import json

import numpy as np
import pytest

from sgreg_cli.main import main


def test_synth_graph_pairs(tmp_path, capsys):
    scan = tmp_path / "scene"
    assert main(["synth", str(scan), "--seed", "3", "--png"]) == 0
    out = capsys.readouterr().out
    assert "nodes:" in out and "edges:" in out and "labels:" in out and "points:" in out
    assert (scan / "points.npy").is_file() and (scan / "graph.png").stat().st_size > 10_000

    png = tmp_path / "g.png"
    assert main(["graph", str(scan), "--png", str(png), "--repeat", "1"]) == 0
    out = capsys.readouterr().out
    assert "build time" in out and png.is_file()

    out_dir = tmp_path / "pairs"
    assert main(["pairs", str(scan), str(out_dir), "--n", "2", "--seed", "1", "--noise", "jitter,drop"]) == 0
    assert "[2/2]" in capsys.readouterr().out
    gt = json.loads((out_dir / "pair_001" / "gt.json").read_text())
    assert np.array(gt["T_src_ref"]).shape == (4, 4) and gt["gt_node_pairs"]
    assert (out_dir / "pair_000" / "src" / "instances.json").is_file()


@pytest.mark.parametrize("argv", [
    ["graph", "{tmp}/missing"],
    ["pairs", "{tmp}", "{tmp}/out"],
    ["pairs", "{tmp}/missing", "{tmp}/out", "--noise", "bogus"],
    ["synth", "{tmp}/s", "--noise", "bogus"],
    ["synth", "{tmp}/s", "--rooms", "0"],
])
def test_bad_input_is_one_line_exit_2(tmp_path, capsys, argv):
    assert main([a.format(tmp=tmp_path) for a in argv]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and err.startswith("sgreg ") and "Traceback" not in err


def test_synth_writes_into_no_folder_that_holds_anything(tmp_path, capsys):
    (tmp_path / "old").mkdir()
    (tmp_path / "old" / "graph.png").write_bytes(b"an earlier scene's picture")
    (tmp_path / "a_file").write_text("x")
    for target in ("old", "a_file"):
        assert main(["synth", str(tmp_path / target)]) == 2
        err = capsys.readouterr().err
        assert "is not an empty folder" in err and err.count("\n") == 1
    assert (tmp_path / "old" / "graph.png").read_bytes() == b"an earlier scene's picture"
    (tmp_path / "empty").mkdir()
    assert main(["synth", str(tmp_path / "empty")]) == 0


def test_the_command_table_comes_from_the_command_modules(capsys, monkeypatch):
    from sgreg_cli import commands

    monkeypatch.setenv("COLUMNS", "300")   # one line per command in the help
    from sgreg_cli.main import command_modules

    found, broken = command_modules()
    assert not broken
    modules = {m.name for m in __import__("pkgutil").iter_modules(commands.__path__)}
    assert len(found) == len(modules) and {"register", "bench-replay", "make-bag"} <= set(found)
    assert main(["--help"]) == 0
    out = capsys.readouterr().out
    assert all(name in out and module.HELP in out for name, module in found.items())
    assert main(["no-such-command"]) == 2


def test_every_option_with_a_default_names_it_in_its_help(capsys, monkeypatch):
    import pytest

    from sgreg_cli.main import command_modules

    monkeypatch.setenv("COLUMNS", "400")   # one line per option
    for name in command_modules()[0]:
        with pytest.raises(SystemExit):
            main([name, "--help"])
        lines = capsys.readouterr().out.splitlines()
        assert not any("(default: )" in line or "(default: [])" in line for line in lines), name
        parser = __import__("argparse").ArgumentParser()
        command_modules()[0][name].add_arguments(parser)
        silent = [a.dest for a in parser._actions if a.option_strings and a.help is None]
        assert not silent, f"{name}: options without help (their defaults go unsaid): {silent}"
    with pytest.raises(SystemExit):
        main(["make-bag", "--help"])
    out = capsys.readouterr().out
    assert "--speed SPEED" in out and "(default: 0.5)" in out.split("--speed SPEED")[-1].splitlines()[0]
    # a help text that says its default itself is left as it is
    with pytest.raises(SystemExit):
        main(["replay", "--help"])
    assert "(default: config/sgreg.yaml)" in capsys.readouterr().out


def test_pairs_never_mix_two_runs_in_one_folder(tmp_path, capsys):
    from sgreg_core.maps.instance_map import write_instance_map
    from sgreg_core.simulation.synth import SynthConfig, generate_scene

    scan, out = tmp_path / "scene", tmp_path / "pairs"
    write_instance_map(generate_scene(3, SynthConfig(density=150.0)), scan)
    assert main(["pairs", str(scan), str(out), "--seed", "-1"]) == 2
    assert main(["pairs", str(scan), str(out), "--n", "3", "--seed", "0"]) == 0
    first = (out / "pair_000" / "gt.json").read_text()
    capsys.readouterr()
    # a second run is refused, the first run's pairs untouched ...
    assert main(["pairs", str(scan), str(out), "--n", "1", "--seed", "7"]) == 2
    assert "--overwrite" in capsys.readouterr().err
    assert (out / "pair_000" / "gt.json").read_text() == first
    # ... unless asked: then only the new run's pairs are there
    assert main(["pairs", str(scan), str(out), "--n", "1", "--seed", "7", "--overwrite"]) == 0
    assert sorted(p.name for p in out.iterdir()) == ["pair_000"]
    assert (out / "pair_000" / "gt.json").read_text() != first
    # a folder with anything else in it is never cleared
    (out / "notes.txt").write_text("mine")
    assert main(["pairs", str(scan), str(out), "--n", "1", "--overwrite"]) == 2
    assert "notes.txt" in capsys.readouterr().err and (out / "pair_000").is_dir()


def test_topic_names_resolve_as_ros_resolves_them_in_the_root_namespace():
    import argparse

    import pytest

    from sgreg_cli.topics import topic_name

    assert topic_name("b/mapping/instances") == "/b/mapping/instances"
    assert topic_name("/a/sgreg/coarse") == "/a/sgreg/coarse"
    for bad in ("", "/", "a//b", "a/1b", "a b", "~/x", "a__b", "a/"):
        with pytest.raises(argparse.ArgumentTypeError):
            topic_name(bad)


def test_outputs_and_numbers_are_checked_before_any_work(tmp_path, capsys):
    """Each refused in one line, exit 2, before the work (a benchmark used to fail on its output
    folder only after the whole run, with a traceback)."""
    from sgreg_core.maps.instance_map import write_instance_map
    from sgreg_core.simulation.synth import SynthConfig, generate_scene

    scan = tmp_path / "scene"
    write_instance_map(generate_scene(0, SynthConfig(density=150.0)), scan)
    (tmp_path / "a_file").write_text("")
    (tmp_path / "scans" / "room").mkdir(parents=True)
    (tmp_path / "scans" / "room" / "instances.json").write_text('[{"no_label": 1}]')
    cases = [
        (["params", "--out", str(tmp_path)], "is a folder"),
        (["params", "--out", str(tmp_path / "a_file" / "p.yaml")], "cannot write"),
        (["graph", str(scan), "--voxel", "0"], "voxel_size"),
        (["graph", str(scan), "--voxel", "nan"], "voxel_size"),
        (["graph", str(scan), "--repeat", "0"], "--repeat must be >= 1"),
        (["graph", str(scan), "--png", str(tmp_path / "g.txt")], "must name a picture format"),
        (["graph", str(scan), "--png", str(tmp_path / "a_file" / "g.png")], "cannot create folder"),
        (["bench-pose", "--out", str(tmp_path)], "is a folder"),
        (["bench-pose", "--seed", "-1"], "--seed >= 0"),
        (["bench-scale", "--out", str(tmp_path / "a_file")], "cannot create folder"),
        (["text-table", "--out", str(tmp_path)], "is a folder"),
        (["text-table", "--scans", str(tmp_path / "none"), "--out", str(tmp_path / "t.npz")], "is not a folder"),
        (["text-table", "--scans", str(tmp_path / "scans"), "--out", str(tmp_path / "t.npz")], "with a 'label'"),
    ]
    for argv, words in cases:
        assert main(argv) == 2, argv
        err = capsys.readouterr().err
        assert err.startswith(f"sgreg {argv[0]}: ") and words in err and err.count("\n") == 1, (argv, err)
    assert not (tmp_path / "t.npz").exists()


def test_defaults_named_in_help_texts_are_the_code_defaults():
    """Where a help text names a default itself, it names the value the code uses."""
    from sgreg_core.maps.scene_graph import GraphConfig
    from sgreg_core.runtime.merge import MergeConfig
    from sgreg_cli.commands import graph, view

    helps = {}
    for module in (graph, view):
        parser = __import__("argparse").ArgumentParser()
        module.add_arguments(parser)
        helps.update({a.dest: a.help for a in parser._actions})
    assert f"{GraphConfig().voxel_size:g})" in helps["voxel"]
    assert MergeConfig().merged_frame in helps["frame"]


def test_bench_startup_times_no_process_that_failed():
    """A process that exits non-zero (a missing module, a refused input) took its time failing:
    that time is no start-up time, so the bench stops and says which one instead of a table."""
    import sys

    from sgreg_cli.commands.bench_startup import ProcessFailed, _timed

    assert _timed([sys.executable, "-c", "pass"], "python") > 0
    with pytest.raises(ProcessFailed, match=r"KISS-Matcher exited with 3 \(boom\): not timed"):
        _timed([sys.executable, "-c", "import sys; print('boom', file=sys.stderr); sys.exit(3)"], "KISS-Matcher")


def test_bench_scale_counts_an_estimate_as_ok_only_when_ground_truth_agrees(monkeypatch):
    """Every *_ok: verified and right, not what the estimate says of itself (an estimate
    claiming success at a wrong pose is not ok). This case's coarse estimate fails verification,
    so coarse_ok's rule is checked on the helper every row is counted by."""
    from types import SimpleNamespace

    from sgreg_core.bench import scale_bench
    from sgreg_core.geometry import yaw_transform
    from sgreg_core.net.model import load_model

    T_gt = yaw_transform(0.3, (1.0, 2.0, 0.0))
    near = yaw_transform(0.3 + np.radians(1.0), (1.1, 2.0, 0.0))
    assert scale_bench.verified_and_right(SimpleNamespace(success=True, T=near), T_gt)
    assert not scale_bench.verified_and_right(SimpleNamespace(success=False, T=near), T_gt)
    assert not scale_bench.verified_and_right(SimpleNamespace(success=True, T=yaw_transform(0.3, (4.0, 2.0, 0.0))), T_gt)

    model = load_model()
    [row] = scale_bench.run_scale(model, scale_bench.ScaleConfig(nodes=(50,), repeats=1), log=lambda s: None)
    assert row["dense_ok"] and row["dense_requested_ok"]
    real = scale_bench.register_features

    def claims_a_wrong_pose(*args, **kwargs):
        reg = real(*args, **kwargs)
        reg.T_levelled = reg.T_levelled.copy()
        reg.T_levelled[:3, 3] += 3.0          # 3 m off, still "success"
        return reg

    monkeypatch.setattr(scale_bench, "register_features", claims_a_wrong_pose)
    [row] = scale_bench.run_scale(model, scale_bench.ScaleConfig(nodes=(50,), repeats=1), log=lambda s: None)
    assert not row["dense_requested_ok"] and not row["dense_ok"]


def test_bench_startup_times_no_shutdown_that_was_a_crash():
    import os
    import signal
    import subprocess
    import sys
    import time

    from sgreg_cli.commands.bench_startup import ProcessFailed, _stopped

    code = ("import signal, sys, time\n"
            "signal.signal(signal.SIGINT, lambda *a: sys.exit({}))\n"
            "print('up', flush=True)\n"
            "time.sleep(30)\n")
    for rc in (0, 5):
        proc = subprocess.Popen([sys.executable, "-c", code.format(rc)], stdout=subprocess.PIPE,
                                start_new_session=True)
        proc.stdout.readline()                 # its handler is set
        os.killpg(proc.pid, signal.SIGINT)
        t0 = time.perf_counter()
        if rc == 0:
            _stopped(proc, "the agent node")
            assert time.perf_counter() - t0 < 10
        else:
            with pytest.raises(ProcessFailed, match="the agent node exited with 5 on SIGINT: not timed"):
                _stopped(proc, "the agent node")


def test_growth_exponents_only_where_every_size_was_timed():
    """A stage that took 0.0 ms at some size has no meaningful log: no exponent (bench-scale
    printed -14 for one)."""
    import math

    from sgreg_core.bench.scale_bench import growth

    rows = [{"nodes": 50, "a_ms": 2.0, "b_ms": 0.3}, {"nodes": 100, "a_ms": 8.0, "b_ms": 0.0}]
    assert growth(rows, "a_ms") == pytest.approx(2.0)
    assert math.isnan(growth(rows, "b_ms")) and math.isnan(growth(rows[:1], "a_ms"))
