"""A pose from the clouds' geometry alone, for pairs whose objects a front end garbled.

Under a mapping front end's errors (confused classes, merged and invented instances) two maps of
one room may share only one or two objects a network can match, and every semantic route of the
pipeline (learned point matches, guided matches, node-center pair poses) is refused: too few
objects agree, however well their points fit. The walls, furniture and clutter of the overlap
still register. So when a dense estimate is refused, KISS-Matcher (faster-PFH features, graph
pruning, GNC; Lim et al. 2025) estimates a pose from the source's points and the reference
cloud, ICP brings it onto the clouds, and it is taken on geometric evidence only, judged more
strictly than a semantic estimate (on training-room pairs, right geometric poses reached a
footprint fitness of 0.60-0.99, wrong ones at most 0.42; docs/VERDICT.md section 13):

- the footprint fitness reaches `min_fitness`, and enough of the source lands on the
  reference's footprint (`min_footprint_share`);
- no rival fits nearly as well: the semantic route's own hypotheses far from the pose and the
  pose turned by quarter turns about the vertical through the source (the other placements
  of a rectangular room, which geometry alone cannot tell apart and the semantic route may
  not propose at all), each refined by ICP, are its rivals, and a rival whose fitness
  reaches `max_ambiguity` of the pose's is a tie (identical rooms, a slide along a wall);
- the confidence (a logistic model of fitness, footprint share and ambiguity, fitted on the
  training rooms' pairs: scripts/choose_geometric.py) reaches the verdict's `min_confidence`.

Public API:
    GeometricConfig
    geometric_hypothesis(src_cloud, ref_points, cfg) -> (4, 4) T or None
    turned(T, src, turns_deg) -> list of (4, 4): T turned about the vertical through src
    surface_count(vox, voxel) -> int   voxels the solver's features can describe
    geometric_confidence(evidence, cfg) -> float in [0, 1]
    judge_geometric(evidence, verdict, cfg) -> reason ("ok" or a verdict.REASONS entry)
    geometric_estimate(src_xyz, ref_xyz, groups, src_cloud, reference, rivals, pose_cfg, cfg)
        -> PoseResult (None when the solver found no pose)
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..geometry import yaw_rotation
from .estimator import (PoseConfig, PoseResult, best_refined_rival, cloud_verifier, far_apart,
                        refine_icp_coarse_to_fine, spread_of)
from .solvers import apply_T, make_T, residuals
from .verdict import REASONS, Evidence, VerdictConfig, finite_or_zero
from .verify import ReferenceCloud, finite_voxel_downsample

# what a dense estimate can be refused for (the estimator's reason before the verdict's); a
# near-tie ("ambiguous") is not among those a geometric pose may answer: it always stands
REFUSALS = ("too_few_correspondences",) + tuple(r for r in REASONS[1:] if r != "ambiguous")
SURFACE_NEIGHBOURS = 4   # other voxels within the solver's normal radius that make a surface voxel
# the least GeometricConfig.min_surface: scripts/fuzz_geometric_solver.py crashed the solver in
# 13 of 500 runs (250 seeded clouds, each as source and as reference), every one on a cloud
# without a single surface voxel
MIN_SURFACE = 50


@dataclass
class GeometricConfig:
    """enabled:        estimate a pose from the clouds when a dense estimate with clouds is
                       refused for a reason in `after`.
    voxel:             m, KISS-Matcher's voxel (its feature radii scale with it): 0.1 found the
                       pose of more training-room pairs than 0.05 on the node points a dense
                       message carries, in a third of the time.
    min_points:        source and reference points the solver needs.
    min_surface:       voxels (of `voxel`) on each side with at least SURFACE_NEIGHBOURS others
                       within the solver's normal radius (3 voxels): surface its features can
                       describe. On a cloud without any (a few voxels, or hundreds of scattered
                       points) the solver crashes the whole process, a segfault that nothing
                       can catch; every map a robot registers has thousands.
    min_voxels:        occupied voxels (of `voxel`) the source needs: the surface the features
                       describe. The node points of a whole view of a training-room pair fill
                       1700-10000; a dense message of a live map carries a sparse sample of its
                       nodes (300-1700 points in the synthetic suite, 1350 voxels at most), on
                       which the solver found no right pose there, at 150-300 ms each.
    icp_distances:     m, correspondence distances of the coarse-to-fine ICP of the pose and of
                       its rivals.
    icp_max_iters:     ICP iterations per distance.
    rivals:            semantic hypotheses far from the pose refined and verified as rivals, at
                       most (the estimator's order: GNC over all, then the cliques').
    turns_deg:         the pose turned by these yaw angles about the vertical through the
                       source's centre, refined and verified as rivals too: a symmetric room's
                       other placements. On training-room pairs the best rival (semantic or
                       turned) fitted 0.14-0.58 as well as a right pose, 0.45 and more as well
                       as a wrong one (docs/VERDICT.md section 13; docs/RESULTS.md, session 45).
    min_fitness:       footprint fitness the pose needs after ICP.
    min_footprint_share: share of the source that must land on the reference's footprint.
    max_ambiguity:     a rival whose footprint fitness reaches this share of the pose's is a tie.
    confidence_weights: logistic weights of (bias, footprint fitness, footprint share,
                       ambiguity), fitted by scripts/choose_geometric.py on training-room pairs.
    after:             the refusals a geometric pose may answer."""

    enabled: bool = True
    voxel: float = 0.1
    min_points: int = 50
    min_surface: int = 100
    min_voxels: int = 1500
    icp_distances: tuple[float, ...] = (0.25, 0.1)
    icp_max_iters: int = 15
    rivals: int = 3
    turns_deg: tuple[float, ...] = (90.0, 180.0, 270.0)
    min_fitness: float = 0.7
    min_footprint_share: float = 0.3
    max_ambiguity: float = 0.8
    confidence_weights: tuple[float, ...] = (-1.367, 11.291, 3.442, -10.738)
    after: tuple[str, ...] = REFUSALS

    def __post_init__(self):
        bad = [r for r in self.after if r not in REFUSALS]
        if bad:
            raise ValueError(f"geometric.after: {bad} are not refusals a geometric pose may "
                             f"answer; choose from {list(REFUSALS)}")
        if not (self.voxel > 0 and self.min_points >= 3 and self.min_surface >= MIN_SURFACE
                and self.min_voxels >= 0 and self.icp_max_iters >= 1 and self.rivals >= 0
                and self.max_ambiguity > 0):
            raise ValueError(f"geometric: voxel and max_ambiguity must be > 0, min_points >= 3, "
                             f"min_surface >= {MIN_SURFACE} (fewer crash the solver), min_voxels, "
                             f"rivals >= 0, icp_max_iters >= 1")
        if not all(0.0 <= v <= 1.0 for v in (self.min_fitness, self.min_footprint_share)):
            raise ValueError("geometric: min_fitness and min_footprint_share are shares in [0, 1]")
        if not self.icp_distances or min(self.icp_distances) <= 0:
            raise ValueError("geometric: icp_distances must be positive distances")
        if not all(np.isfinite(a) and a % 360.0 != 0.0 for a in self.turns_deg):
            raise ValueError(f"geometric: turns_deg must be finite yaw angles that turn (not "
                             f"multiples of 360), got {self.turns_deg!r}")
        w = np.asarray(self.confidence_weights, np.float64)
        if w.shape != (4,) or not np.isfinite(w).all():
            raise ValueError("geometric: confidence_weights must be 4 finite numbers (bias, "
                             "fitness, footprint share, ambiguity)")


def geometric_hypothesis(src_cloud: np.ndarray, ref_points: np.ndarray,
                         cfg: GeometricConfig) -> np.ndarray | None:
    """KISS-Matcher's pose of src_cloud onto ref_points, or None when either is too small (too
    few points or too little surface, the source also by cfg.min_voxels) or the solver finds no
    valid solution. Not bit-for-bit repeatable: the solver's threads may order its work
    differently from run to run (raw poses up to centimetres apart on a test room, the same
    after ICP), which can tip a borderline pair across a gate."""
    import kiss_matcher  # compiled extension: imported only when a geometric pose is needed

    src = np.asarray(src_cloud, np.float32).reshape(-1, 3)
    ref = np.asarray(ref_points, np.float32).reshape(-1, 3)
    src, ref = src[np.isfinite(src).all(1)], ref[np.isfinite(ref).all(1)]
    if min(src.shape[0], ref.shape[0]) < cfg.min_points:
        return None
    src_vox = finite_voxel_downsample(src, cfg.voxel)
    if src_vox.shape[0] < cfg.min_voxels or not _has_surface(src_vox, cfg) \
            or not _has_surface(finite_voxel_downsample(ref, cfg.voxel), cfg):
        return None
    matcher = kiss_matcher.KISSMatcher(kiss_matcher.KISSMatcherConfig(cfg.voxel))
    sol = matcher.estimate(src, ref)
    if not sol.valid:
        return None
    T = np.eye(4)
    T[:3, :3] = np.asarray(sol.rotation, np.float64)
    T[:3, 3] = np.asarray(sol.translation, np.float64).reshape(3)
    return T if np.isfinite(T).all() else None


def _surface(tree, points: np.ndarray, voxel: float) -> np.ndarray:
    """(N,) bool: which points (voxel centroids in tree) have SURFACE_NEIGHBOURS others within
    the solver's normal radius, 3 voxels: surface its features can describe."""
    return tree.query_ball_point(points, 3.0 * voxel, return_length=True) > SURFACE_NEIGHBOURS


