#!/usr/bin/env python
"""Choose the verdict's thresholds and fit its confidence from offline replays.

Input: `sgreg bench-replay --backend offline` result folders run with a permissive verdict (every
estimate judged, none refused, no confirmation; see docs/VERDICT.md for the command), so that
every estimate carries its full evidence, and optionally `sgreg bench-register` result folders
of rooms seen in training (--register DIR: pairs with every front-end error, each estimate
with its evidence whatever the verdict). Held-out rooms are left out: thresholds are chosen on
rooms seen in training and on synthetic scenes only.

For dense and coarse/merged estimates separately it prints how right and wrong estimates spread
over each piece of evidence, then, over a grid of thresholds, how many wrong estimates each
setting would still accept and how many right ones it would refuse, the shipped setting first
(the grid's minimum confidence applies the confidence the replay recorded, i.e. the shipped
weights). Last it fits the logistic confidence (pose/verdict.py `confidence`) on every estimate
and prints its weights.

    python scripts/choose_verdict.py RESULTS_DIR [RESULTS_DIR ...] [--register DIR ...]
                                     [--held-out scene0005] [--refit] [--min-objects K]
                                     [--fix ambiguity=-2.353 ...]
"""
from __future__ import annotations

import argparse
import itertools
import json
from pathlib import Path

import numpy as np

from sgreg_core.pipeline import PipelineConfig

FEATURES = ("objects", "inliers", "spread", "fitness", "footprint_share", "ambiguity", "inlier_ratio")


def load_frames(dirs: list[str], held_out: list[str]) -> list[dict]:
    frames = []
    for d in dirs:
        for path in sorted(Path(d, "bags").glob("*.json")):
            if any(room in path.stem for room in held_out):
                continue
            for f in json.loads(path.read_text())["frames"]:
                ev = f.get("evidence") or {}
                if "objects" not in ev or f["reason"] in ("too_few_matches", "no_peer_cloud_to_verify",
                                                          "too_few_nodes", "no_node_matches"):
                    continue
                frames.append({**{k: float(ev.get(k) if ev.get(k) is not None else np.nan)
                                  for k in FEATURES},
                               "confidence": float(f.get("confidence", np.nan)),
                               "mode": f["mode"], "correct": bool(f["correct"]), "bag": path.stem})
    return frames


def load_register_rows(dirs: list[str], held_out: list[str]) -> list[dict]:
    """sgreg rows of bench-register results, rooms seen in training only; right = RMSE under
    the benchmark's threshold (different rooms: never right)."""
    frames = []
    for d in dirs:
        for r in json.loads(Path(d, "results.json").read_text())["rows"]:
            ev = r.get("evidence")
            if not r["method"].startswith("sgreg") or not ev or r.get("held_out") \
                    or any(room in r["case"] for room in held_out) or r["reason"] in ("too_few_nodes", "no_node_matches"):
                continue
            frames.append({**{k: float(ev.get(k) if ev.get(k) is not None else np.nan) for k in FEATURES},
                           "confidence": float(r.get("confidence", np.nan)),
                           "mode": "dense" if r["method"] == "sgreg_dense" else "coarse",
                           "correct": bool(r["success"]), "bag": f"{d}:{r['setting']}"})
    return frames


def describe(frames: list[dict]) -> None:
    ok = [f for f in frames if f["correct"]]
    bad = [f for f in frames if not f["correct"]]
    print(f"  {len(ok)} right, {len(bad)} wrong estimates")
    for k in FEATURES:
        a = np.array([f[k] for f in ok])
        b = np.array([f[k] for f in bad])
        q = lambda v: " ".join(f"{x:6.2f}" for x in np.nanpercentile(v, [5, 25, 50, 75, 95])) if len(v) else "-"
        print(f"  {k:16s} right p5..p95 {q(a)}   wrong p5..p95 {q(b)}")


def grid(frames: list[dict], min_inliers: int, shipped: tuple, min_objects: int = 2) -> None:
    ok = np.array([f["correct"] for f in frames])
    x = {k: np.nan_to_num(np.array([f[k] for f in frames]), nan=0.0)
         for k in FEATURES + ("confidence",)}

    def accepted(objects, fit, share, amb, spread, conf):
        return ((x["inliers"] >= min_inliers) & (x["objects"] >= objects) & (x["fitness"] >= fit)
                & (x["footprint_share"] >= share) & (x["ambiguity"] < amb) & (x["spread"] >= spread)
                & (x["confidence"] >= conf))

    rows = []
    for t in itertools.product([k for k in (2, 3, 4, 5) if k >= min_objects], (0.5, 0.55, 0.6, 0.65, 0.7), (0.1, 0.2, 0.3),
                               (0.5, 0.6, 0.7, 0.8, 1.0), (0.1, 0.2, 0.3), (0.0, 0.5, 0.8, 0.9, 0.95)):
        acc = accepted(*t)
        rows.append((int((acc & ~ok).sum()), -int((acc & ok).sum()), *t))
    rows.sort()
    head = "objects fitness share ambiguity< spread confidence"
    print(f"  {'wrong accepted':>14} {'right accepted':>14}  {head}   (of {int(ok.sum())} right)")
    acc = accepted(*shipped)
    for wrong, right, *t in [(int((acc & ~ok).sum()), -int((acc & ok).sum()), *shipped)] + rows[:12]:
        print(f"  {wrong:14d} {-right:14d}  {t[0]:7d} {t[1]:7.2f} {t[2]:5.2f} {t[3]:10.2f} {t[4]:6.2f}"
              f" {t[5]:10.2f}{'   <- shipped' if tuple(t) == tuple(shipped) else ''}")


