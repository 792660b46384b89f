"""`sgreg register` and `sgreg bench-register` on synthetic instance maps, with the shipped
weights: the result JSON contract, exit codes on bad input, coarse mode, the picture, a pair of
different rooms refused, and the benchmark's output schema."""
import argparse
import json
import shutil

import numpy as np
import pytest

from sgreg_cli.commands import register as register_cmd
from sgreg_cli.commands.register import pipeline_config
from sgreg_cli.main import main
from sgreg_core.maps.instance_map import write_instance_map
from sgreg_core.metrics import registration_rmse
from sgreg_core.net.model import load_model
from sgreg_core.net.testing import toy_graph
from sgreg_core.simulation.pairs import PairConfig, make_pair
from sgreg_core.pipeline import PipelineConfig, build_graphs, register_graphs
from sgreg_core.simulation.synth import SynthConfig, generate_scene

RESULT_KEYS = {"T": list, "success": bool, "node_matches": int, "inliers": int,
               "timing_ms": dict, "reason": str, "weights_id": str, "mode": str,
               "correspondences": int, "guided": bool, "refined": bool, "unrepeated": bool}


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    """An easy pair cut from one synthetic apartment, and a view of a synthetic office."""
    root = tmp_path_factory.mktemp("register")
    apartment = generate_scene(3, SynthConfig(density=300.0))
    pair = make_pair(apartment, PairConfig(overlap=0.8), np.random.default_rng(1))
    write_instance_map(pair.src, root / "src")
    write_instance_map(pair.ref, root / "ref")
    office = generate_scene(4, SynthConfig(kind="office", density=300.0))
    write_instance_map(make_pair(office, PairConfig(overlap=0.8), np.random.default_rng(2)).ref,
                       root / "other")
    return root, pair


def _register(root, *extra) -> tuple[int, dict]:
    out = root / "out.json"
    out.unlink(missing_ok=True)
    code = main(["register", str(root / extra[0]), str(root / extra[1]), "--json", str(out),
                 *extra[2:]])
    return code, json.loads(out.read_text())


def test_register_writes_the_result_contract(data, capsys, tmp_path):
    root, pair = data
    png = tmp_path / "reg.png"
    code, res = _register(root, "src", "ref", "--png", str(png))
    for key, kind in RESULT_KEYS.items():
        assert isinstance(res[key], kind), key
    assert res["fitness"] is None or isinstance(res["fitness"], float)
    assert res["mode"] == "dense" and code == (0 if res["success"] else 1)
    T = np.array(res["T"])
    assert T.shape == (4, 4) and np.allclose(T[3], [0, 0, 0, 1])
    stages = {"graph", "gnn", "shape", "node_match", "point_match", "pose", "total"}
    assert stages <= set(res["timing_ms"])
    # an easy pair (80 % overlap, clean): registered, and T maps SRC into REF
    assert res["success"], res["reason"]
    assert registration_rmse(pair.src.points, T, pair.T_src_ref) < 0.2
    out = capsys.readouterr().out
    assert "T (SRC -> REF)" in out and "registered:" in out
    assert png.stat().st_size > 10_000


def test_coarse_mode(data):
    root, pair = data
    code, res = _register(root, "src", "ref", "--coarse")
    assert res["mode"] == "coarse" and code == (0 if res["success"] else 1)
    assert "point_match" not in res["timing_ms"]
    # coarse correspondences are the node matches themselves
    assert res["correspondences"] == res["node_matches"]
    # an easy pair: node centers alone register it
    assert res["success"] and code == 0, res["reason"]
    assert registration_rmse(pair.src.points, np.array(res["T"]), pair.T_src_ref) < 0.2


def test_different_rooms_are_not_registered(data):
    root, _ = data
    for mode in ([], ["--coarse"]):
        code, res = _register(root, "src", "other", *mode)
        assert code == 1 and res["success"] is False and res["reason"] != "ok"


