"""Does the reference repeat what the source shows? Look-alike placements of the source graph.

The verdict's strictest gates (the 0.9 confidence, the whole footprint in the fitness) are there
for floors of identical rooms, where a slide by one room width rests on many objects that fit
well. A partial map of a room that does not repeat pays for them: its right poses are refused for
a fitness or confidence a little short (docs/VERDICT.md sections 6, 7 and 9). This module measures
whether the reference could host the source somewhere else as well as at the estimate.

Each source node's look-alikes are the `top_k` reference nodes whose node descriptors are the
most similar (cosine). A placement of the source (a pose) is supported by the source nodes whose
center lands within `bound` of one of their look-alikes. Poses are hypothesised from every two
look-alike pairs of two source nodes (yaw and translation: both graphs are levelled); the best
supported ones at least the competitor distance from the estimate are its rival placements.
Node centers alone do not tell a repeat: in a furnished room chance placements of a few chairs
on other chairs abound. So each rival is brought onto the clouds by coarse-to-fine ICP and
verified, and

    repeat = the best rival's footprint fitness / the estimate's

Identical rooms give a repeat near 1 (the source fits the twin room as well); a room that does
not repeat gives a low one. Ground truth plays no part.

Public API:
    RepeatConfig
    Placements          support of the estimate's placement and its rival placements
    placements(T, src_centers, src_desc, ref_centers, ref_desc, cfg) -> Placements
    rival_fitness(placements, T, verifier, pose_cfg, cfg) -> the best rival's footprint fitness
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from .estimator import PoseConfig, best_refined_rival, far_apart, far_apart_many
from .pairs import placement_support, yaw_hypotheses
from .verdict import REASONS
from .verify import CloudVerifier, check_probe, check_rim


@dataclass
class RepeatConfig:
    """top_k:          look-alikes per source node (most similar reference descriptors).
    bound:             m, a source node center within this of a look-alike supports a placement.
    min_pair_m:        m, two source nodes closer than this horizontally do not fix a yaw.
    max_hypotheses:    pose hypotheses scored at most (a seeded subset of the pairs beyond it).
    competitor_m, competitor_deg: a placement is a rival when it moves the source's nodes'
                       centroid at least this far from the estimate's placement, or turns it by
                       this much.
    seed:              seed of the subset.
    rivals:            rival placements verified on the clouds, the best supported first and
                       pairwise far apart (with 3, placements just beyond the competitor
                       distance, which ICP brings back onto the estimate, crowded out the twin
                       room on the building suite).
    icp_distances:     m, correspondence distances of the coarse-to-fine ICP of each rival (a
                       placement from node centers is decimetres off).
    icp_max_iters:     ICP iterations per distance.
    verify_max_points: source points of the clouds the rivals are refined and verified on (as
                       for guided matching: ranking needs no more, ICP is most of the cost).

    What the pipeline does with it (pipeline.register_features, dense mode with clouds):
    enabled:           a dense estimate refused for a reason in `after` is estimated again under
                       the gates for unrepeated maps below, and accepted when the reference does
                       not repeat the source's placement there.
    after:             the refusals this may answer: those of the clouds and of the confidence
                       (the gates that are there for identical rooms).
    max_repeat:        the map counts as unrepeated when the repeat is below this (chosen on
                       training rooms, synthetic scenes and the building suite, whose slides
                       showed 0.48 and up; docs/VERDICT.md section 9)...
    min_support:       ...and at least this many source nodes land on look-alikes at the estimate.
    footprint_rim:     PoseConfig.footprint_rim of the second estimate.
    footprint_probe:   PoseConfig.footprint_probe of the second estimate (m; 0: the first
                       estimate's).
    min_confidence:    VerdictConfig.min_confidence of the second estimate."""

    top_k: int = 3
    bound: float = 0.4
    min_pair_m: float = 0.5
    max_hypotheses: int = 4000
    competitor_m: float = 1.0
    competitor_deg: float = 10.0
    seed: int = 0
    rivals: int = 10
    icp_distances: tuple[float, ...] = (0.5, 0.25, 0.1)
    icp_max_iters: int = 10
    verify_max_points: int = 600
    enabled: bool = True
    after: tuple[str, ...] = ("verification_failed", "low_confidence")
    max_repeat: float = 0.4
    min_support: int = 3
    footprint_rim: int = 1
    footprint_probe: float = 0.5
    min_confidence: float = 0.8

    def __post_init__(self):
        bad = [r for r in self.after if r not in REASONS[1:]]
        if bad:
            raise ValueError(f"repeats.after: {bad} are not verdict refusals {list(REASONS[1:])}")
        check_rim(self.footprint_rim)
        check_probe(self.footprint_probe)
        if not (0.0 <= self.min_confidence <= 1.0 and self.max_repeat > 0
                and self.min_support >= 1):
            raise ValueError("repeats: min_confidence must lie in [0, 1], max_repeat > 0, "
                             "min_support >= 1")
        if not (self.top_k >= 1 and self.bound > 0 and self.min_pair_m >= 0
                and self.max_hypotheses >= 1 and self.competitor_m > 0 and self.competitor_deg > 0
                and self.rivals >= 1 and self.icp_max_iters >= 1 and self.verify_max_points >= 3
                and len(self.icp_distances)
                and min(self.icp_distances) > 0):
            raise ValueError("repeats: top_k, max_hypotheses, rivals and icp_max_iters must be "
                             ">= 1, verify_max_points >= 3, min_pair_m >= 0, and bound, "
                             "competitor_m, competitor_deg and icp_distances > 0 (and given)")

    def relaxed(self, pose_cfg: PoseConfig) -> PoseConfig:
        """pose_cfg under the gates for unrepeated maps."""
        return replace(pose_cfg, footprint_rim=self.footprint_rim,
                       footprint_probe=self.footprint_probe or pose_cfg.footprint_probe,
                       verdict=replace(pose_cfg.verdict, min_confidence=self.min_confidence))


@dataclass
class Placements:
    """support: source nodes that land on a look-alike at the estimate; centroid: (3,) of the
    source nodes, where "far" is measured; hypotheses: placements far from the estimate that
    were scored (0: the look-alikes fix no pose, so nothing can be said about repeats);
    rivals: [(T (4, 4), support)] the best supported of them, far from each other."""

    support: int = 0
    centroid: np.ndarray = field(default_factory=lambda: np.zeros(3))
    hypotheses: int = 0
    rivals: list = field(default_factory=list)


def _unit(desc: np.ndarray) -> np.ndarray:
    d = np.asarray(desc, np.float64)
    return d / np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-12)


def placements(T: np.ndarray, src_centers: np.ndarray, src_desc: np.ndarray,
               ref_centers: np.ndarray, ref_desc: np.ndarray,
               cfg: RepeatConfig | None = None) -> Placements:
    """The estimate's placement of the source graph (T: source -> reference, both levelled) and
    its rival placements among the look-alikes (module doc). Non-finite nodes take no part."""
    cfg = cfg or RepeatConfig()
    src = np.asarray(src_centers, np.float64).reshape(-1, 3)
    ref = np.asarray(ref_centers, np.float64).reshape(-1, 3)
    sd, rd = np.asarray(src_desc, np.float64), np.asarray(ref_desc, np.float64)
    s_ok = np.isfinite(src).all(1) & np.isfinite(sd).all(1)
    r_ok = np.isfinite(ref).all(1) & np.isfinite(rd).all(1)
    src, sd, ref, rd = src[s_ok], sd[s_ok], ref[r_ok], rd[r_ok]
    T = np.asarray(T, np.float64)
    if src.shape[0] == 0 or ref.shape[0] == 0 or not np.isfinite(T).all():
        return Placements()
    k = min(cfg.top_k, ref.shape[0])
    sim = _unit(sd) @ _unit(rd).T
    top = np.argsort(-sim, axis=1, kind="stable")[:, :k]                       # (n, k)
    alike = ref[top]                                                          # (n, k, 3)
    out = Placements(support=int(placement_support(T[None, :3, :3], T[None, :3, 3], src, alike,
                                                   cfg.bound)[0]), centroid=src.mean(0))
    node = np.repeat(np.arange(src.shape[0]), k)
    R, t = yaw_hypotheses(np.repeat(src, k, axis=0), alike.reshape(-1, 3), node, cfg.bound,
                          cfg.min_pair_m, cfg.max_hypotheses, cfg.seed)
    far = far_apart_many(R, t, T[:3, :3], T[:3, 3], out.centroid, cfg)
    R, t = R[far], t[far]
    out.hypotheses = int(R.shape[0])
    if not out.hypotheses:
        return out
    sup = placement_support(R, t, src, alike, cfg.bound)
    # the best of each cell of half the competitor distance (placed centroid, yaw): thousands of
    # hypotheses are a few hundred placements
    order = np.argsort(-sup, kind="stable")
    placed = R @ out.centroid + t
    yaw_cells = int(np.ceil(720.0 / cfg.competitor_deg))
    yaw = np.degrees(np.arctan2(R[:, 1, 0], R[:, 0, 0])) + 180.0
    cell = np.c_[np.floor(placed[:, :2] / (0.5 * cfg.competitor_m)),
                 np.floor(yaw / (0.5 * cfg.competitor_deg)) % yaw_cells].astype(np.int64)
    _, first = np.unique(cell[order], axis=0, return_index=True)
    for h in order[np.sort(first)]:
        if len(out.rivals) == cfg.rivals or sup[h] < cfg.min_support:
            break
        if all(far_apart_many(R[h], t[h], T_o[:3, :3], T_o[:3, 3], out.centroid, cfg)
               for T_o, _ in out.rivals):
            T_h = np.eye(4)
            T_h[:3, :3], T_h[:3, 3] = R[h], t[h]
            out.rivals.append((T_h, int(sup[h])))
    return out


def rival_fitness(place: Placements, T: np.ndarray, verifier: CloudVerifier, pose_cfg: PoseConfig,
                  cfg: RepeatConfig) -> float:
    """The best footprint fitness of the rival placements once coarse-to-fine ICP has brought
    them onto the clouds (0 when none stays far from T; ICP may bring a rival back onto the
    estimate): how well the reference's geometry hosts the source elsewhere."""
    best = best_refined_rival([T_h for T_h, _ in place.rivals], verifier, pose_cfg,
                              cfg.icp_distances, cfg.icp_max_iters,
                              lambda R: far_apart(R, T, cfg, place.centroid))
    return 0.0 if best is None else best[1]