def design(frames: list[dict]) -> np.ndarray:
    def col(k, default=0.0):
        return np.nan_to_num(np.array([f[k] for f in frames]), nan=default)
    return np.stack([np.ones(len(frames)), np.log1p(col("objects")), col("fitness"),
                     col("footprint_share"), np.minimum(col("ambiguity"), 1.5), col("inlier_ratio")], 1)


WEIGHTS = ("bias", "objects", "fitness", "share", "ambiguity", "inlier_ratio")   # design()'s columns


def fit_logistic(X: np.ndarray, y: np.ndarray, l2: float = 1e-2, iters: int = 50,
                 free_bias: bool = False, fixed: dict[int, float] | None = None) -> np.ndarray:
    """Newton's method on the L2-regularised log-likelihood; free_bias: the first column (the
    bias) is not regularised (where the classes separate, the bias must run free); fixed:
    column -> weight held at that value (its term enters as an offset)."""
    fixed = fixed or {}
    free = [j for j in range(X.shape[1]) if j not in fixed]
    offset = sum(X[:, j] * v for j, v in fixed.items()) if fixed else np.zeros(len(X))
    Xf = X[:, free]
    w = np.zeros(len(free))
    reg = np.full(len(free), l2)
    if free_bias and 0 in free:
        reg[free.index(0)] = 0.0
    for _ in range(iters):
        p = 1 / (1 + np.exp(-(Xf @ w + offset)))
        g = Xf.T @ (p - y) + reg * w
        H = Xf.T @ (Xf * (p * (1 - p))[:, None]) + np.diag(reg)
        step = np.linalg.solve(H, g)
        w -= step
        if np.abs(step).max() < 1e-8:
            break
    out = np.zeros(X.shape[1])
    out[free] = w
    for j, v in fixed.items():
        out[j] = v
    return out


def parse_fixed(items: list[str]) -> dict[int, float]:
    """["ambiguity=-2.353"] -> {4: -2.353}."""
    fixed = {}
    for item in items:
        name, _, value = item.partition("=")
        if name not in WEIGHTS or not value:
            raise SystemExit(f"--fix {item!r}: expected NAME=VALUE, NAME one of {', '.join(WEIGHTS)}")
        fixed[WEIGHTS.index(name)] = float(value)
    return fixed


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("dirs", nargs="+")
    p.add_argument("--register", nargs="*", default=[], help="bench-register result folders")
    p.add_argument("--held-out", nargs="*", default=["scene0005"])
    p.add_argument("--refit", action="store_true",
                   help="judge the grid's minimum confidence with the weights fitted here")
    p.add_argument("--min-objects", type=int, default=2, help="grid rows with fewer objects are not shown")
    p.add_argument("--fix", nargs="*", default=[], metavar="NAME=VALUE",
                   help=f"hold a confidence weight at a value while fitting the rest ({', '.join(WEIGHTS)})")
    args = p.parse_args()
    fixed = parse_fixed(args.fix)
    frames = load_frames(args.dirs, args.held_out) + load_register_rows(args.register, args.held_out)
    print(f"{len(frames)} estimates from {len({f['bag'] for f in frames})} bags "
          f"(held-out rooms {args.held_out} left out)")
    X, y = design(frames), np.array([f["correct"] for f in frames], float)
    w = fit_logistic(X, y, fixed=fixed)
    p_hat = 1 / (1 + np.exp(-X @ w))
    if args.refit:      # the grid judges the confidence the refitted weights give
        for f, p_f in zip(frames, p_hat):
            f["confidence"] = float(p_f)
    shipped = PipelineConfig()
    for name, modes, v in (("dense", ("dense",), shipped.pose.verdict),
                           ("coarse", ("coarse",), shipped.coarse_pose.verdict),
                           ("merged (published only when they agree with a confirmed link)", ("merged",),
                            shipped.coarse_pose.verdict)):
        sel = [f for f in frames if f["mode"] in modes]
        print(f"\n{name}:")
        describe(sel)
        grid(sel, v.min_inliers, (v.min_objects, v.min_fitness, v.min_footprint_share,
                                  v.max_ambiguity, v.min_spread, v.min_confidence), args.min_objects)
    edges = np.linspace(0, 1, 11)
    idx = np.clip(np.digitize(p_hat, edges[1:-1]), 0, 9)
    ece = sum(abs(p_hat[idx == b].mean() - y[idx == b].mean()) * (idx == b).sum()
              for b in range(10) if (idx == b).any()) / len(y)
    print(f"\nconfidence weights (bias, log1p objects, fitness, footprint share, ambiguity, "
          f"inlier ratio): ({', '.join(f'{c:.3f}' for c in w)})  training ECE {ece:.3f}")


if __name__ == "__main__":
    main()
