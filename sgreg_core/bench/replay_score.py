"""Scoring a multi-agent replay: every registration result the agents published, against the
ground truth of the bag. Pure: fed with plain records, knows nothing of ROS.

A query frame is one published result (one estimate attempt of one agent). It succeeds when its
estimate is verified and within RTE < 0.5 m and RRE < 5 deg (the paper's two-agent criterion
on the estimates a user would act on); `success_rate_any` counts every estimate that met the
criterion, verified or not, which is the paper's definition. A frame is *registrable* when, by
ground truth, both maps already hold at least `min_shared_objects` common objects at the bag
time of the frame (bags from `sgreg make-bag` list the objects of every snapshot); before that
no method can be asked to succeed. Times to first success are per directed link (agent ->
peer), from the bag time at which both maps first hold `min_shared_objects` common objects by
ground truth (not from the link's first registrable result: a link that publishes nothing for a
while is charged for it).
"""
from __future__ import annotations

from dataclasses import asdict, dataclass, field

import numpy as np

from ..config import finite_number
from ..geometry import invert_transform, is_rigid
from ..metrics import rre, rte, two_agent_success

MIN_SHARED_OBJECTS = 3


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
    confidence: float = float("nan")
    bag_t: float | None = None   # bag time (s, the bag's simulation clock) the frame falls at
    evidence: dict = field(default_factory=dict)   # the verdict's evidence, as far as known
    link: str = ""        # the link's state after the estimate (none, candidate, confirmed)
    stamp_ns: int | None = None   # the result's stamp: of the newer map it was made from


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
    confidence: float
    correct: bool          # the estimate meets the criterion, verified or not
    shared_objects: int | None
    registrable: bool | None
    evidence: dict
    bag_t: float | None = None   # the frame's time on the bag's clock


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
    registrable_frames: int | None = None
    success_rate_registrable: float | None = None
    links: dict = field(default_factory=dict)   # "a->b": first registrable / success times
    frames: list = field(default_factory=list)

    def to_dict(self) -> dict:
        d = asdict(self)
        d["frames"] = [asdict(f) for f in self.frames]
        return d


def ground_truth(T_scene_map: dict, agent: str, peer: str) -> np.ndarray:
    """T_agent^peer from each agent's map frame in the scene frame."""
    return invert_transform(np.asarray(T_scene_map[peer])) @ np.asarray(T_scene_map[agent])


def check_ground_truth(gt) -> dict:
    """gt (a bag's ground_truth.json, parsed), once it holds what scoring reads: T_scene_map, a
    rigid 4x4 per agent; t_origin (optional) a finite number; objects (optional) per agent a
    list of [t, ids]. ValueError naming the first entry that does not."""
    if not isinstance(gt, dict):
        raise ValueError(f"expected a JSON object, got {type(gt).__name__}")
    maps = gt.get("T_scene_map")
    if not isinstance(maps, dict) or not maps:
        raise ValueError("T_scene_map: expected an object of agent -> 4x4 transform")
    bad = sorted(str(a) for a, T in maps.items() if not is_rigid(T))
    if bad:
        raise ValueError(f"T_scene_map of {', '.join(bad)}: not a rigid 4x4 transform")
    if not finite_number(gt.get("t_origin", 0.0)):
        raise ValueError(f"t_origin: expected a number, got {gt['t_origin']!r}")
    objects = gt.get("objects")
    if objects is not None and not (isinstance(objects, dict) and all(
            isinstance(snaps, list) and all(_snapshot(s) for s in snaps) for snaps in objects.values())):
        raise ValueError("objects: expected per agent a list of [t, ids]")
    return gt


def _snapshot(s) -> bool:
    return (isinstance(s, list) and len(s) == 2 and finite_number(s[0]) and isinstance(s[1], list)
            and all(isinstance(i, int) and not isinstance(i, bool) for i in s[1]))


def shared_objects(objects: dict, agent: str, peer: str, bag_t: float) -> int:
    """How many objects both agents' latest snapshots at bag time bag_t hold (objects: per
    agent a list of [t, ids] in time order, as in a bag's ground_truth.json)."""
    def held(name):
        ids = [ids for t, ids in objects.get(name, []) if t <= bag_t + 1e-6]
        return set(ids[-1]) if ids else set()
    return len(held(agent) & held(peer))


