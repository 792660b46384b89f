#!/usr/bin/env python
"""Fit the geometric pose's confidence and check its gates on pairs of rooms seen in training.

For every pair of the chosen settings and seeds (rooms seen in training only; the held-out
room never enters) it makes the geometric pose the pipeline would make after a refused dense
estimate (pose/geometric.py), with the semantic route's hypotheses as rivals, whatever the
semantic verdict said, and records its evidence and whether it is right (RMSE under the
benchmark's 0.2 m; different rooms: never). It prints how right and wrong poses spread over the
evidence, fits the logistic confidence (bias, footprint fitness, footprint share, ambiguity)
and shows what the shipped gates accept with the fitted weights and with the shipped ones.
Rivals (the semantic hypotheses and the pose's own turns) are rated for every pose, including
those the gates refuse before the pipeline would look for rivals. Output JSON keeps every pose.

    python scripts/choose_geometric.py --seeds 3 4 --settings frontend noisy different_rooms \
        --out results/choose_geometric.json
"""
from __future__ import annotations

import argparse
import json
from dataclasses import replace
from pathlib import Path

import numpy as np

from sgreg_core.bench.cases import CaseConfig, build_cases
from sgreg_core.geometry import invert_transform
from sgreg_core.metrics import registration_success
from sgreg_core.net.model import load_model
from sgreg_core.pipeline import PipelineConfig, build_graphs, node_cloud, reference_cloud
from sgreg_core.pose import ReferenceCloud
from sgreg_core.pose.estimator import pose_hypotheses
from sgreg_core.pose.geometric import geometric_confidence, geometric_estimate, judge_geometric
from sgreg_core.pose.verdict import Evidence

from choose_verdict import fit_logistic   # scripts/, beside this one

TRAINING_ROOMS = ("scene0000", "scene0001", "scene0002", "scene0003", "scene0004")


def poses(seeds, settings, cfg: PipelineConfig) -> list[dict]:
    model = load_model()
    pose_cfg = replace(cfg.pose, icp=True)
    # the pipeline rates rivals only for a pose the clouds support; the fit needs the ambiguity
    # of every pose, the gates are applied afterwards
    every_rival = replace(cfg.geometric, min_fitness=0.0, min_footprint_share=0.0)
    out = []
    for seed in seeds:
        cases = build_cases(CaseConfig(rooms=TRAINING_ROOMS, held_out_rooms=("scene0005",),
                                       rescan_gt="", n=60, seed=seed), tuple(settings))
        for i, case in enumerate(cases):
            sg, rg = build_graphs(case.src, case.ref, cfg)
            src, ref = model.encode(sg, dense=True), model.encode(rg, dense=True)
            pts = model.match_dense(src, ref, {}).points
            s, r = np.asarray(pts.src_xyz, np.float64), np.asarray(pts.ref_xyz, np.float64)
            w = np.asarray(pts.score, np.float64)
            rivals = pose_hypotheses(s, r, w, np.full(len(w), pose_cfg.noise_bound), pose_cfg) \
                if len(w) >= 3 else []
            reference = ReferenceCloud(reference_cloud(rg), pose_cfg.verify_voxel, pose_cfg.footprint_cell)
            geo = geometric_estimate(s, r, np.asarray(pts.node_match), node_cloud(sg), reference,
                                     rivals, pose_cfg, every_rival)
            if geo is None:
                continue
            right = case.T_gt is not None and bool(registration_success(
                case.src.points, invert_transform(rg.level.T) @ geo.T @ sg.level.T, case.T_gt, 0.2))
            ev = geo.evidence
            out.append({"case": case.name, "setting": case.setting, "seed": seed, "right": right,
                        "fitness": ev.fitness, "footprint_share": ev.footprint_share,
                        "ambiguity": ev.ambiguity, "objects": ev.objects})
            print(f"seed {seed} {i + 1}/{len(cases)} {case.setting} right={int(right)} "
                  f"fitness {ev.fitness:.2f} share {ev.footprint_share:.2f} "
                  f"ambiguity {ev.ambiguity:.2f}", flush=True)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[3, 4])
    ap.add_argument("--settings", nargs="+", default=["frontend", "noisy", "different_rooms"])
    ap.add_argument("--out", default="results/choose_geometric.json")
    args = ap.parse_args()
    cfg = PipelineConfig()
    rows = poses(args.seeds, args.settings, cfg)
    y = np.array([r["right"] for r in rows], float)
    X = np.array([[1.0, r["fitness"], r["footprint_share"], min(r["ambiguity"], 1.5)] for r in rows])
    print(f"\n{len(rows)} geometric poses, {int(y.sum())} right")
    for name, col in (("fitness", 1), ("footprint_share", 2), ("ambiguity", 3)):
        for label, sel in (("right", y == 1), ("wrong", y == 0)):
            v = X[sel, col]
            if v.size:
                print(f"  {name:16s} {label}: min {v.min():.2f} median {np.median(v):.2f} max {v.max():.2f}")
    w = fit_logistic(X, y, free_bias=True)
    print("fitted confidence_weights:", tuple(round(float(x), 3) for x in w))
    fitted = replace(cfg.geometric, confidence_weights=tuple(float(x) for x in w))
    for label, geo_cfg in (("fitted", fitted), ("shipped", cfg.geometric)):
        accepted = np.array([judge_geometric(Evidence(fitness=r["fitness"], footprint_share=r["footprint_share"],
                                                      ambiguity=r["ambiguity"]),
                                             cfg.pose.verdict, geo_cfg) == "ok" for r in rows])
        print(f"gates with the {label} weights: {int((accepted & (y == 1)).sum())} right and "
              f"{int((accepted & (y == 0)).sum())} wrong accepted, "
              f"{int((~accepted & (y == 1)).sum())} right refused")
    conf = np.array([geometric_confidence(Evidence(fitness=r["fitness"], footprint_share=r["footprint_share"],
                                                   ambiguity=r["ambiguity"]), fitted) for r in rows])
    for lo, hi in ((0, .1), (.1, .5), (.5, .9), (.9, 1.01)):
        sel = (conf >= lo) & (conf < hi)
        if sel.any():
            print(f"  confidence [{lo:.1f}, {min(hi, 1):.1f}): {int(sel.sum())} poses, {y[sel].mean():.2f} right")
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps({"weights": list(map(float, w)), "config": vars(args),
                                          "poses": rows}, indent=1))
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