def test_set_overrides_the_pipeline_config(data, capsys):
    """--set reaches the pipeline (an impossible inlier count refuses the easy pair; the rim
    lands in the pose config); a key that does not exist, a value out of range or not YAML, a
    section given a value: one line on stderr and exit 2, not a traceback."""
    root, _ = data
    code, res = _register(root, "src", "ref", "--set", "pose.verdict.min_inliers=100000",
                          "--set", "geometric.enabled=false")
    assert code == 1 and res["reason"] == "too_few_inliers"
    args = argparse.Namespace(coarse=False, no_icp=False, overrides=["pose.footprint_rim=1"])
    assert pipeline_config(args).pose_config().footprint_rim == 1
    args.overrides = ["pose.footprint_probe=0.5"]
    assert pipeline_config(args).pose_config().footprint_probe == 0.5
    both = PipelineConfig().with_pose(footprint_probe=0.5)    # what the registration node sets
    assert both.pose.footprint_probe == both.coarse_pose.footprint_probe == 0.5
    assert both.pose.verify_voxel == PipelineConfig().pose.verify_voxel
    args.overrides = ["guided.enabled=false", "guided.min_objects=5"]
    assert not pipeline_config(args).guided.enabled and pipeline_config(args).guided.min_objects == 5
    args.overrides = ["repeats.enabled=false", "repeats.max_repeat=0.3"]
    assert not pipeline_config(args).repeats.enabled and pipeline_config(args).repeats.max_repeat == 0.3
    for bad in ("pose.no_such_key=1", "pose.footprint_rim=-1", "pose.footprint_rim=1.5",
                "pose.footprint_probe=-0.5",
                "pose.footprint_rim=[1", "pose=1", "pose.verdict.min_inliers", "guided.after=[ok]",
                "repeats.after=[ambiguous, ok]", "repeats.min_confidence=2",
                # wrong types and settings that divided by zero or were taken as they came
                "min_nodes=abc", "min_nodes=0", "graph.voxel_size=abc", "graph.voxel_size=0",
                "graph.voxel_size=.nan", "graph.voxel_size=-0.05", "graph.box_angles=0",
                "icp=true", "pose.clique_deltas=[0.2, x]",
                # the other mode's pose settings would change nothing
                "coarse_pose.noise_bound=0.5"):
        code = main(["register", str(root / "src"), str(root / "ref"), "--set", bad])
        err = capsys.readouterr().err.strip()
        assert code == 2 and err.startswith("sgreg register: --set: ") and "\n" not in err, bad
    code = main(["register", str(root / "src"), str(root / "ref"), "--coarse", "--set", "pose.footprint_rim=1"])
    err = capsys.readouterr().err.strip()
    assert code == 2 and "--coarse registration takes coarse_pose.*, not pose.*" in err, err
    code = main(["register", str(root / "src"), str(root / "ref"), "--set", "coarse_pose.footprint_rim=1"])
    err = capsys.readouterr().err.strip()
    assert code == 2 and "dense registration takes pose.*, not coarse_pose.*" in err, err
    for threads in ("0", "-3"):
        code = main(["register", str(root / "src"), str(root / "ref"), "--threads", threads])
        err = capsys.readouterr().err.strip()
        assert code == 2 and err == f"sgreg register: --threads must be >= 1, got {threads}", err


@pytest.mark.parametrize("problem", ["missing", "malformed"])
def test_bad_input_is_one_line_exit_2(data, tmp_path, capsys, problem):
    root, _ = data
    bad = tmp_path / "bad"
    if problem == "malformed":
        bad.mkdir()
        (bad / "points.npy").write_bytes(b"not numpy")
    out = tmp_path / "o.json"
    out.write_text('{"success": true}\n')       # an earlier run's result must not stay
    code = main(["register", str(bad), str(root / "ref"), "--json", str(out)])
    err = capsys.readouterr().err.strip()
    assert code == 2 and err.startswith("sgreg register: ") and "\n" not in err
    result = json.loads(out.read_text())
    assert result["success"] is False and result["error"] in err and result["src"] == str(bad)


