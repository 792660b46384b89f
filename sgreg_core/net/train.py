"""Training loop of the SG-Reg network on CPU (paper section V).

One optimiser step = `batch_pairs` registration pairs (gradients accumulated), each freshly
augmented by random 4-DoF transforms and a new point sample. The pairs a step uses and their
augmentation derive from (seed, step) only, and the checkpoint holds the model, optimiser,
schedule, torch RNG and history, so a resumed run continues exactly where it stopped.

Run directory:
    config.yaml            the resolved TrainConfig
    checkpoint.pt          written every `checkpoint_every` steps (atomic)
    history.json           logged training losses and validation results
    loss_curve.png         training / validation losses and validation matching quality
    model.safetensors      final weights, + model.json (ModelConfig, weights_id, what it saw)

Public API:
    OptimConfig, TrainConfig (config.from_dict(TrainConfig, yaml_dict) builds one)
    train(cfg, resume=False, progress=True, text_encoder=None) -> Path of model.safetensors
"""
from __future__ import annotations

import json
import math
import os
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch
import yaml
from tqdm import tqdm

from ..config import to_dict
from .dataset import DataConfig, GraphPair, PairSource, augment
from .evaluate import evaluate_pairs, summarize
from .losses import LossConfig, pair_losses
from .model import ModelConfig, SGRegModel, save_model
from .text import TextEncoder

LOSS_TERMS = ("total", "gnn", "contrastive", "ot")


@dataclass
class OptimConfig:
    """steps: optimiser steps; batch_pairs: pairs per step; AdamW with linear warm-up then
    cosine decay to lr * min_lr_ratio; gradients clipped to grad_clip (global norm)."""

    steps: int = 2000
    batch_pairs: int = 4
    lr: float = 2e-3
    weight_decay: float = 1e-4
    warmup_steps: int = 100
    min_lr_ratio: float = 0.05
    grad_clip: float = 5.0


@dataclass
class TrainConfig:
    """run_dir: outputs (see the module docstring); threads: torch CPU threads (1 is fastest
    for these small graphs on a shared 2-core machine); text_cache: label embeddings on disk."""

    run_dir: str = "runs/train_default"
    seed: int = 0
    threads: int = 1
    log_every: int = 25
    val_every: int = 250
    checkpoint_every: int = 50
    text_cache: str = "runs/cache/text_minilm.npz"
    model: ModelConfig = field(default_factory=ModelConfig)
    loss: LossConfig = field(default_factory=LossConfig)
    data: DataConfig = field(default_factory=DataConfig)
    optim: OptimConfig = field(default_factory=OptimConfig)

    def to_dict(self) -> dict:
        return to_dict(self)


def _lr_factor(step: int, cfg: OptimConfig) -> float:
    if step < cfg.warmup_steps:
        return (step + 1) / cfg.warmup_steps
    progress = (step - cfg.warmup_steps) / max(1, cfg.steps - cfg.warmup_steps)
    return cfg.min_lr_ratio + (1 - cfg.min_lr_ratio) * 0.5 * (1 + math.cos(math.pi * min(1.0, progress)))


def pair_step_losses(model: SGRegModel, pair: GraphPair, cfg: TrainConfig,
                     rng: np.random.Generator) -> dict[str, torch.Tensor]:
    """Losses of one (already augmented) pair; the point sample is drawn from rng."""
    gt = torch.from_numpy(pair.matches(cfg.loss.min_iou))
    inp_src = model.prepare(pair.src, rng=rng)
    inp_ref = model.prepare(pair.ref, rng=rng)
    T = torch.as_tensor(pair.T_src_ref, dtype=torch.float32)
    return pair_losses(model, inp_src, inp_ref, T, gt, cfg.loss)


@torch.no_grad()
def validate(model: SGRegModel, pairs: list[GraphPair], cfg: TrainConfig) -> dict:
    model.eval()
    losses = [pair_step_losses(model, p, cfg, np.random.default_rng(k)) for k, p in enumerate(pairs)]
    out = {f"loss_{k}": float(np.mean([l[k].item() for l in losses])) for k in LOSS_TERMS}
    out.update(summarize(evaluate_pairs(model, pairs, min_iou=cfg.loss.min_iou)))
    model.train()
    return out


