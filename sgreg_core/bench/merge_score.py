"""Scoring the merged frame of N agents against ground truth (what `sgreg replay` reports as
"merge"): which agents are placed, whether a wrong link was kept, how far each merged pose is
from the truth. Pure: fed with the merger's result and a bag's ground truth.

A link is wrong when it is off by more than 0.5 m or 5 deg (the two-agent criterion); a merged
pose T_merged<-x is compared with T_anchor<-x of the ground truth (the merged frame is the
anchor's map frame).

Public API:
    merge_report(records, T_scene_map, poses=None, hold_s=1.0, cfg=None) -> (MergeResult, dict)
                                   the merge every agent's merger holds after these results
                                   (replay records) and its score, with "while_replayed": how
                                   long it held a wrong link or misplaced an agent during the bag
    score_merge(result, T_scene_map, poses=None) -> dict
"""
from __future__ import annotations

import numpy as np

from ..geometry import invert_transform
from ..metrics import SUCCESS_RRE_DEG, SUCCESS_RTE_M, rre, rte
from ..runtime.clock import seconds_to_ns
from ..runtime.merge import MergeConfig, MergeResult, Merger
from .replay_score import ground_truth

WRONG_M, WRONG_DEG = SUCCESS_RTE_M, SUCCESS_RRE_DEG


def merge_report(records, T_scene_map: dict, poses: dict | None = None, hold_s: float = 1.0,
                 cfg: MergeConfig | None = None) -> tuple[MergeResult, dict]:
    """The merge every agent's merger computes from these registration results (they all hear
    the same results, so they all hold this one) at the end of the bag, and its score_merge
    (poses: as published, see there) with "while_replayed": the merge re-scored after every
    result's bag time (it changes only when results come), each state held until the next one
    and the last for hold_s (a merge period); "seconds" scored, "wrong_s" the seconds it kept
    a wrong link or placed an agent off by more than the wrong-link criterion, and the
    "wrong_windows" [start, end) in bag seconds. The nodes merge once a merge period, so this
    bounds what /tf carried from above: a wrong link held for less than a period may never
    have reached it. cfg: the merge settings the agents ran (default MergeConfig())."""
    agents = sorted(T_scene_map)
    merger = Merger(cfg or MergeConfig(), min(agents))
    merger.links.agents |= set(agents)
    records = sorted(records, key=lambda r: r.bag_t if r.bag_t is not None else r.t)
    stamp = [r.bag_t if r.bag_t is not None else r.t for r in records]
    wrong_s, windows = 0.0, []
    for i, r in enumerate(records):
        # a result that states no confidence (older bags) weighs as a sure one
        confidence = r.confidence if np.isfinite(r.confidence) else 1.0
        # links age by their maps' stamps, as in the nodes (older records: their bag time)
        merger.take(r.agent, r.peer, r.T, r.verified, r.reason, r.link, confidence,
                    r.stamp_ns if r.stamp_ns is not None else seconds_to_ns(stamp[i]))
        if i + 1 < len(records) and stamp[i + 1] == stamp[i]:
            continue                      # results of one instant are merged together
        merger.update()
        s = score_merge(merger.result, T_scene_map)
        off = s["max_pose_error_m"] is not None and (s["max_pose_error_m"] > WRONG_M
                                                      or s["max_pose_error_deg"] > WRONG_DEG)
        if s["wrong_links_kept"] or off:
            start, end = float(stamp[i]), float(stamp[i + 1] if i + 1 < len(records) else stamp[i] + hold_s)
            wrong_s += end - start
            if windows and windows[-1][1] == start:
                windows[-1][1] = end
            else:
                windows.append([start, end])
    seconds = float(stamp[-1] + hold_s - stamp[0]) if records else 0.0
    timeline = {"seconds": seconds, "wrong_s": wrong_s, "wrong_windows": windows}
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
    # the anchor is placed by definition: with no other agent attached, no pose error was measured
    placed = [e for a, e in errors.items() if a != result.anchor]
    return {
        "agents": len(T_scene_map),
        "attached": len(poses),
        "anchor": result.anchor,
        "wrong_links_kept": len(wrong),
        "wrong_links": wrong,
        "links_kept": len(result.accepted),
        "links_rejected": len(result.rejected),
        "right_links_rejected": rejected_right,
        "max_pose_error_m": max((e[0] for e in placed), default=None),
        "max_pose_error_deg": max((e[1] for e in placed), default=None),
        "pose_errors": {a: {"m": round(e[0], 4), "deg": round(e[1], 3)} for a, e in errors.items()},
    }