def test_many_pairs_load_the_model_once(data, tmp_path, capsys):
    root, pair = data
    listing = tmp_path / "pairs.txt"
    listing.write_text(f"# src ref\n{root / 'src'} {root / 'ref'}\n\n{root / 'src'} {root / 'other'}\n"
                       f"{tmp_path / 'missing'} {root / 'ref'}\n")
    out = tmp_path / "all.json"
    code = main(["register", "--pairs", str(listing), "--json", str(out)])
    results = json.loads(out.read_text())
    assert code == 2 and len(results) == 3          # the bad pair is reported, the others run
    assert results[0]["success"] and registration_rmse(pair.src.points, np.array(results[0]["T"]),
                                                       pair.T_src_ref) < 0.2
    assert results[1]["success"] is False and "error" in results[2]
    assert "1 of 3 pairs registered" in capsys.readouterr().out
    listing.write_text(f"{root / 'src'}\n")
    assert main(["register", "--pairs", str(listing)]) == 2
    assert main(["register", str(root / "src")]) == 2
    assert "give SRC_DIR REF_DIR, or --pairs FILE" in capsys.readouterr().err
    assert main(["register", str(root / "src"), str(root / "ref"), "--pairs", str(listing)]) == 2
    assert "give SRC_DIR REF_DIR or --pairs FILE, not both" in capsys.readouterr().err


def test_ctrl_c_in_a_run_of_pairs_keeps_the_pairs_registered(data, tmp_path, capsys, monkeypatch):
    root, _ = data
    register_one = register_cmd._register_one
    done = []

    def interrupted_at_the_second(*args, **kwargs):
        if done:
            raise KeyboardInterrupt
        done.append(1)
        return register_one(*args, **kwargs)

    monkeypatch.setattr(register_cmd, "_register_one", interrupted_at_the_second)
    listing = tmp_path / "pairs.txt"
    listing.write_text(f"{root / 'src'} {root / 'ref'}\n{root / 'src'} {root / 'other'}\n")
    out = tmp_path / "all.json"
    assert main(["register", "--pairs", str(listing), "--json", str(out)]) == 130
    results = json.loads(out.read_text())
    assert len(results) == 1 and results[0]["success"]
    err = capsys.readouterr().err
    assert f"1 of 2 pairs registered before Ctrl-C: {out}" in err and err.endswith("sgreg register: interrupted\n")


def test_one_broken_pair_loses_no_other_result(data, tmp_path, capsys, monkeypatch):
    """A points.npy that is an .npz archive is bad input of its pair; a pair that fails in the
    pipeline is reported as that pair's error; the other pairs are still written."""
    root, _ = data
    npz = tmp_path / "npz"
    shutil.copytree(root / "src", npz)
    with open(npz / "points.npy", "wb") as f:
        np.savez(f, np.load(root / "src" / "points.npy"))
    register_one = register_cmd._register_one

    def breaks_on_other(*args, **kwargs):
        if args[3].endswith("other"):
            raise RuntimeError("a bug in the pipeline")
        return register_one(*args, **kwargs)

    monkeypatch.setattr(register_cmd, "_register_one", breaks_on_other)
    listing = tmp_path / "pairs.txt"
    listing.write_text(f"{root / 'src'} {root / 'ref'}\n{npz} {root / 'ref'}\n"
                       f"{root / 'src'} {root / 'other'}\n")
    out = tmp_path / "all.json"
    assert main(["register", "--pairs", str(listing), "--json", str(out)]) == 2
    results = json.loads(out.read_text())
    assert [r["success"] for r in results] == [True, False, False]
    assert "an .npz archive" in results[1]["error"] and "a bug in the pipeline" in results[2]["error"]
    err = capsys.readouterr().err
    assert "bad input" in err and "failed: RuntimeError" in err and "Traceback" not in err