def _latency(values: list[float]) -> dict:
    if not values:
        return {"n": 0, "median": None, "p90": None}
    v = np.asarray(values)
    return {"n": int(v.size), "median": float(np.median(v)), "p90": float(np.percentile(v, 90))}


def score_replay(records: list[ResultRecord], T_scene_map: dict, objects: dict | None = None,
                 min_shared_objects: int = MIN_SHARED_OBJECTS) -> ReplayScore:
    """objects: the bag's per-snapshot object lists (None: registrability unknown, old bags)."""
    frames = []
    for r in sorted(records, key=lambda r: r.t):
        gt = ground_truth(T_scene_map, r.agent, r.peer)
        e_t, e_r = float(rte(r.T, gt)), float(rre(r.T, gt))
        ok = two_agent_success(r.T, gt)
        shared = None
        if objects is not None and r.bag_t is not None:
            shared = shared_objects(objects, r.agent, r.peer, r.bag_t)
        frames.append(FrameScore(r.t, r.agent, r.peer, r.mode, r.verified, r.reason, e_t, e_r,
                                 bool(r.verified and ok), r.total_ms, float(r.confidence), bool(ok),
                                 shared, None if shared is None else shared >= min_shared_objects,
                                 dict(r.evidence), r.bag_t))
    n = len(frames)
    good = [f for f in frames if f.success]
    verified = [f for f in frames if f.verified]
    score = ReplayScore(
        query_frames=n,
        success_rate=len(good) / n if n else 0.0,
        success_rate_any=sum(f.correct for f in frames) / n if n else 0.0,
        wrong_verified=sum(f.verified and not f.correct for f in frames),
        verified=len(verified),
        first_success_s=good[0].t if good else None,
        median_rte_verified=float(np.median([f.rte for f in verified])) if verified else None,
        median_rre_verified=float(np.median([f.rre for f in verified])) if verified else None,
        coarse_latency_ms=_latency([f.total_ms for f in frames if f.mode in ("coarse", "merged")]),
        dense_latency_ms=_latency([f.total_ms for f in frames if f.mode == "dense"]),
        frames=frames,
    )
    if objects is not None:
        reg = [f for f in frames if f.registrable]
        score.registrable_frames = len(reg)
        score.success_rate_registrable = sum(f.success for f in reg) / len(reg) if reg else None
        # every directed link of the bag's agents, the silent ones too: a link that published
        # nothing while its maps could be registered is one never registered, not one left out
        agents = sorted(str(a) for a in T_scene_map)
        # the replay's last result (any link): a link that fell silent before it is charged
        end = max((f.bag_t for f in frames if f.bag_t is not None), default=None)
        for agent, peer in sorted({(a, p) for a in agents for p in agents if a != p}
                                  | {(f.agent, f.peer) for f in frames}):
            fs = [f for f in frames if (f.agent, f.peer) == (agent, peer)]
            first_reg = next((f.t for f in fs if f.registrable), None)
            first_ok = next((f for f in fs if f.success), None)
            since = registrable_since(objects, agent, peer, min_shared_objects)
            if since is not None and (end is None or since > end):
                since = None      # registrable only after the replay's last result: not asked
            delay = None
            if since is not None and first_ok is not None and first_ok.bag_t is not None:
                delay = max(first_ok.bag_t - since, 0.0)
            score.links[f"{agent}->{peer}"] = {"results": len(fs), "first_registrable_s": first_reg,
                                               "registrable_since_bag_s": since,
                                               "first_success_s": None if first_ok is None else first_ok.t,
                                               "time_to_success_s": delay}
    return score


def registrable_since(objects: dict, agent: str, peer: str,
                      min_shared_objects: int = MIN_SHARED_OBJECTS) -> float | None:
    """The bag time from which both agents' maps hold min_shared_objects common objects by
    ground truth (None: never in the bag)."""
    times = sorted({float(t) for name in (agent, peer) for t, _ in objects.get(name, [])})
    return next((t for t in times if shared_objects(objects, agent, peer, t) >= min_shared_objects), None)
