#!/usr/bin/env python
"""Where estimates of a single-capture bag lose the right pose: matcher, or evidence?

For every map update of a bag (both agents' latest maps at that time) and both directions, the
matches are compared with the truth and the estimator is run twice: on every match, as sgreg
does, and on the right matches only (an oracle that needs ground truth, so never part of
sgreg's own code path). Coarse: node matches, right when both nodes are the same instance (a
bag made from one capture, synthetic or real) and their centers lie within the coarse noise
bound at the true pose. Dense: point matches of both whole graphs (as `sgreg register`; the
runtime asks for the best matched nodes only), right within `--true-m` of the truth.

    oracle refused   the right matches alone are too few, or the clouds do not back their
                     pose: a better matcher or more map is what the update needs (the oracle is
                     the estimator's first pass, so the pipeline's later passes, guided point
                     matching and the clouds' geometry, may still find the pose)
    oracle passes    the matches hold the right pose and the estimate missed it: the estimator
                     (its candidates, its clique search) is where to look

Prints one line per update and direction, then a tally, and writes JSON (minutes per bag: the
dense route matches whole graphs). Run it on rooms seen in training or on synthetic scenes only
when choosing anything from it.

    python scripts/diagnose_bag_matches.py bags/generated/synthetic/synth_apartment2_11_fast_same_s2
"""
from __future__ import annotations

import argparse
import json
from collections import Counter
from itertools import permutations
from pathlib import Path

import numpy as np

from sgreg_cli.bags import instance_maps_in_bag
from sgreg_core.geometry import invert_transform
from sgreg_core.metrics import two_agent_success
from sgreg_core.net.model import load_model
from sgreg_core.pipeline import PipelineConfig, build_graphs, node_cloud, reference_cloud, register_graphs
from sgreg_core.pose import residuals
from sgreg_core.pose import apply_T
from sgreg_core.pose.estimator import estimate_pose


def _outcome(res, T_true) -> dict:
    """res: a pipeline Registration (its T_levelled) or an estimator PoseResult (its T), both
    between the levelled graphs, as T_true."""
    T = res.T_levelled if hasattr(res, "T_levelled") else res.T
    return {"reason": res.reason, "confidence": float(res.confidence), "objects": int(res.evidence.objects),
            "fitness": float(res.evidence.fitness), "footprint_share": float(res.evidence.footprint_share),
            "right": two_agent_success(T, T_true)}


def _oracle(src_c, ref_c, scores, groups, src_graph, ref_graph, cfg: PipelineConfig, T_true) -> dict:
    """The estimate from the right matches alone."""
    if len(src_c) == 0:
        return {"reason": "no_right_matches", "right": False, "confidence": 0.0, "objects": 0}
    return _outcome(estimate_pose(src_c, ref_c, scores, node_cloud(src_graph), reference_cloud(ref_graph),
                                  cfg.pose_config(), groups=groups), T_true)


def diagnose(model, src_map, ref_map, T_src_ref_true: np.ndarray, true_m: float) -> dict:
    """One direction at one time: coarse and dense matches against the truth, and the estimates
    from all of them and from the right ones alone."""
    coarse, dense = PipelineConfig(mode="coarse"), PipelineConfig()
    src_graph, ref_graph = build_graphs(src_map, ref_map, coarse)
    T = ref_graph.level.T @ T_src_ref_true @ invert_transform(src_graph.level.T)   # levelled frames
    src, ref = model.encode(src_graph, dense=True), model.encode(ref_graph, dense=True)
    src_ids, ref_ids = np.asarray(src.node_ids), np.asarray(ref.node_ids)

    nodes = model.match_coarse(src, ref)
    src_c, ref_c = np.asarray(nodes.src_xyz, np.float64), np.asarray(nodes.ref_xyz, np.float64)
    same = src_ids[nodes.src_idx] == ref_ids[nodes.ref_idx]
    near = same & (np.linalg.norm(apply_T(T, src_c) - ref_c, axis=1) <= coarse.coarse_pose.noise_bound)

    pts = model.match_dense(src, ref).points
    src_p, ref_p = np.asarray(pts.src_xyz, np.float64), np.asarray(pts.ref_xyz, np.float64)
    true = residuals(T, src_p, ref_p) <= true_m
    groups = np.asarray(pts.node_match, np.int64)
    return {"nodes": [int(src_ids.size), int(ref_ids.size)],
            "shared": int(np.intersect1d(src_ids, ref_ids).size),
            "node_matches": int(same.size), "same_instance": int(same.sum()), "right_within_bound": int(near.sum()),
            "coarse": _outcome(register_graphs(model, src_graph, ref_graph, coarse), T),
            "coarse_oracle": _oracle(src_c[near], ref_c[near], np.asarray(nodes.score, np.float64)[near],
                                     np.flatnonzero(near), src_graph, ref_graph, coarse, T),
            "point_matches": int(true.size), "right_points": int(true.sum()),
            "right_point_objects": int(np.unique(groups[true]).size),
            "dense": _outcome(register_graphs(model, src_graph, ref_graph, dense), T),
            "dense_oracle": _oracle(src_p[true], ref_p[true], np.asarray(pts.score, np.float64)[true],
                                    groups[true], src_graph, ref_graph, dense, T)}


def _verdict(row: dict, route: str) -> str:
    """What holds the route back at this update (see the module docstring)."""
    if row[route]["reason"] == "ok":
        return "passes" if row[route]["right"] else "WRONG passes"
    return "oracle passes" if row[f"{route}_oracle"]["reason"] == "ok" else "oracle refused"


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("bag", help="a bag folder with ground_truth.json, made from one capture")
    ap.add_argument("--true-m", type=float, default=0.1, help="a point match this close is right")
    ap.add_argument("--out", default="results/bag_matches.json")
    args = ap.parse_args()
    gt = json.loads((Path(args.bag) / "ground_truth.json").read_text())
    if gt.get("scan_b") not in (None, "None"):
        raise SystemExit(f"{args.bag}: agent b walks another capture, whose instance ids are not "
                         "a's; this diagnosis needs a bag made from one capture")
    T_scene = {k: np.asarray(v, np.float64) for k, v in gt["T_scene_map"].items()}
    model = load_model()
    latest, rows = {}, []
    for t, agent, imap in instance_maps_in_bag(args.bag, gt.get("t_origin", 0.0)):
        latest[agent] = imap
        for src, ref in permutations(sorted(latest), 2):
            T_true = invert_transform(T_scene[ref]) @ T_scene[src]
            row = {"t": round(t, 2), "src": src, "ref": ref,
                   **diagnose(model, latest[src], latest[ref], T_true, args.true_m)}
            rows.append(row)
            print(f"{t:6.1f} {src}->{ref} nodes {row['nodes'][0]:3d}/{row['nodes'][1]:3d} "
                  f"shared {row['shared']:3d} | coarse: right {row['right_within_bound']:2d} of "
                  f"{row['node_matches']:3d}, {_verdict(row, 'coarse'):14s} | dense: right points "
                  f"{row['right_points']:4d} of {row['point_matches']:4d} on "
                  f"{row['right_point_objects']:2d} objects, {_verdict(row, 'dense'):14s} "
                  f"(oracle {row['dense_oracle']['reason']}, conf "
                  f"{row['dense_oracle']['confidence']:.2f})", flush=True)
    tally = {route: dict(Counter(_verdict(r, route) for r in rows)) for route in ("coarse", "dense")}
    print(f"{len(rows)} updates x directions:", tally)
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps({"bag": args.bag, "true_m": args.true_m, "tally": tally,
                                          "rows": rows}, indent=1) + "\n")
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