def test_one_pair_that_breaks_the_pipeline_is_one_line_and_a_result(data, tmp_path, capsys,
                                                                   monkeypatch):
    """A single pair that fails in the pipeline: exit 2, one line naming the error and where it
    was raised, the JSON written with the error, no picture and no traceback."""
    root, _ = data

    def breaks(*args, **kwargs):
        raise RuntimeError("a bug in the pipeline\n  spread over lines")

    monkeypatch.setattr(register_cmd, "_register_one", breaks)
    out = tmp_path / "one.json"
    code = main(["register", str(root / "src"), str(root / "ref"), "--json", str(out),
                 "--png", str(tmp_path / "r.png")])
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1 and "Traceback" not in err
    assert "failed: RuntimeError: a bug in the pipeline spread over lines (at register.py:" in err
    assert " -> test_register.py:" in err      # sgreg's frame, then the one it called that raised
    result = json.loads(out.read_text())
    assert result["success"] is False and "a bug in the pipeline" in result["error"]
    assert not (tmp_path / "r.png").exists()


@pytest.mark.parametrize("png", ["r.txt", "a_file/r.png"])
def test_a_picture_that_cannot_be_written_is_refused_before_registering(data, tmp_path, capsys, png):
    root, _ = data
    (tmp_path / "a_file").write_text("not a folder")
    code = main(["register", str(root / "src"), str(root / "ref"), "--png", str(tmp_path / png),
                 "--json", str(tmp_path / "o.json")])
    out, err = capsys.readouterr()
    assert code == 2 and err.startswith("sgreg register: --png: ") and err.count("\n") == 1
    assert "T (SRC -> REF)" not in out and not (tmp_path / "o.json").exists()


def test_a_failed_picture_keeps_the_result(data, tmp_path, capsys, monkeypatch):
    import sgreg_core.plots.registration as plots

    def disk_full(*args, **kwargs):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(plots, "plot_registration", disk_full)
    root, _ = data
    code, res = _register(root, "src", "ref", "--png", str(tmp_path / "r.png"))
    err = capsys.readouterr().err
    assert code == 2 and res["success"] and err.startswith("sgreg register: cannot draw ")
    assert err.count("\n") == 1


def test_the_result_does_not_depend_on_the_order_the_maps_list_their_nodes(data):
    """Two robots that list the same maps' nodes in other orders get the same answer."""
    _, pair = data
    cfg = PipelineConfig()
    src, ref = build_graphs(pair.src, pair.ref, cfg, {})
    model = load_model()
    first = register_graphs(model, src, ref, cfg)
    rng = np.random.default_rng(3)
    again = register_graphs(model, src.reordered(rng.permutation(src.num_nodes)),
                            ref.reordered(rng.permutation(ref.num_nodes)), cfg)
    assert first.success and (again.reason, again.inliers) == (first.reason, first.inliers)
    np.testing.assert_allclose(again.T, first.T, atol=1e-5)
    assert again.confidence == pytest.approx(first.confidence, abs=1e-6)


def test_tiny_graphs_are_refused_without_matching():
    graph = toy_graph(np.random.default_rng(0), n=2)
    reg = register_graphs(load_model(), graph, graph, PipelineConfig())
    assert not reg.success and reg.reason == "too_few_nodes" and np.allclose(reg.T, np.eye(4))


