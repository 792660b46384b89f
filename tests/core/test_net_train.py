"""Training end to end on tiny generated scans: outputs, exact resume, the CLI config path."""
import json
from pathlib import Path

import numpy as np
import pytest
import torch
from safetensors.torch import load_file

from sgreg_core.maps.instance_map import write_instance_map
from sgreg_core.net import load_model
from sgreg_core.net import train as train_module
from sgreg_core.config import apply_overrides, from_dict
from sgreg_core.net.dataset import DataConfig
from sgreg_core.net.dataset import PairSource, augment
from sgreg_core.net.testing import hashed_text_encoder
from sgreg_core.net.train import TrainConfig, train
from sgreg_core.simulation.synth import SynthConfig, generate_scene


@pytest.fixture(scope="module")
def scans(tmp_path_factory):
    """Two small synthetic rooms written as scans; room 'scene0002' is the validation room."""
    root = tmp_path_factory.mktemp("scans")
    for k, name in enumerate(["toy_scene0001_00", "toy_scene0002_00"]):
        write_instance_map(generate_scene(k, SynthConfig(density=150.0)), root / name)
    return root


def _cfg(tmp_path, scans, run="run", log_every=1, **optim):
    data = {
        "run_dir": str(tmp_path / run), "threads": 1, "log_every": log_every, "val_every": 100,
        "checkpoint_every": 2,
        "data": {"scans_dir": str(scans), "scan_prefix": "toy_", "rescan_gt": "",
                 "val_room": "scene0002", "train_pairs": 3, "val_pairs": 1,
                 "mix": {"scan": 1.0}, "synth_scenes": 0, "cache_dir": str(tmp_path / "cache")},
        "model": {"shape": {"points_per_node": 16, "d_hidden": 16}, "gnn": {"layers": 1}},
        "optim": {"steps": 4, "batch_pairs": 1, "warmup_steps": 1, **optim},
    }
    return from_dict(TrainConfig, data)


@pytest.fixture(autouse=True)
def one_thread():
    before = torch.get_num_threads()
    yield
    torch.set_num_threads(before)


def test_the_held_out_room_is_neither_trained_nor_validated_on(tmp_path, scans):
    """test_rooms are what benchmarks report on: no run may train or select weights on them."""
    from dataclasses import replace

    cfg = replace(_cfg(tmp_path, scans).data, test_rooms=("scene0002",), val_room="", synth_scenes=2)
    assert PairSource(cfg, "train", 0).scans == ["toy_scene0001_00"]
    assert PairSource(cfg, "test", 0).scans == ["toy_scene0002_00"]
    val = PairSource(cfg, "val", 0)
    assert val.scans == [] and val.weights == {"synth": 1.0}
    assert val.pair(0).source in {f"synth:{k}" for k in range(2, 2 + cfg.val_synth_scenes)}   # never trained on
    with pytest.raises(ValueError, match="one of test_rooms"):
        replace(cfg, val_room="scene0002")


def test_pair_source_splits_rooms_and_caches(tmp_path, scans):
    cfg = _cfg(tmp_path, scans).data
    train_src, val_src = PairSource(cfg, "train", 0), PairSource(cfg, "val", 0)
    assert train_src.scans == ["toy_scene0001_00"] and val_src.scans == ["toy_scene0002_00"]
    pair = train_src.pair(0)
    assert pair.source == "scan:toy_scene0001_00" and len(pair.gt) >= cfg.min_matches
    again = PairSource(cfg, "train", 0).pair(0)  # from the disk cache
    assert np.array_equal(pair.gt, again.gt) and np.allclose(pair.T_src_ref, again.T_src_ref)
    # gt node pairs really overlap once src is moved into the ref frame
    moved = augment(pair, np.random.default_rng(0))
    i, j = moved.matches(0.3)[0]
    src_pts = moved.src.points[i] @ moved.T_src_ref[:3, :3].T + moved.T_src_ref[:3, 3]
    dist = np.linalg.norm(src_pts[:, None] - moved.ref.points[j][None], axis=-1).min(1)
    assert np.median(dist) < 0.1


def test_the_pair_cache_is_keyed_on_the_rescan_transforms_and_the_code(tmp_path, scans, monkeypatch):
    """A corrected pseudo ground truth (same file name) or a change to the code that cuts pairs
    must not reuse pairs cut before it."""
    from dataclasses import replace

    from sgreg_core.net import dataset

    def rescan_gt(x):
        path = tmp_path / f"gt_{x}.json"
        path.write_text(json.dumps({"pairs": [{"src": "toy_scene0001_00", "ref": "toy_scene0001_00",
                                               "accepted": True,
                                               "T_src_to_ref": np.eye(4).tolist() if x == 0 else
                                               [[1, 0, 0, x], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]}]}))
        return str(path)

    cfg = _cfg(tmp_path, scans).data
    first = PairSource(replace(cfg, rescan_gt=rescan_gt(0)), "train", 0).cache
    assert PairSource(replace(cfg, rescan_gt=rescan_gt(0)), "train", 0).cache == first
    (tmp_path / "gt_0.json").write_text((Path(rescan_gt(1))).read_text())     # corrected in place
    assert PairSource(replace(cfg, rescan_gt=str(tmp_path / "gt_0.json")), "train", 0).cache != first
    before = PairSource(cfg, "train", 0).cache
    monkeypatch.setattr(dataset, "source_digest", lambda *paths: "changed")
    assert PairSource(cfg, "train", 0).cache != before