class _Run:
    """Checkpoint and history files of a run directory."""

    def __init__(self, run_dir: Path):
        self.dir = run_dir
        self.checkpoint = run_dir / "checkpoint.pt"

    def load_checkpoint(self) -> dict:
        """The checkpoint's state (tensors and plain values only: nothing in it runs code);
        ValueError, in one line, for a file that is not one."""
        try:
            return torch.load(self.checkpoint, weights_only=True)
        except Exception as exc:   # a cut file, another format: UnpicklingError, RuntimeError
            raise ValueError(f"{self.checkpoint} cannot be resumed: {' '.join(str(exc).split())[:200]}") from None

    def save_checkpoint(self, state: dict) -> None:
        tmp = self.checkpoint.with_suffix(".tmp")
        torch.save(state, tmp)
        os.replace(tmp, self.checkpoint)

    def write_history(self, history: dict) -> None:
        (self.dir / "history.json").write_text(json.dumps(history, indent=1) + "\n")


def train(cfg: TrainConfig, resume: bool = False, progress: bool = True,
          text_encoder: TextEncoder | None = None) -> Path:
    """Train (or resume) the run of cfg; returns the final model path. text_encoder replaces
    the cached MiniLM encoder (tests)."""
    torch.set_num_threads(cfg.threads)
    torch.manual_seed(cfg.seed)
    run = _Run(Path(cfg.run_dir))
    if run.checkpoint.exists() and not resume:
        raise FileExistsError(f"{run.checkpoint} exists: resume it (--resume) or pick another run_dir")
    state = run.load_checkpoint() if resume and run.checkpoint.exists() else None
    if state is not None:
        # a resumed run is the run it continues: another validation room or data would make a
        # model trained on two configs, saved under one
        changed = _changed(state.get("config") or _saved_config(run), cfg.to_dict())
        if changed:
            raise ValueError(f"{run.checkpoint} was trained with other settings ({', '.join(changed)}); "
                             "resume it with its own config or pick another run_dir")
    else:
        run.dir.mkdir(parents=True, exist_ok=True)
        (run.dir / "config.yaml").write_text(yaml.safe_dump(cfg.to_dict(), sort_keys=False))

    text_encoder = text_encoder or TextEncoder(cache_path=cfg.text_cache)
    model = SGRegModel(cfg.model, text_encoder=text_encoder).train()
    opt = torch.optim.AdamW(model.parameters(), lr=cfg.optim.lr, weight_decay=cfg.optim.weight_decay)
    sched = torch.optim.lr_scheduler.LambdaLR(opt, lambda s: _lr_factor(s, cfg.optim))
    history: dict = {"train": [], "val": []}
    start = 0
    window: list[dict] = []      # losses since the last log line
    if state is not None:
        model.load_state_dict(state["model"])
        opt.load_state_dict(state["optimizer"])
        sched.load_state_dict(state["scheduler"])
        torch.set_rng_state(state["torch_rng"])
        history, start = state["history"], state["step"]
        window = state.get("window", [])

    train_pairs = PairSource(cfg.data, "train", cfg.seed)
    val_source = PairSource(cfg.data, "val", cfg.seed)
    val_pairs: list[GraphPair] | None = None
    bar = tqdm(range(start, cfg.optim.steps), initial=start, total=cfg.optim.steps,
               disable=not progress, desc="train", unit="step", dynamic_ncols=True)
    t_start = time.time()
    for step in bar:
        rng = np.random.default_rng([cfg.seed, step])
        opt.zero_grad(set_to_none=True)
        for index in rng.integers(len(train_pairs), size=cfg.optim.batch_pairs):
            losses = pair_step_losses(model, augment(train_pairs.pair(int(index)), rng), cfg, rng)
            (losses["total"] / cfg.optim.batch_pairs).backward()
            window.append({k: losses[k].item() for k in LOSS_TERMS})
        torch.nn.utils.clip_grad_norm_(model.parameters(), cfg.optim.grad_clip)
        opt.step()
        sched.step()

        done = step + 1
        if done % cfg.log_every == 0 or done == cfg.optim.steps:
            mean = {k: float(np.mean([w[k] for w in window])) for k in LOSS_TERMS}
            history["train"].append({"step": done, "lr": sched.get_last_lr()[0], **mean})
            bar.set_postfix(loss=f"{mean['total']:.3f}", gnn=f"{mean['gnn']:.3f}", ot=f"{mean['ot']:.3f}")
            window = []
        if done % cfg.val_every == 0 or done == cfg.optim.steps:
            if val_pairs is None:
                val_pairs = [val_source.pair(k) for k in range(len(val_source))]
            result = validate(model, val_pairs, cfg)
            history["val"].append({"step": done, **result})
            bar.write(f"step {done}: val loss {result['loss_total']:.3f}  node recall "
                      f"{result['node_recall']:.3f}  precision {result['node_precision']:.3f}  "
                      f"inlier ratio {result['inlier_ratio']:.3f}")
        if done % cfg.checkpoint_every == 0 or done == cfg.optim.steps:
            run.save_checkpoint({"model": model.state_dict(), "optimizer": opt.state_dict(),
                                 "scheduler": sched.state_dict(), "torch_rng": torch.get_rng_state(),
                                 "history": history, "step": done, "window": window,
                                 "config": cfg.to_dict()})
            run.write_history(history)
    bar.close()

    plot_history(history, run.dir / "loss_curve.png")
    run.write_history(history)
    meta = {"trained_on": _trained_on(cfg), "steps": cfg.optim.steps, "seed": cfg.seed,
            "final_val": history["val"][-1] if history["val"] else None,
            "train_seconds_last_session": round(time.time() - t_start, 1)}
    model_path = run.dir / "model.safetensors"
    save_model(model.eval(), model_path, meta=meta)
    return model_path


