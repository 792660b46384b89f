"""Scoring the merged frame of N agents against ground truth (what `sgreg replay` reports as
"merge"): which agents are placed, whether a wrong link was kept, how far each merged pose is
from the truth. Pure: fed with the merger's result and a bag's ground truth.

A link is wrong when it is off by more than 0.5 m or 5 deg (the two-agent criterion); a merged
pose T_merged<-x is compared with T_anchor<-x of the ground truth (the merged frame is the
anchor's map frame).

Public API:
    merge_report(records, T_scene_map, poses=None, step_s=1.0, cfg=None) -> (MergeResult, dict)
                                   the merge every agent's merger holds after these results
                                   (replay records) and its score, with "while_replayed": how
                                   long it held a wrong link or misplaced an agent during the bag
    score_merge(result, T_scene_map, poses=None) -> dict
"""
from __future__ import annotations

import numpy as np

from ..geometry import invert_transform
from ..metrics import rre, rte
from ..runtime.clock import seconds_to_ns
from ..runtime.merge import MergeConfig, MergeResult, Merger
from .replay_score import ground_truth

WRONG_M, WRONG_DEG = 0.5, 5.0


def merge_report(records, T_scene_map: dict, poses: dict | None = None, step_s: float = 1.0,
                 cfg: MergeConfig | None = None) -> tuple[MergeResult, dict]:
    """The merge every agent's merger computes from these registration results (they all hear
    the same results, so they all hold this one) at the end of the bag, and its score_merge
    (poses: as published, see there) with "while_replayed": the same merge re-scored every
    step_s of bag time, "seconds" scored, "wrong_s" the seconds it kept a wrong link or placed
    an agent off by more than the wrong-link criterion (what /tf carried then: a robot acting
    on the merged map acts on that), and the "wrong_windows" [start, end] in bag seconds."""
    agents = sorted(T_scene_map)
    merger = Merger(cfg or MergeConfig(), min(agents))
    merger.links.agents |= set(agents)
    records = sorted(records, key=lambda r: r.t)     # bag time grows with replay time
    stamp = [r.bag_t if r.bag_t is not None else r.t for r in records]
    steps = np.arange(stamp[0], stamp[-1] + step_s, step_s) if records else np.zeros(0)
    i, wrong, windows = 0, 0, []

    def take_until(t: float) -> None:
        nonlocal i
        while i < len(records) and stamp[i] <= t:
            r = records[i]
            # a result that states no confidence (older bags) weighs as a sure one
            confidence = r.confidence if np.isfinite(r.confidence) else 1.0
            merger.take(r.agent, r.peer, r.T, r.verified, r.reason, r.link, confidence, seconds_to_ns(stamp[i]))
            i += 1
        merger.update()

    for t in steps:
        take_until(t)
        s = score_merge(merger.result, T_scene_map)
        off = s["max_pose_error_m"] is not None and (s["max_pose_error_m"] > WRONG_M
                                                      or s["max_pose_error_deg"] > WRONG_DEG)
        if s["wrong_links_kept"] or off:
            wrong += 1
            if windows and abs(windows[-1][1] - (t - step_s)) < 1e-9:
                windows[-1][1] = float(t)
            else:
                windows.append([float(t), float(t)])
    take_until(np.inf)
    timeline = {"seconds": float(len(steps) * step_s), "wrong_s": float(wrong * step_s),
                "wrong_windows": windows}
    return merger.result, {**score_merge(merger.result, T_scene_map, poses), "while_replayed": timeline}


def score_merge(result: MergeResult, T_scene_map: dict, poses: dict | None = None) -> dict:
    """poses: the merged poses as published (agent -> T_merged<-agent, e.g. read off /tf);
    default the result's own."""
    poses = result.poses if poses is None else poses
    wrong = []
    for link in result.accepted:
        gt = ground_truth(T_scene_map, link.src, link.dst)
        if rte(link.T, gt) > WRONG_M or rre(link.T, gt) > WRONG_DEG:
            wrong.append(f"{link.src}->{link.dst}")
    errors = {}
    if result.anchor is not None:
        anchor = np.asarray(T_scene_map[result.anchor], np.float64)
        for agent, T in sorted(poses.items()):
            gt = invert_transform(anchor) @ np.asarray(T_scene_map[agent], np.float64)
            errors[agent] = (float(rte(T, gt)), float(rre(T, gt)))
    rejected_right = [f"{l.src}->{l.dst}" for l, _ in result.rejected
                      if rte(l.T, ground_truth(T_scene_map, l.src, l.dst)) <= WRONG_M
                      and rre(l.T, ground_truth(T_scene_map, l.src, l.dst)) <= WRONG_DEG]
    return {
        "agents": len(T_scene_map),
        "attached": len(poses),
        "anchor": result.anchor,
        "wrong_links_kept": len(wrong),
        "wrong_links": wrong,
        "links_kept": len(result.accepted),
        "links_rejected": len(result.rejected),
        "right_links_rejected": rejected_right,
        "max_pose_error_m": max((e[0] for e in errors.values()), default=None),
        "max_pose_error_deg": max((e[1] for e in errors.values()), default=None),
        "pose_errors": {a: {"m": round(e[0], 4), "deg": round(e[1], 3)} for a, e in errors.items()},
    }