def surface_count(vox: np.ndarray, voxel: float) -> int:
    """How many of the voxel centroids vox (of `voxel`) are surface (see _surface)."""
    from scipy.spatial import cKDTree

    return int(_surface(cKDTree(vox), vox, voxel).sum()) if vox.shape[0] else 0


def _has_surface(vox: np.ndarray, cfg: GeometricConfig) -> bool:
    """Whether at least cfg.min_surface of the voxel centroids vox (of cfg.voxel) are surface.
    Voxels are looked at in a seeded order, a few times min_surface at a time, until enough
    are found: a map of half a million voxels costs one KD-tree, not a search about each."""
    from scipy.spatial import cKDTree

    if vox.shape[0] < cfg.min_surface:
        return False
    tree, order = cKDTree(vox), np.random.default_rng(0).permutation(vox.shape[0])
    found, chunk = 0, 4 * cfg.min_surface
    for start in range(0, order.size, chunk):
        found += int(_surface(tree, vox[order[start:start + chunk]], cfg.voxel).sum())
        if found >= cfg.min_surface:
            return True
    return False


def turned(T: np.ndarray, src: np.ndarray, turns_deg: tuple[float, ...]) -> list[np.ndarray]:
    """T followed by each yaw turn about the vertical through the centre of src placed by T."""
    centre = apply_T(T, np.asarray(src, np.float64).reshape(-1, 3)).mean(0)
    out = []
    for deg in turns_deg:
        R = yaw_rotation(np.radians(deg))
        out.append(make_T(R, centre - R @ centre) @ T)
    return out