def _saved_config(run: _Run) -> dict | None:
    """The config.yaml of a run whose checkpoint predates keeping its config (None: none)."""
    path = run.dir / "config.yaml"
    return yaml.safe_load(path.read_text()) if path.exists() else None


# settings a resumed run may change: where it runs and reports, not what it trains (threads
# only changes float rounding: weights then differ from an uninterrupted run's in the 5th digit)
RESUMABLE_CHANGES = ("run_dir", "threads", "log_every", "val_every", "checkpoint_every", "text_cache",
                     "data.cache_dir")


def _changed(before: dict | None, now: dict, prefix: str = "") -> list[str]:
    """The dotted keys whose values differ between two resolved configs (before None: none),
    but for RESUMABLE_CHANGES and keys one of them lacks (a setting added since the checkpoint
    was written has its default, which is what the run had)."""
    if before is None:
        return []
    out = []
    for key in sorted(before.keys() & now.keys()):
        a, b, name = before[key], now[key], f"{prefix}{key}"
        if isinstance(a, dict) and isinstance(b, dict) and name != "data.mix":   # mix's keys are its value
            out += _changed(a, b, f"{name}.")
        elif name not in RESUMABLE_CHANGES and json.dumps(a) != json.dumps(b):   # tuples and lists alike
            out.append(name)
    return out


def _trained_on(cfg: TrainConfig) -> str:
    d = cfg.data
    val = f"room {d.val_room}" if d.val_room else f"{d.val_synth_scenes} unseen synthetic scenes"
    return (f"pairs cut from ScanNet v2 scans in {d.scans_dir} ({d.scan_prefix}*, rescans with "
            f"pseudo ground truth) except rooms {', '.join(d.test_rooms) or '-'} (held out for "
            f"reporting) and the validation's ({val}), mixed with synthetic scenes of "
            f"sgreg_core.simulation.synth; mix {d.mix}")


def plot_history(history: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax_loss, ax_val) = plt.subplots(1, 2, figsize=(11, 4))
    train_rows, val_rows = history["train"], history["val"]
    for term in LOSS_TERMS:
        ax_loss.plot([r["step"] for r in train_rows], [r[term] for r in train_rows], label=f"train {term}")
    if val_rows:
        ax_loss.plot([r["step"] for r in val_rows], [r["loss_total"] for r in val_rows], "k--o",
                     label="val total")
        for key in ("node_recall", "node_precision", "inlier_ratio"):
            ax_val.plot([r["step"] for r in val_rows], [r[key] for r in val_rows], "-o", label=key)
    ax_loss.set(xlabel="step", ylabel="loss", title="losses")
    ax_val.set(xlabel="step", ylim=(0, 1), title="validation matching")
    ax_loss.legend(fontsize=8)
    ax_val.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
