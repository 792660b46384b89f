"""Scoring a two-agent replay: every registration result the agents published, against the
ground truth of the bag. Pure: fed with plain records, knows nothing of ROS.

A query frame is one published result (one estimate attempt of one agent). It succeeds when its
estimate is within RTE < 0.5 m and RRE < 5 deg (the paper's two-agent criterion). `success_rate`
counts only verified estimates, the ones a user would act on; `success_rate_any` counts every
estimate that met the criterion, verified or not, which is the paper's definition.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass, field

import numpy as np

from .geometry import invert_transform
from .metrics import rre, rte, two_agent_success


@dataclass
class ResultRecord:
    t: float              # s since the replay started
    agent: str
    peer: str
    T: np.ndarray         # estimated T_agent^peer
    verified: bool
    mode: str
    reason: str
    node_matches: int
    inliers: int
    total_ms: float


@dataclass
class FrameScore:
    t: float
    agent: str
    peer: str
    mode: str
    verified: bool
    reason: str
    rte: float
    rre: float
    success: bool
    total_ms: float


@dataclass
class ReplayScore:
    query_frames: int
    success_rate: float
    success_rate_any: float
    wrong_verified: int
    verified: int
    first_success_s: float | None
    median_rte_verified: float | None
    median_rre_verified: float | None
    coarse_latency_ms: dict
    dense_latency_ms: dict
    frames: list = field(default_factory=list)

    def to_dict(self) -> dict:
        d = asdict(self)
        d["frames"] = [asdict(f) for f in self.frames]
        return d


def ground_truth(T_scene_map: dict, agent: str, peer: str) -> np.ndarray:
    """T_agent^peer from each agent's map frame in the scene frame."""
    return invert_transform(np.asarray(T_scene_map[peer])) @ np.asarray(T_scene_map[agent])


def _latency(values: list[float]) -> dict:
    if not values:
        return {"n": 0, "median": None, "p90": None}
    v = np.asarray(values)
    return {"n": int(v.size), "median": float(np.median(v)), "p90": float(np.percentile(v, 90))}


def score_replay(records: list[ResultRecord], T_scene_map: dict) -> ReplayScore:
    frames = []
    for r in sorted(records, key=lambda r: r.t):
        gt = ground_truth(T_scene_map, r.agent, r.peer)
        e_t, e_r = float(rte(r.T, gt)), float(rre(r.T, gt))
        ok = two_agent_success(r.T, gt)
        frames.append(FrameScore(r.t, r.agent, r.peer, r.mode, r.verified, r.reason, e_t, e_r, ok, r.total_ms))
    n = len(frames)
    good = [f for f in frames if f.verified and f.success]
    verified = [f for f in frames if f.verified]
    return ReplayScore(
        query_frames=n,
        success_rate=len(good) / n if n else 0.0,
        success_rate_any=sum(f.success for f in frames) / n if n else 0.0,
        wrong_verified=sum(f.verified and not f.success for f in frames),
        verified=len(verified),
        first_success_s=good[0].t if good else None,
        median_rte_verified=float(np.median([f.rte for f in verified])) if verified else None,
        median_rre_verified=float(np.median([f.rre for f in verified])) if verified else None,
        coarse_latency_ms=_latency([f.total_ms for f in frames if f.mode in ("coarse", "merged")]),
        dense_latency_ms=_latency([f.total_ms for f in frames if f.mode == "dense"]),
        frames=frames,
    )