def geometric_confidence(ev: Evidence, cfg: GeometricConfig) -> float:
    """P(pose right | geometric evidence) from the logistic model of cfg.confidence_weights."""
    f = finite_or_zero
    x = np.array([1.0, f(ev.fitness), f(ev.footprint_share), min(f(ev.ambiguity), 1.5)])
    z = float(x @ np.asarray(cfg.confidence_weights, np.float64))
    return float(1.0 / (1.0 + np.exp(-z)))


def judge_geometric(ev: Evidence, verdict: VerdictConfig, cfg: GeometricConfig) -> str:
    """"ok", or why the geometric pose is refused: the clouds do not support it, a rival fits
    nearly as well, or its confidence falls short of the verdict's bar."""
    if not (ev.fitness >= cfg.min_fitness and ev.footprint_share >= cfg.min_footprint_share):
        return "verification_failed"
    if ev.ambiguity >= cfg.max_ambiguity:
        return "ambiguous"
    if geometric_confidence(ev, cfg) < verdict.min_confidence:
        return "low_confidence"
    return "ok"


def geometric_estimate(src_xyz: np.ndarray, ref_xyz: np.ndarray, groups: np.ndarray,
                       src_cloud: np.ndarray, reference: ReferenceCloud, rivals: list[np.ndarray],
                       pose_cfg: PoseConfig, cfg: GeometricConfig) -> PoseResult | None:
    """The geometric pose of src_cloud onto the reference, refined by ICP on pose_cfg's
    verification clouds and judged (judge_geometric). src_xyz / ref_xyz / groups: the semantic
    correspondences, which say how many objects agree with the pose (reported, not required)
    and which of them a runtime may keep; rivals: the semantic route's hypotheses. None when the
    solver found no pose (the verification clouds are built only once it has one: most live
    sources are too small to try)."""
    if not reference.valid:
        return None
    T0 = geometric_hypothesis(src_cloud, reference.points, cfg)
    verifier = None if T0 is None else cloud_verifier(src_cloud, reference, pose_cfg)
    if verifier is None or not verifier.valid:
        return None
    T = refine_icp_coarse_to_fine(verifier, T0, pose_cfg, cfg.icp_distances, cfg.icp_max_iters)
    ver = verifier(T)
    n = src_xyz.shape[0]
    inl = residuals(T, src_xyz, ref_xyz) <= pose_cfg.noise_bound if n else np.zeros(0, bool)
    ev = Evidence(inliers=int(inl.sum()), inlier_ratio=float(inl.mean()) if n else 0.0,
                  objects=int(np.unique(groups[inl]).size),
                  spread=spread_of(src_xyz[inl], pose_cfg.dof) if inl.any() else 0.0,
                  fitness=ver.footprint_fitness, footprint_share=ver.footprint_share)
    # rivals cost an ICP each: only for a pose the clouds support (a refused one stays refused)
    supported = ev.fitness >= cfg.min_fitness and ev.footprint_share >= cfg.min_footprint_share
    rival = None
    if supported:
        at = verifier.src.mean(0)
        far = [R for R in rivals if far_apart(R, T, pose_cfg.verdict, at)][: cfg.rivals]
        far += turned(T, verifier.src, cfg.turns_deg)
        rival = best_refined_rival(far, verifier, pose_cfg, cfg.icp_distances, cfg.icp_max_iters,
                                   lambda R: far_apart(R, T, pose_cfg.verdict, at))
    if rival is not None:
        ev.competitor_fitness = rival[1]
        ev.ambiguity = ev.competitor_fitness / max(ev.fitness, 1e-9)
    reason = judge_geometric(ev, pose_cfg.verdict, cfg)
    return PoseResult(T=T, T_estimate=T0, refined=True, success=reason == "ok", reason=reason,
                      confidence=geometric_confidence(ev, cfg), evidence=ev,
                      inliers=ev.inliers, inlier_ratio=ev.inlier_ratio, inlier_mask=inl,
                      inlier_groups=np.unique(groups[inl]), num_correspondences=n, candidates=1,
                      hypotheses=[T0], spread=ev.spread,
                      T_competitor=None if rival is None else rival[0], fitness=ver.fitness,
                      footprint_share=ver.footprint_share, footprint_fitness=ver.footprint_fitness)