def test_train_writes_outputs_and_resumes_exactly(tmp_path, scans, monkeypatch):
    text = hashed_text_encoder()
    # losses logged every 3 steps, checkpoints every 2: the resumed run must carry the losses
    # of the steps before its checkpoint into its first log line
    full = train(_cfg(tmp_path, scans, "full", log_every=3), progress=False, text_encoder=text)
    run_dir = full.parent
    for name in ("config.yaml", "history.json", "loss_curve.png", "model.json", "checkpoint.pt"):
        assert (run_dir / name).exists(), name
    history = json.loads((run_dir / "history.json").read_text())
    assert [r["step"] for r in history["train"]] == [3, 4] and len(history["val"]) == 1
    assert load_model(full, text_encoder=text).weights_id == json.loads(
        (run_dir / "model.json").read_text())["weights_id"]

    # a run killed during step 3 resumes from its step-2 checkpoint to the same weights
    calls = {"n": 0}
    real = train_module.pair_step_losses

    def dying(*args, **kwargs):
        calls["n"] += 1
        if calls["n"] == 3:
            raise KeyboardInterrupt
        return real(*args, **kwargs)

    cfg = _cfg(tmp_path, scans, "split", log_every=3)
    monkeypatch.setattr(train_module, "pair_step_losses", dying)
    with pytest.raises(KeyboardInterrupt):
        train(cfg, progress=False, text_encoder=text)
    monkeypatch.setattr(train_module, "pair_step_losses", real)
    with pytest.raises(FileExistsError):
        train(cfg, progress=False, text_encoder=text)
    # another validation room (or any other setting) is not this run: refused, nothing written
    saved = (cfg_dir := Path(cfg.run_dir)).joinpath("config.yaml").read_text()
    other = from_dict(TrainConfig, apply_overrides(cfg.to_dict(), ["data.val_room=scene0001"]))
    with pytest.raises(ValueError, match=r"other settings \(data.val_room\)"):
        train(other, resume=True, progress=False, text_encoder=text)
    assert (cfg_dir / "config.yaml").read_text() == saved
    # where it runs and reports may change (a run folder moved, more threads); what it trains not
    from sgreg_core.net.train import _changed
    was = cfg.to_dict()
    moved = from_dict(TrainConfig, apply_overrides(cfg.to_dict(), ["threads=2", "log_every=7",
                                                                   "data.cache_dir=/elsewhere"])).to_dict()
    assert _changed(was, moved) == []
    mixed = from_dict(TrainConfig, apply_overrides(cfg.to_dict(), ["data.mix={scan: 1.0, synth: 0.5}"])).to_dict()
    assert _changed(was, mixed) == ["data.mix"]
    del was["optim"]["steps"]          # a setting the checkpoint predates: its default is taken
    assert _changed(was, cfg.to_dict()) == []
    resumed = train(cfg, resume=True, progress=False, text_encoder=text)
    a, b = load_file(str(full)), load_file(str(resumed))
    assert all(torch.equal(a[k], b[k]) for k in a)
    assert json.loads((cfg_dir / "history.json").read_text())["train"] == history["train"]


def test_a_checkpoint_that_cannot_be_read_is_one_line(tmp_path, scans, capsys):
    from sgreg_cli.main import main

    cfg = _cfg(tmp_path, scans, "cut")
    Path(cfg.run_dir).mkdir(parents=True)
    (Path(cfg.run_dir) / "checkpoint.pt").write_bytes(b"PK\x03\x04 not a checkpoint")
    config = tmp_path / "train.yaml"
    import yaml
    config.write_text(yaml.safe_dump(cfg.to_dict()))
    assert main(["train", "--config", str(config), "--resume", "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert "checkpoint.pt cannot be resumed" in err and err.count("\n") == 1
    with pytest.raises(ValueError, match="data.mix"):
        from_dict(TrainConfig, apply_overrides(cfg.to_dict(), ["data.mix={scna: 1.0}"]))


def test_default_config_file_parses_and_overrides():
    import yaml

    data = yaml.safe_load((Path(__file__).parents[2] / "config" / "train.yaml").read_text())
    cfg = from_dict(TrainConfig, apply_overrides(data, ["optim.steps=7", "model.fusion=early"]))
    assert cfg.optim.steps == 7 and cfg.model.fusion == "early"
    assert cfg.data.test_rooms == ("scene0005",) and cfg.data.val_room == ""
    with pytest.raises(ValueError, match="unknown"):
        from_dict(TrainConfig, apply_overrides(data, ["optim.stepz=7"]))


def test_a_pair_without_node_matches_at_the_loss_iou_adds_nothing_instead_of_failing(tmp_path, scans):
    """A pool pair has min_matches node pairs at iou_store (0.1), the losses take those at
    their own min_iou (0.3): small, partial views can have none there."""
    from sgreg_core.net.losses import pair_losses

    from sgreg_core.net.model import SGRegModel

    cfg = _cfg(tmp_path, scans)
    model = SGRegModel(cfg.model, text_encoder=hashed_text_encoder())
    pair = PairSource(cfg.data, "train", 0).pair(0)
    rng = np.random.default_rng(0)
    losses = pair_losses(model, model.prepare(pair.src, rng=rng), model.prepare(pair.ref, rng=rng),
                         torch.as_tensor(pair.T_src_ref, dtype=torch.float32),
                         torch.zeros((0, 2), dtype=torch.int64), cfg.loss)
    assert all(torch.isfinite(v.detach()) for v in losses.values()) and losses["total"].detach().item() == 0.0
    losses["total"].backward()


def test_held_out_rooms_name_rooms_not_captures():
    """Splits compare rooms: a capture named as held out would hold nothing out."""
    with pytest.raises(ValueError, match="name captures, not rooms"):
        DataConfig(test_rooms=("scene0005_00",))
    with pytest.raises(ValueError, match="name captures"):
        DataConfig(val_room="scene0002_01")
