"""Matching quality of a model on pairs with ground truth (validation and bench-match).

Per pair: node recall / precision of the dual-softmax node matches against the gt node pairs
(IoU >= min_iou), inlier ratio of the point correspondences (residual under the gt transform
below inlier_threshold), counts, and the time of every stage.

Public API:
    evaluate_pairs(model, pairs, min_iou=0.3, inlier_threshold=0.1) -> list of per-pair dicts
    summarize(rows) -> dict of means (nan-aware), medians for timings
"""
from __future__ import annotations

import numpy as np

from ..metrics import inlier_ratio, node_match_scores
from .dataset import GraphPair
from .model import SGRegModel

ENCODE_STAGES = ("text", "sample", "shape", "gnn")
MATCH_STAGES = ("node_match", "point_match")


def evaluate_pairs(model: SGRegModel, pairs: list[GraphPair], min_iou: float = 0.3,
                   inlier_threshold: float = 0.1) -> list[dict]:
    rows = []
    for pair in pairs:
        t_src, t_ref, t_match = {}, {}, {}
        src = model.encode(pair.src, timings=t_src)
        ref = model.encode(pair.ref, timings=t_ref)
        dm = model.match_dense(src, ref, timings=t_match)
        pred = np.stack([dm.nodes.src_idx, dm.nodes.ref_idx], axis=1)
        nodes = node_match_scores(pred, pair.gt, pair.gt_iou, min_iou)
        row = {
            "source": pair.source,
            "nodes_src": pair.src.num_nodes, "nodes_ref": pair.ref.num_nodes,
            "gt_matches": nodes.ground_truth, "node_matches": nodes.predicted,
            "node_recall": nodes.recall, "node_precision": nodes.precision,
            "point_matches": len(dm.points),
            "inlier_ratio": (inlier_ratio(dm.points.src_xyz, dm.points.ref_xyz, pair.T_src_ref,
                                          inlier_threshold) if len(dm.points) else float("nan")),
        }
        for stage in ENCODE_STAGES:  # per graph
            row[f"ms_{stage}"] = (t_src.get(stage, 0.0) + t_ref.get(stage, 0.0)) / 2
        for stage in MATCH_STAGES:
            row[f"ms_{stage}"] = t_match.get(stage, 0.0)
        # the coarse path of one graph: label encoding + GNN, then node matching (the DESIGN's
        # < 20 ms budget); the shape network and point matching belong to the dense path
        row["ms_coarse_path"] = row["ms_text"] + row["ms_gnn"] + row["ms_node_match"]
        rows.append(row)
    return rows


def summarize(rows: list[dict]) -> dict:
    """Means over pairs (nan = undefined for that pair, skipped); medians for timings."""
    out: dict = {"pairs": len(rows)}
    if not rows:
        return out
    for key, value in rows[0].items():
        if isinstance(value, str):
            continue
        values = np.array([r[key] for r in rows], dtype=np.float64)
        finite = values[np.isfinite(values)]
        if key.startswith("ms_"):
            out[key] = float(np.median(finite)) if len(finite) else float("nan")
        else:
            out[key] = float(finite.mean()) if len(finite) else float("nan")
    return out
