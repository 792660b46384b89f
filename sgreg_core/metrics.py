"""Evaluation metrics of the paper (section VII-A2).

Public API:
    rre(T_est, T_gt) -> float                 relative rotation error, degrees
    rte(T_est, T_gt) -> float                 relative translation error, metres
    registration_rmse(src_points, T_est, T_gt) -> float
        RMSE between the source points moved by T_est and by T_gt
    registration_success(src_points, T_est, T_gt, max_rmse=0.2) -> bool   registration recall
    SUCCESS_RTE_M, SUCCESS_RRE_DEG          the paper's two-agent criterion (0.5 m, 5 deg)
    two_agent_success(T_est, T_gt, max_rte=0.5, max_rre=5.0) -> bool
    inlier_ratio(src_pts, ref_pts, T_gt, threshold=0.1) -> float
        fraction of correspondences (row i of src_pts <-> row i of ref_pts) whose residual
        under T_gt is below threshold; 0.0 when there are none
    node_match_scores(pred_pairs, gt_pairs, gt_iou, min_iou=0.3) -> NodeMatchScore
        a predicted (src id, ref id) pair is true when its ground-truth IoU >= min_iou
    NodeMatchScore: true_positives, predicted, ground_truth, precision, recall
        (precision is nan with no prediction, recall nan with no ground-truth pair)
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .geometry import transform_points

__all__ = [
    "SUCCESS_RRE_DEG", "SUCCESS_RTE_M", "rre", "rte", "registration_rmse", "registration_success",
    "two_agent_success", "inlier_ratio", "NodeMatchScore", "node_match_scores",
]


def rre(T_est: np.ndarray, T_gt: np.ndarray) -> float:
    R = np.asarray(T_est)[:3, :3].T @ np.asarray(T_gt)[:3, :3]
    cos = np.clip((np.trace(R) - 1.0) / 2.0, -1.0, 1.0)
    return float(np.degrees(np.arccos(cos)))


def rte(T_est: np.ndarray, T_gt: np.ndarray) -> float:
    return float(np.linalg.norm(np.asarray(T_est)[:3, 3] - np.asarray(T_gt)[:3, 3]))


def registration_rmse(src_points: np.ndarray, T_est: np.ndarray, T_gt: np.ndarray) -> float:
    a = transform_points(T_est, np.asarray(src_points, dtype=np.float64))
    b = transform_points(T_gt, np.asarray(src_points, dtype=np.float64))
    return float(np.sqrt(np.mean(np.sum((a - b) ** 2, axis=1))))


def registration_success(src_points: np.ndarray, T_est: np.ndarray, T_gt: np.ndarray, max_rmse: float = 0.2) -> bool:
    return registration_rmse(src_points, T_est, T_gt) < max_rmse


# the paper's two-agent criterion: an estimate within both is right
SUCCESS_RTE_M, SUCCESS_RRE_DEG = 0.5, 5.0


def two_agent_success(T_est: np.ndarray, T_gt: np.ndarray, max_rte: float = SUCCESS_RTE_M,
                      max_rre: float = SUCCESS_RRE_DEG) -> bool:
    return rte(T_est, T_gt) < max_rte and rre(T_est, T_gt) < max_rre


def inlier_ratio(src_pts: np.ndarray, ref_pts: np.ndarray, T_gt: np.ndarray, threshold: float = 0.1) -> float:
    src_pts = np.asarray(src_pts, dtype=np.float64).reshape(-1, 3)
    ref_pts = np.asarray(ref_pts, dtype=np.float64).reshape(-1, 3)
    if len(src_pts) == 0:
        return 0.0
    residual = np.linalg.norm(transform_points(T_gt, src_pts) - ref_pts, axis=1)
    return float(np.mean(residual < threshold))


@dataclass
class NodeMatchScore:
    true_positives: int
    predicted: int
    ground_truth: int
    precision: float
    recall: float


def node_match_scores(pred_pairs: np.ndarray, gt_pairs: np.ndarray, gt_iou: np.ndarray, min_iou: float = 0.3) -> NodeMatchScore:
    """Node precision and recall; pairs are (src instance id, ref instance id) rows."""
    pred = np.asarray(pred_pairs, dtype=np.int64).reshape(-1, 2)
    gt = np.asarray(gt_pairs, dtype=np.int64).reshape(-1, 2)[np.asarray(gt_iou).reshape(-1) >= min_iou]
    gt_set = set(map(tuple, gt.tolist()))
    pred_set = set(map(tuple, pred.tolist()))
    tp = len(pred_set & gt_set)
    return NodeMatchScore(
        true_positives=tp,
        predicted=len(pred_set),
        ground_truth=len(gt_set),
        precision=tp / len(pred_set) if pred_set else float("nan"),
        recall=tp / len(gt_set) if gt_set else float("nan"),
    )
