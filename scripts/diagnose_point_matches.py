#!/usr/bin/env python
"""Where dense estimates of bench-register pairs lose their right pose (docs/VERDICT.md
section 8): for every pair, the node matches that are right (ground-truth node pairs), how many
learned point matches each gives and how many of those lie within 10 cm of the truth, and how
far apart its node centers lie at the true pose. Prints a table per setting and writes JSON.
Run it on rooms seen in training only when choosing anything from it.

    python scripts/diagnose_point_matches.py --rooms scene0000 scene0001 scene0002 scene0003 \
        scene0004 --n 60 --seed 3 --settings frontend noisy --out results/point_matches.json
"""
from __future__ import annotations

import argparse
import json
from dataclasses import replace
from pathlib import Path

import numpy as np

from sgreg_core.bench.cases import CaseConfig, build_cases
from sgreg_core.geometry import invert_transform
from sgreg_core.net.model import load_model
from sgreg_core.pipeline import PipelineConfig, build_graphs, register_graphs
from sgreg_core.pose import apply_T, residuals
from sgreg_core.pose.guided import GuidedConfig


def diagnose(model, case, cfg: PipelineConfig, true_m: float) -> dict:
    src_graph, ref_graph = build_graphs(case.src, case.ref, cfg)
    # the truth between the levelled frames the graphs were built in
    T = ref_graph.level.T @ case.T_gt @ invert_transform(src_graph.level.T)
    src, ref = model.encode(src_graph, dense=True), model.encode(ref_graph, dense=True)
    dm = model.match_dense(src, ref)
    nodes, pts = dm.nodes, dm.points
    gt = {tuple(p) for p in case.gt_node_pairs.tolist()}
    pairs = [(int(src.node_ids[i]), int(ref.node_ids[j])) for i, j in zip(nodes.src_idx, nodes.ref_idx)]
    true = residuals(T, np.asarray(pts.src_xyz, np.float64), np.asarray(pts.ref_xyz, np.float64)) <= true_m
    center_err = np.linalg.norm(apply_T(T, np.asarray(nodes.src_xyz, np.float64))
                                - np.asarray(nodes.ref_xyz, np.float64), axis=1)
    right = [k for k, p in enumerate(pairs) if p in gt]
    plain = register_graphs(model, src_graph, ref_graph, replace(cfg, guided=GuidedConfig(enabled=False)))
    reg = register_graphs(model, src_graph, ref_graph, cfg)
    return {"case": case.name, "setting": case.setting, "success_without_guided": bool(plain.success),
            "reason_without_guided": plain.reason, "success": bool(reg.success), "reason": reg.reason,
            "guided": bool(reg.guided), "node_matches": len(pairs),
            "right_node_matches": len(right),
            "right_with_true_point_match": int(sum(true[pts.node_match == k].any() for k in right)),
            "right_within_0.5m": int(sum(center_err[k] <= 0.5 for k in right)),
            "point_matches_of_right": int(sum((pts.node_match == k).sum() for k in right)),
            "true_point_matches_of_right": int(sum(true[pts.node_match == k].sum() for k in right))}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--rooms", nargs="+", required=True)
    ap.add_argument("--n", type=int, default=60)
    ap.add_argument("--seed", type=int, default=3)
    ap.add_argument("--settings", nargs="+", default=["frontend", "noisy"])
    ap.add_argument("--true-m", type=float, default=0.1, help="a point match this close is right")
    ap.add_argument("--out", default="results/point_matches.json")
    args = ap.parse_args()
    cfg = CaseConfig(rooms=tuple(args.rooms), n=args.n, seed=args.seed, rescan_gt="")
    model, pipeline = load_model(), PipelineConfig()
    rows = []
    cases = build_cases(cfg, tuple(args.settings))
    for k, case in enumerate(cases, 1):
        rows.append(diagnose(model, case, pipeline, args.true_m))
        print(f"\r{k}/{len(cases)} {case.name}", end="", flush=True)
    print()
    print("refused: without guided matching; right: >= 3 right node matches; starved: of those, "
          "<= 1 with a true point match; near: >= 3 right centers within 0.5 m")
    print("setting    pairs  refused  right  starved  near  guided successes")
    for setting in args.settings:
        rs = [r for r in rows if r["setting"] == setting]
        refused = [r for r in rs if not r["success_without_guided"]]
        three = [r for r in refused if r["right_node_matches"] >= 3]
        starved = sum(r["right_with_true_point_match"] <= 1 for r in three)
        near = sum(r["right_within_0.5m"] >= 3 for r in three)
        print(f"{setting:9s} {len(rs):6d} {len(refused):8d} {len(three):6d} {starved:8d} {near:5d}"
              f" {sum(r['guided'] for r in rs):17d}")
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps({"args": vars(args), "rows": rows}, indent=1) + "\n")
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