def test_bench_register_schema(tmp_path, capsys):
    scans = tmp_path / "scans"
    write_instance_map(generate_scene(5, SynthConfig(density=200.0)), scans / "toy_scene0009_00")
    # any folder name: one without a capture number is a room of its own
    write_instance_map(generate_scene(6, SynthConfig(kind="office", density=200.0)),
                       scans / "myoffice")
    out = tmp_path / "bench"
    code = main(["bench-register", "--scans", str(scans), "--scan-prefix", "",
                 "--rooms", "scene0009", "--held-out-rooms", "scene0009", "--rescan-gt", "",
                 "--n", "2", "--methods", "sgreg_dense", "sgreg_coarse", "kiss_matcher",
                 "--out", str(out), "--no-progress"])
    assert code == 0
    printed = capsys.readouterr().out
    assert "clean" in printed and "different_rooms" in printed and "kiss_matcher" in printed
    results = json.loads((out / "results.json").read_text())
    # the machine and its speed at the time, so that runs on other days can be compared
    host = results["machine"]
    assert host["cores"] >= 1 and host["torch_threads"] == 1 and host["cpu"]
    assert all(0 < host["reference_ms"][k] < 10_000 for k in ("before", "after"))
    assert set(host["reference_ms"]["by_setting"]) == {"clean"}    # every 30 cases: the first
    assert "reference workload" in printed
    config = json.loads((out / "config.json").read_text())
    assert config["config"]["cases"]["n"] == 2 and config["weights_id"] == results["weights_id"]
    assert (out / "recall.png").stat().st_size > 10_000
    summary = results["summary"]
    assert set(summary) == {"clean", "noisy", "tilt", "frontend", "different_rooms"}
    for group, by_method in summary.items():
        assert set(by_method) == {"sgreg_dense", "sgreg_coarse", "kiss_matcher"}
        for method, s in by_method.items():
            assert s["n"] == 2
            for key in ("recall", "verified_recall", "claimed_rate", "false_claims", "median_rte_m",
                        "median_rre_deg", "time_ms_median", "time_ms_p90"):
                assert key in s
            if method.startswith("sgreg"):
                for key in ("node_recall", "node_precision", "inlier_ratio",
                            "pseudo_inlier_ratio", "stage_ms_median", "reasons"):
                    assert key in s
    assert len(results["rows"]) == 5 * 2 * 3      # settings x cases x methods
    for row in results["rows"]:
        assert {"setting", "case", "method", "claimed", "success", "false_claim", "rmse",
                "time_ms"} <= set(row)
        if row["setting"] == "different_rooms":
            assert row["success"] is False and row["false_claim"] == row["claimed"]
    # sgreg never claims a wrong answer on these
    assert all(not r["false_claim"] for r in results["rows"] if r["method"].startswith("sgreg"))


def test_bench_register_refuses_an_unusable_out_before_any_case(tmp_path, capsys):
    (tmp_path / "a_file").write_text("not a folder")
    code = main(["bench-register", "--scans", str(tmp_path / "no_scans"), "--methods", "kiss_matcher",
                 "--out", str(tmp_path / "a_file" / "bench"), "--no-progress"])
    err = capsys.readouterr().err
    assert code == 2 and err.startswith("sgreg bench-register: cannot create folder ")
    assert err.count("\n") == 1


def bench_scans(tmp_path):
    scans = tmp_path / "scans"
    write_instance_map(generate_scene(5, SynthConfig(density=200.0)), scans / "toy_scene0009_00")
    return ["--scans", str(scans), "--scan-prefix", "", "--rooms", "scene0009",
            "--held-out-rooms", "scene0009", "--no-progress"]


def test_bench_register_keeps_the_dense_row_when_the_coarse_estimate_fails(tmp_path, capsys, monkeypatch):
    from sgreg_core.bench import register_bench

    def broken(*args, **kwargs):
        raise RuntimeError("coarse broke")

    monkeypatch.setattr(register_bench, "register_features", broken)
    out = tmp_path / "bench"
    assert main(["bench-register", *bench_scans(tmp_path), "--rescan-gt", "", "--n", "2",
                 "--settings", "clean", "--methods", "sgreg_dense", "sgreg_coarse", "--out", str(out)]) == 0
    rows = json.loads((out / "results.json").read_text())["rows"]
    coarse = [r for r in rows if r["method"] == "sgreg_coarse"]
    dense = [r for r in rows if r["method"] == "sgreg_dense"]
    assert len(coarse) == len(dense) == 2
    assert all(r["error"] == "RuntimeError: coarse broke" for r in coarse)
    assert not any("error" in r for r in dense) and any(r["success"] for r in dense)


def test_bench_register_with_no_case_to_run_says_so(tmp_path, capsys):
    code = main(["bench-register", *bench_scans(tmp_path), "--rescan-gt", "", "--settings", "rescan",
                 "--methods", "kiss_matcher", "--out", str(tmp_path / "bench")])
    err = capsys.readouterr().err
    assert code == 2 and "no cases for settings rescan" in err and err.count("\n") == 1
