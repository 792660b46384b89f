"""`sgreg bench-match` on tiny generated scans with two models (an ablation pair)."""
import json

import numpy as np
import pytest
import torch

from sgreg_cli import main as cli
from sgreg_core.maps.instance_map import write_instance_map
from sgreg_core.net import ModelConfig, SGRegModel, save_model
from sgreg_core.net import text as text_module
from sgreg_core.net.testing import _hashed_embed
from sgreg_core.simulation.synth import SynthConfig, generate_scene


@pytest.fixture()
def setup(tmp_path, monkeypatch):
    monkeypatch.setattr(text_module, "_load_minilm", lambda: _hashed_embed)  # no model load
    before = torch.get_num_threads()
    scans = tmp_path / "scans"
    write_instance_map(generate_scene(5, SynthConfig(density=150.0)), scans / "toy_scene0009_00")
    paths = []
    for name, cfg in [("late", ModelConfig()), ("notriplets", ModelConfig.from_dict({"gnn": {"use_triplets": False}}))]:
        torch.manual_seed(0)
        path = tmp_path / name / "model.safetensors"
        save_model(SGRegModel(cfg), path)
        paths.append(str(path))
    yield tmp_path, scans, paths
    torch.set_num_threads(before)


def test_bench_match_compares_models_on_clean_noisy_and_frontend_pairs(setup, capsys):
    tmp_path, scans, paths = setup
    out = tmp_path / "results" / "bench.json"
    code = cli.main(["bench-match", "--weights", *paths, "--pairs", "2", "--scans-dir", str(scans),
                     "--scan-prefix", "toy_",
                     "--rescan-gt", "", "--val-room", "scene0009", "--cache-dir", str(tmp_path / "cache"),
                     "--text-cache", str(tmp_path / "text.npz"), "--match", "node_topk=1",
                     "--out", str(out)])
    assert code == 0
    printed = capsys.readouterr().out
    assert "late" in printed and "notriplets" in printed and "noisy" in printed and "frontend" in printed
    results = json.loads(out.read_text())["results"]
    assert [(r["model"], r["condition"]) for r in results] == [
        (m, c) for m in ("late", "notriplets") for c in ("clean", "noisy", "frontend")]
    for r in results:
        assert r["summary"]["pairs"] == 2 and len(r["pairs"]) == 2
        for key in ("node_recall", "node_precision", "inlier_ratio", "ms_gnn", "ms_shape",
                    "ms_text", "ms_node_match", "ms_point_match"):
            assert key in r["summary"]
        assert 0 <= r["summary"]["node_recall"] <= 1 or np.isnan(r["summary"]["node_recall"])
    resolved = json.loads(out.with_name("bench.config.json").read_text())
    assert resolved["models"]["notriplets"]["config"]["gnn"]["use_triplets"] is False
    assert resolved["models"]["late"]["config"]["match"]["node_topk"] == 1


def test_bench_match_reports_missing_weights(tmp_path, capsys):
    code = cli.main(["bench-match", "--weights", str(tmp_path / "nope.safetensors"),
                     "--out", str(tmp_path / "b.json")])
    assert code == 2
    assert "nope.json" in capsys.readouterr().err


@pytest.mark.parametrize("args", [["--pairs", "0"], ["--threads", "0"], ["--seed", "-1"],
                                  ["--match", "point_threshold=abc"], ["--match", "no_such=1"]])
def test_bench_match_refuses_bad_arguments_before_any_pair(tmp_path, capsys, args):
    code = cli.main(["bench-match", *args, "--scans-dir", str(tmp_path / "none"),
                     "--out", str(tmp_path / "b.json")])
    err = capsys.readouterr().err.strip()
    assert code == 2 and err.startswith("sgreg bench-match: ") and "\n" not in err
    assert not (tmp_path / "b.json").exists()


def test_bench_match_on_the_validation_split_uses_unseen_synthetic_scenes_not_the_held_out_room(setup, capsys):
    """What a choice between weights may rest on (--on val), apart from what is reported."""
    tmp_path, scans, paths = setup
    out = tmp_path / "results" / "val.json"
    code = cli.main(["bench-match", "--weights", paths[0], "--pairs", "1", "--scans-dir", str(scans),
                     "--scan-prefix", "toy_", "--rescan-gt", "", "--room", "scene0009", "--on", "val",
                     "--cache-dir", str(tmp_path / "cache"), "--text-cache", str(tmp_path / "text.npz"),
                     "--out", str(out)])
    assert code == 0, capsys.readouterr().err
    sources = {row["source"] for r in json.loads(out.read_text())["results"] for row in r["pairs"]}
    assert sources and all(s.startswith("synth:") and int(s.split(":")[1]) >= 200 for s in sources)
