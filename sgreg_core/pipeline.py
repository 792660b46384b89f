"""The registration pipeline: two scene graphs (or their encoded features) -> a verified T.

One pipeline for every caller (the `sgreg register` CLI, `sgreg bench-register`, the ROS
registration node through runtime/peers.py), so that what is benchmarked is what runs.

Each map is levelled on its own floor and walls first (maps/level.py: a robot's gravity is off
by a degree or two, differently per robot), its graph is built and registered in that upright
frame, and T is turned back into the maps' own frames: a full SE(3), whose residual tilt ICP
refines.

    dense:  encode both graphs -> node matches (dual softmax) -> point matches (Sinkhorn)
            -> estimate_pose on the point correspondences
    coarse: node matches -> estimate_pose on the matched node centers only
    merged: coarse, plus correspondences kept from an earlier dense estimate (the paper's
            scheme for query frames that bring only a coarse message)

Every correspondence carries the node match (object pair) it comes from, so the verdict counts
distinct inlier objects, not points. The verification clouds are all node points of each graph
(what a dense message carries), so even a coarse estimate is checked against geometry when the
clouds are at hand. Node centers of partly seen objects move with what was seen, so coarse and
merged modes have their own PoseConfig with a wider inlier bound and ICP reach. By default
every estimate that passes the correspondence checks is refined by ICP on the verification
clouds, and the verdict (pose/verdict.py: evidence, ambiguity, confidence) is taken on the
better supported of the estimate and its refinement.

Public API:
    PipelineConfig                 level, graph, dense / coarse PoseConfig, mode, icp, min_nodes
    Correspondences                point pairs with the node pair each comes from
    Registration                   T (SRC -> REF), verdict, confidence, matches, timings
    register_graphs(model, src_graph, ref_graph, cfg, timings=None) -> Registration
    build_graphs(src_map, ref_map, cfg, timings) -> (src_graph, ref_graph)   (levelled;
                                   "level" and "graph" stages)
    to_map_frames(reg, src_level, ref_level)   T between levelled frames -> between the maps
    register_features(model, src_feats, ref_feats, src_cloud, ref_cloud, cfg, timings, kept)
    node_cloud(graph) -> (N, 3)    all node points of a graph (what a dense message carries)
    reference_cloud(graph) -> (N, 3)   every point of the graph's map, labelled or not (what a
                                   pose is verified against; the node points when unknown)
    warm_up(model)                 load the text encoder now, so that no timing includes it
    TIMING_STAGES                  the keys of Registration.timing_ms, in pipeline order
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field, replace

import numpy as np

from .net.model import NodeFeatures, SGRegModel
from .pose import PoseConfig, ReferenceCloud, estimate_pose, nms_correspondences
from .pose.estimator import as_points, cloud_verifier
from .pose.geometric import GeometricConfig, geometric_estimate
from .pose.guided import GuidedConfig, center_poses, guided_matches
from .pose.repeats import RepeatConfig, placements, rival_fitness
from .pose.verdict import Evidence, VerdictConfig
from .maps.level import LevelConfig, Levelling, level_map
from .maps.scene_graph import GraphConfig, build_scene_graph
from .geometry import invert_transform
from .types import InstanceMap, SceneGraph

MODES = ("dense", "coarse")   # what PipelineConfig.mode asks for; "merged" = coarse + kept
ICP_MODES = ("never", "coarse", "always")
# refusals of a coarse estimate that mean its pose is likely wrong, not only short of trust:
# worth trying the poses two node-center matches fix (PipelineConfig.coarse_pairs); a tie and
# a confidence short of the bar stand, as those gates are there for identical rooms
COARSE_PAIRS_AFTER = ("too_few_inliers", "too_few_objects", "degenerate_geometry",
                      "verification_failed")
# level: gravity of both maps; graph: scene graphs of both maps; text / sample / shape / gnn: encoding of both graphs
# (label embeddings, node point sampling, shape + point features, GNN); node_match /
# point_match: matching; pose: estimation, verification and ICP; total: the whole call.
TIMING_STAGES = ("level", "graph", "text", "sample", "shape", "gnn", "node_match", "point_match", "pose",
                 "total")


def _dense_pose() -> PoseConfig:
    """Verification on a 10 cm grid: a third of the 5 cm grid's points, so building the
    reference (voxelisation and normals, most of the pose time) costs about half, and it
    separates right from wrong poses as well."""
    return PoseConfig(verify_voxel=0.1)


def _coarse_pose() -> PoseConfig:
    """Node centers of partial objects are off by decimetres: wider bound, fewer inliers, and
    an ICP reach that covers the error of a pose from centers. Verification and ICP on 600
    source points keep a coarse estimate near 20 ms with the same recall as on 1500."""
    return PoseConfig(noise_bound=0.3, nms_radius=0.0, verdict=VerdictConfig(min_inliers=4, min_objects=4),
                      clique_deltas=(0.2, 0.4, 0.8), verify_voxel=0.1, icp_distance=0.2,
                      verify_max_points=600, icp_max_iters=15)


@dataclass
class PipelineConfig:
    """level:       levelling of each map before its graph is built (maps/level.py).
    graph:          scene-graph construction (only used when starting from instance maps).
    pose:           estimator settings of dense mode (point correspondences).
    coarse_pose:    estimator settings of coarse mode (node-center correspondences).
    mode:           "dense" (points) or "coarse" (node centers only, merged with kept
                    correspondences when the caller has some).
    icp:            when the estimate is refined with point-to-plane ICP on the
                    verification clouds before the verdict: "never", "coarse" (coarse mode
                    only) or "always" (default: even centimetre-accurate point matches leave
                    a degree of rotation that costs a low-overlap pair its support); overrides
                    the pose configs' own `icp`.
    min_nodes:      graphs with fewer nodes are not registered (reason "too_few_nodes").
    guided:         guided point matching when a dense estimate with clouds fails
                    (pose/guided.py).
    coarse_pairs:   when a coarse estimate from node centers alone (no kept correspondences)
                    with clouds is refused for one of COARSE_PAIRS_AFTER, it is estimated again
                    with this many poses that two node-center matches fix among its candidates
                    (PoseConfig.pair_hypotheses), and taken if it passes; 0: off. Early, small
                    maps share four or five objects, and a wrong clique of centers hides the
                    right one (docs/VERDICT.md section 11).
    repeats:        look-alike placements of the source graph in the reference, and the
                    gates for maps that do not repeat it (pose/repeats.py).
    geometric:      a pose from the clouds' geometry alone when every semantic route of a
                    dense estimate with clouds was refused (pose/geometric.py).
    kept_noise_bound: m, inlier bound of the kept point correspondences in a merged estimate
                    (node centers keep coarse_pose.noise_bound): kept points lie on surfaces,
                    and under the centers' bound one compact cluster of them also fits a pose
                    turned far from the truth about it."""

    level: LevelConfig = field(default_factory=LevelConfig)
    graph: GraphConfig = field(default_factory=GraphConfig)
    pose: PoseConfig = field(default_factory=_dense_pose)
    coarse_pose: PoseConfig = field(default_factory=_coarse_pose)
    mode: str = "dense"
    icp: str = "always"
    min_nodes: int = 3
    guided: GuidedConfig = field(default_factory=GuidedConfig)
    coarse_pairs: int = 8
    repeats: RepeatConfig = field(default_factory=RepeatConfig)
    geometric: GeometricConfig = field(default_factory=GeometricConfig)
    kept_noise_bound: float = 0.15

    def __post_init__(self):
        if not 0.0 < self.kept_noise_bound < np.inf:
            raise ValueError(f"kept_noise_bound must be a finite distance > 0 (m), got {self.kept_noise_bound}")
        if self.coarse_pairs < 0:
            raise ValueError(f"coarse_pairs must be >= 0, got {self.coarse_pairs}")
        if self.min_nodes < 1:
            raise ValueError(f"min_nodes must be >= 1, got {self.min_nodes}")
        if self.mode not in MODES:
            raise ValueError(f"mode must be one of {MODES}, got {self.mode!r}")
        if self.icp not in ICP_MODES:
            raise ValueError(f"icp must be one of {ICP_MODES}, got {self.icp!r}")

    def pose_config(self) -> PoseConfig:
        icp = self.icp == "always" or (self.icp == "coarse" and self.mode == "coarse")
        return replace(self.pose if self.mode == "dense" else self.coarse_pose, icp=icp)

    def with_pose(self, **changes) -> "PipelineConfig":
        """The same config with estimator settings (pose.PoseConfig) changed in both the dense
        and the coarse pose configs (to the same value: only for settings both should share)."""
        return self._each_pose(lambda pose: replace(pose, **changes))

    def with_verdict(self, **changes) -> "PipelineConfig":
        """The same config with verdict settings (pose/verdict.VerdictConfig) changed in both
        the dense and the coarse pose configs (each keeps its other verdict settings)."""
        return self._each_pose(lambda pose: replace(pose, verdict=replace(pose.verdict, **changes)))

    def _each_pose(self, change) -> "PipelineConfig":
        return replace(self, pose=change(self.pose), coarse_pose=change(self.coarse_pose))


@dataclass
class Correspondences:
    """Point pairs for the estimator: src_xyz / ref_xyz (c, 3) float64 in each graph's frame,
    score (c,) confidence, pairs (c, 2) int64 the (src node id, ref node id) of the node match
    each comes from."""

    src_xyz: np.ndarray
    ref_xyz: np.ndarray
    score: np.ndarray
    pairs: np.ndarray

    def __len__(self) -> int:
        return int(self.score.shape[0])

    def subset(self, mask: np.ndarray) -> "Correspondences":
        return Correspondences(self.src_xyz[mask], self.ref_xyz[mask], self.score[mask],
                               self.pairs[mask])

    @staticmethod
    def concat(a: "Correspondences", b: "Correspondences") -> "Correspondences":
        return Correspondences(*(np.concatenate([x, y]) for x, y in
                                 ((a.src_xyz, b.src_xyz), (a.ref_xyz, b.ref_xyz),
                                  (a.score, b.score), (a.pairs, b.pairs))))

    def groups(self) -> np.ndarray:
        """(c,) one integer per distinct node pair."""
        if len(self) == 0:
            return np.zeros(0, np.int64)
        return np.unique(self.pairs, axis=0, return_inverse=True)[1].reshape(-1).astype(np.int64)


@dataclass
class Registration:
    """Outcome of one registration.

    T:               (4, 4) float64 mapping SRC points into REF's frame (ICP-refined when
                     PipelineConfig.icp asks for it and ICP kept the fitness), between the maps'
                     own frames; when nothing was estimated, the identity between the
                     levelled frames.
    T_levelled:      the same between the levelled frames the graphs were built in.
    levelling:       {"src": ..., "ref": ...} each map's levelling (Levelling.to_json: tilt_deg,
                     up, ok, reason); empty when the caller gave graphs of unlevelled maps.
    success:         True only when the verdict accepted the estimate.
    reason:          "ok", "too_few_nodes", "no_node_matches" or the estimator's reason
                     (pose/verdict.py REASONS).
    confidence:      P(T right | evidence) in [0, 1] (pose/verdict.py), 0 without estimate.
    evidence:        what the verdict was taken on (pose.verdict.Evidence).
    mode:            "dense", "coarse" or "merged".
    node_pairs:      (m, 2) int64 matched (src node id, ref node id); node_scores (m,).
    corr:            the Correspondences of the estimate reported (points in dense mode, node
                     centers in coarse mode, plus the kept ones in merged mode; the learned
                     points, thinned, then the guided ones when `guided`).
    inlier_mask:     (c,) bool, inliers of the estimator's pose (before any ICP).
    inliers, inlier_ratio: their count and share.
    inlier_nodes:    node matches with at least one inlier correspondence.
    T_competitor:    the best competing hypothesis the verdict weighed (None: none found).
    fitness:         verification fitness of T: share of SRC points on REF surfaces (NaN
                     without clouds).
    footprint_fitness: the same share among the SRC points that land on REF's footprint, the
                     measure of the verdict (pose/verify.py; NaN without clouds).
    refined:         True when T is the ICP refinement.
    guided:          True when the estimate needed guided point matches (pose/guided.py).
    geometric:       True when the estimate is the clouds' geometric pose (pose/geometric.py):
                     its confidence is the geometric model's.
    guided_pairs:    the last guided_pairs of corr are those guided matches: made at the pose,
                     they are no evidence for a later estimate and are not kept (inlier_corr).
    repeat:          under the gates for unrepeated maps, the best look-alike placement's
                     footprint fitness over the estimate's (pose/repeats.py; NaN unless
                     measured): how well the reference hosts the source elsewhere.
    unrepeated:      True when the estimate was accepted under the gates for maps that do not
                     repeat the source's placement (RepeatConfig; it failed the strict ones).
    timing_ms:       milliseconds per TIMING_STAGES entry that ran, and "total".
    pose_timing_ms:  the estimator's own steps (nms, gnc, clique, candidates, verify, icp) of
                     the first estimate, "guided": the whole guided pass when it ran, and
                     "repeats": the estimate under the gates for unrepeated maps when it ran,
                     "geometric": the geometric pose when it ran."""

    T: np.ndarray = field(default_factory=lambda: np.eye(4))
    T_levelled: np.ndarray = field(default_factory=lambda: np.eye(4))
    levelling: dict = field(default_factory=dict)
    success: bool = False
    reason: str = "too_few_nodes"
    confidence: float = 0.0
    evidence: Evidence = field(default_factory=Evidence)
    mode: str = "dense"
    node_pairs: np.ndarray = field(default_factory=lambda: np.zeros((0, 2), np.int64))
    node_scores: np.ndarray = field(default_factory=lambda: np.zeros(0, np.float32))
    corr: Correspondences = field(default_factory=lambda: Correspondences(
        np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0), np.zeros((0, 2), np.int64)))
    inlier_mask: np.ndarray = field(default_factory=lambda: np.zeros(0, bool))
    inliers: int = 0
    inlier_ratio: float = 0.0
    inlier_nodes: int = 0
    T_competitor: np.ndarray | None = None
    fitness: float = float("nan")
    footprint_fitness: float = float("nan")
    refined: bool = False
    guided: bool = False
    geometric: bool = False
    guided_pairs: int = 0
    repeat: float = float("nan")
    unrepeated: bool = False
    timing_ms: dict[str, float] = field(default_factory=dict)
    pose_timing_ms: dict[str, float] = field(default_factory=dict)

    @property
    def node_matches(self) -> int:
        return int(self.node_pairs.shape[0])

    @property
    def correspondences(self) -> int:
        return len(self.corr)

    def inlier_node_pairs(self) -> np.ndarray:
        """(k, 2) int64 the node matches (src id, ref id) with at least one inlier."""
        pairs = self.corr.pairs[self.inlier_mask] if len(self.corr) else np.zeros((0, 2), np.int64)
        return np.unique(pairs, axis=0) if len(pairs) else np.zeros((0, 2), np.int64)

    def inlier_corr(self) -> Correspondences:
        """The correspondences the estimate explains, guided ones left out (what a runtime
        keeps for merging)."""
        mask = self.inlier_mask.copy()
        if self.guided_pairs:
            mask[len(mask) - self.guided_pairs:] = False
        return self.corr.subset(mask)

    def to_json(self) -> dict:
        """The result JSON of docs/ARCHITECTURE.md ("Contracts") (+ reason, mode, counts, node pairs)."""
        return {
            "T": np.asarray(self.T, np.float64).tolist(),
            "success": bool(self.success),
            "reason": self.reason,
            "confidence": float(self.confidence),
            "mode": self.mode,
            "node_matches": self.node_matches,
            "node_pairs": self.node_pairs.tolist(),
            "correspondences": self.correspondences,
            "inliers": int(self.inliers),
            "inlier_ratio": float(self.inlier_ratio),
            "inlier_nodes": int(self.inlier_nodes),
            "fitness": _finite_or_none(self.fitness),
            "footprint_fitness": _finite_or_none(self.footprint_fitness),
            "refined": bool(self.refined),
            "guided": bool(self.guided),
            "geometric": bool(self.geometric),
            "repeat": _finite_or_none(self.repeat),
            "unrepeated": bool(self.unrepeated),
            "evidence": {k: _finite_or_none(v) if isinstance(v, float) else v
                         for k, v in vars(self.evidence).items()},
            "T_competitor": None if self.T_competitor is None else
            np.asarray(self.T_competitor, np.float64).tolist(),
            "tilt_deg": {k: v["tilt_deg"] for k, v in self.levelling.items()},
            "levelling": self.levelling,
            "timing_ms": {k: round(float(v), 3) for k, v in self.timing_ms.items()},
        }


def _finite_or_none(v: float) -> float | None:
    return float(v) if np.isfinite(v) else None


def node_cloud(graph: SceneGraph) -> np.ndarray:
    """All node points of a graph, (N, 3) float32 (the verification cloud)."""
    if graph.num_nodes == 0:
        return np.zeros((0, 3), np.float32)
    return np.concatenate(graph.points).astype(np.float32, copy=False)


def reference_cloud(graph: SceneGraph) -> np.ndarray:
    """What a pose onto this graph is verified against: every point of its map, labelled or
    not. Verification is geometry: an object the front end dropped, merged or mislabelled is
    still a surface, and a right pose of the other map's points lands on it."""
    return graph.map_points if graph.map_points is not None else node_cloud(graph)


def warm_up(model: SGRegModel) -> None:
    """Load the text encoder's weights (seconds, on first use) so that registration timings
    measure registration."""
    model.text_encoder.encode(["object"])


def _add(timings: dict, stage: str, t0: float) -> None:
    timings[stage] = timings.get(stage, 0.0) + 1e3 * (time.perf_counter() - t0)


def register_features(model: SGRegModel, src_feats: NodeFeatures, ref_feats: NodeFeatures,
                      src_cloud: np.ndarray | None = None,
                      ref_cloud: np.ndarray | ReferenceCloud | None = None,
                      cfg: PipelineConfig | None = None,
                      timings: dict | None = None,
                      kept: Correspondences | None = None,
                      kept_pose: np.ndarray | None = None) -> Registration:
    """Match encoded graphs and estimate T (SRC -> REF). Dense mode needs dense features.

    src_cloud / ref_cloud: verification clouds in each graph's frame (all node points;
    ref_cloud may be a prebuilt pose.ReferenceCloud); without them the verdict rests on the
    correspondences only. timings: stages already spent by the caller (graph, encoding) are
    kept and the matching / pose stages added; "total" is left to the caller when it passes
    timings in (it knows where it started). kept: coarse mode only, correspondences from an
    earlier dense estimate merged with the node centers (mode "merged"); kept_pose: that
    estimate's T_levelled, one more candidate pose (weighed by the clouds with the fitted ones:
    GNC over centers and kept points together can settle between two poses, and a fit of the
    kept points alone lies decimetres from the ICP-refined pose they came from)."""
    cfg = cfg or PipelineConfig()
    t_start = time.perf_counter()
    own_total = timings is None
    timings = {} if timings is None else timings
    out = Registration(mode=cfg.mode, timing_ms=timings)
    if min(src_feats.num_nodes, ref_feats.num_nodes) < cfg.min_nodes:
        return _finish(out, timings, t_start, own_total)
    src_ids, ref_ids = np.asarray(src_feats.node_ids), np.asarray(ref_feats.node_ids)
    bounds, given = None, None     # the pose config's own, except for kept correspondences
    if cfg.mode == "dense":
        dm = model.match_dense(src_feats, ref_feats, timings)
        nodes, pts = dm.nodes, dm.points
        pair_idx = np.asarray(pts.node_match, np.int64)
        corr = Correspondences(np.asarray(pts.src_xyz, np.float64), np.asarray(pts.ref_xyz, np.float64),
                               np.asarray(pts.score, np.float64),
                               np.stack([src_ids[nodes.src_idx[pair_idx]],
                                         ref_ids[nodes.ref_idx[pair_idx]]], 1).astype(np.int64))
    else:
        nodes = model.match_coarse(src_feats, ref_feats, timings)
        corr = Correspondences(np.asarray(nodes.src_xyz, np.float64), np.asarray(nodes.ref_xyz, np.float64),
                               np.asarray(nodes.score, np.float64),
                               np.stack([src_ids[nodes.src_idx], ref_ids[nodes.ref_idx]], 1).astype(np.int64))
        if kept is not None and len(kept):
            bounds = np.r_[np.full(len(corr), cfg.coarse_pose.noise_bound),
                           np.full(len(kept), cfg.kept_noise_bound)]
            given = None if kept_pose is None else [kept_pose]
            corr = Correspondences.concat(corr, kept)
            out.mode = "merged"
    out.node_pairs = np.stack([src_ids[nodes.src_idx], ref_ids[nodes.ref_idx]], 1).astype(np.int64)
    out.node_scores = np.asarray(nodes.score, np.float32)
    out.corr = corr
    out.inlier_mask = np.zeros(len(corr), bool)
    if len(corr) == 0 and len(out.node_pairs) == 0:
        out.reason = "no_node_matches"
        return _finish(out, timings, t_start, own_total)

    t0 = time.perf_counter()
    pose_cfg = cfg.pose_config()
    dense_clouds = cfg.mode == "dense" and src_cloud is not None and ref_cloud is not None
    guided_on = cfg.guided.enabled and dense_clouds
    coarse_retry = (out.mode == "coarse" and cfg.coarse_pairs > 0 and src_cloud is not None
                    and ref_cloud is not None)
    geometric_on = cfg.geometric.enabled and dense_clouds
    second_pass = guided_on or (cfg.repeats.enabled and dense_clouds) or coarse_retry or geometric_on
    if second_pass and not isinstance(ref_cloud, ReferenceCloud) and as_points(ref_cloud) is not None:
        # one reference for every pass: building it is most of the pose time
        ref_cloud = ReferenceCloud(ref_cloud, pose_cfg.verify_voxel, pose_cfg.footprint_cell)
    groups = corr.groups()
    res = estimate_pose(corr.src_xyz, corr.ref_xyz, corr.score, src_cloud, ref_cloud,
                        pose_cfg, groups=groups, noise_bounds=bounds, given=given)
    pose_ms = {k: v for k, v in res.timing_ms.items() if k != "total"}
    if guided_on and res.reason in cfg.guided.after and isinstance(ref_cloud, ReferenceCloud):
        t_guided = time.perf_counter()
        second = _guided_estimate(src_feats, ref_feats, nodes, src_ids, ref_ids, corr, src_cloud,
                                  ref_cloud, pose_cfg, cfg.guided)
        pose_ms["guided"] = 1e3 * (time.perf_counter() - t_guided)
        if second is not None and second[0].success:
            res, corr, out.guided_pairs = second
            groups, out.corr, out.guided = corr.groups(), corr, True
    if (cfg.repeats.enabled and dense_clouds and res.reason in cfg.repeats.after
            and isinstance(ref_cloud, ReferenceCloud)):
        # the gates for maps that do not repeat the source: the estimate again under them,
        # taken only where no look-alike placement of the source fits nearly as well
        t_rep = time.perf_counter()
        relaxed = cfg.repeats.relaxed(pose_cfg)
        third = estimate_pose(corr.src_xyz, corr.ref_xyz, corr.score, src_cloud, ref_cloud,
                              relaxed, groups=groups)
        if third.success:
            out.repeat = _repeat(third.T, src_feats, ref_feats, src_cloud, ref_cloud, relaxed,
                                 cfg.repeats)
            if out.repeat < cfg.repeats.max_repeat:   # NaN (cannot be told) is not below
                res, out.unrepeated = third, True
        pose_ms["repeats"] = 1e3 * (time.perf_counter() - t_rep)
    # with no candidate at all (GNC found no fit) the pair poses would meet the same fit
    if coarse_retry and res.reason in COARSE_PAIRS_AFTER and res.candidates:
        t_pairs = time.perf_counter()
        second = estimate_pose(corr.src_xyz, corr.ref_xyz, corr.score, src_cloud, ref_cloud,
                               replace(pose_cfg, pair_hypotheses=cfg.coarse_pairs), groups=groups,
                               hypotheses=res.hypotheses)
        if second.success:
            res = second
        pose_ms["pairs"] = 1e3 * (time.perf_counter() - t_pairs)
    if geometric_on and res.reason in cfg.geometric.after and isinstance(ref_cloud, ReferenceCloud):
        t_geo = time.perf_counter()
        src_points = as_points(src_cloud)
        geo = None if src_points is None else geometric_estimate(
            corr.src_xyz, corr.ref_xyz, groups, src_points, ref_cloud, res.hypotheses, pose_cfg,
            cfg.geometric)
        if geo is not None and geo.success:
            res, out.geometric = geo, True
        pose_ms["geometric"] = 1e3 * (time.perf_counter() - t_geo)
    _add(timings, "pose", t0)
    out.success, out.reason, out.T, out.refined = bool(res.success), res.reason, res.T, res.refined
    out.T_levelled = res.T
    out.confidence, out.evidence, out.T_competitor = res.confidence, res.evidence, res.T_competitor
    out.inlier_mask = res.inlier_mask
    out.inliers, out.inlier_ratio = int(res.inliers), float(res.inlier_ratio)
    out.inlier_nodes = int(np.unique(groups[res.inlier_mask]).size)
    out.fitness, out.footprint_fitness = float(res.fitness), float(res.footprint_fitness)
    out.pose_timing_ms = pose_ms
    return _finish(out, timings, t_start, own_total)


def _guided_estimate(src_feats: NodeFeatures, ref_feats: NodeFeatures, nodes, src_ids, ref_ids,
                     corr: Correspondences, src_cloud, ref_cloud: ReferenceCloud,
                     pose_cfg: PoseConfig, gcfg: GuidedConfig):
    """The estimate on the learned correspondences plus the node matches' points paired at the
    best poses from node centers (pose/guided.py), asking for gcfg.min_objects. Returns
    (PoseResult, correspondences: learned then guided, number of guided ones), or None when no
    pair was made. Each set is thinned by the NMS on its own: a point paired at both guided
    poses and by the network is evidence for each of them."""
    verifier = cloud_verifier(src_cloud, ref_cloud,
                              replace(pose_cfg, verify_max_points=gcfg.verify_max_points))
    if verifier is None:
        return None
    poses = center_poses(nodes.src_xyz, nodes.ref_xyz, nodes.score, verifier, pose_cfg, gcfg)
    sp, sv = np.asarray(src_feats.points)[nodes.src_idx], np.asarray(src_feats.valid)[nodes.src_idx]
    rp, rv = np.asarray(ref_feats.points)[nodes.ref_idx], np.asarray(ref_feats.valid)[nodes.ref_idx]
    pairs = np.stack([src_ids[nodes.src_idx], ref_ids[nodes.ref_idx]], 1).astype(np.int64)
    sets = []
    for T, _ in poses:
        k, s, r, d = guided_matches(T, sp, sv, rp, rv, gcfg.radius)
        score = np.asarray(nodes.score, np.float64)[k] * (1.0 - d / gcfg.radius)
        sets.append(Correspondences(s, r, score, pairs[k]))
    guided = [c.subset(nms_correspondences(c.src_xyz, c.ref_xyz, c.score, pose_cfg.nms_radius))
              for c in sets if len(c)]
    if not guided:
        return None
    learned = corr.subset(nms_correspondences(corr.src_xyz, corr.ref_xyz, corr.score,
                                              pose_cfg.nms_radius))
    both = learned
    for c in guided:
        both = Correspondences.concat(both, c)
    verdict = replace(pose_cfg.verdict, min_objects=max(pose_cfg.verdict.min_objects, gcfg.min_objects),
                      competitor_min_fitness=gcfg.competitor_min_fitness)
    res = estimate_pose(both.src_xyz, both.ref_xyz, both.score, src_cloud, ref_cloud,
                        replace(pose_cfg, nms_radius=0.0, verdict=verdict), groups=both.groups())
    return res, both, len(both) - len(learned)


def _repeat(T: np.ndarray, src_feats: NodeFeatures, ref_feats: NodeFeatures, src_cloud,
            ref_cloud: ReferenceCloud, pose_cfg: PoseConfig, rcfg: RepeatConfig) -> float:
    """How well the reference hosts the source elsewhere than at T: the best look-alike
    placement's footprint fitness over T's (pose/repeats.py), on pose_cfg's verification. NaN
    (taken as a repeat) when it cannot be told: fewer than rcfg.min_support source nodes land
    on look-alikes at T, the look-alikes fix no pose far from T, or the clouds cannot judge T
    (a cloud malformed or too small on this verification's sample, or T's footprint fitness 0:
    a ratio over nothing would read as no repeat)."""
    verifier = cloud_verifier(src_cloud, ref_cloud,
                              replace(pose_cfg, verify_max_points=rcfg.verify_max_points))
    if verifier is None or not verifier.valid:
        return float("nan")
    place = placements(T, src_feats.centers, src_feats.descriptor, ref_feats.centers,
                       ref_feats.descriptor, rcfg)
    if place.support < rcfg.min_support or not place.hypotheses:
        return float("nan")
    own = verifier(T).footprint_fitness
    if not own > 0:
        return float("nan")
    return rival_fitness(place, T, verifier, pose_cfg, rcfg) / own


def _finish(out: Registration, timings: dict, t_start: float, own_total: bool) -> Registration:
    if own_total:
        timings["total"] = 1e3 * (time.perf_counter() - t_start)
    return out


def register_graphs(model: SGRegModel, src_graph: SceneGraph, ref_graph: SceneGraph,
                    cfg: PipelineConfig | None = None,
                    timings: dict | None = None) -> Registration:
    """Encode both graphs and register them; timings gets the encoding stages and "total"
    (from this call's start, plus whatever the caller already put in "graph")."""
    cfg = cfg or PipelineConfig()
    t_start = time.perf_counter()
    timings = {} if timings is None else timings
    dense = cfg.mode == "dense"
    src = model.encode(src_graph, dense=dense, timings=timings)
    ref = model.encode(ref_graph, dense=dense, timings=timings)
    out = register_features(model, src, ref, node_cloud(src_graph), reference_cloud(ref_graph), cfg,
                            timings)
    to_map_frames(out, src_graph.level, ref_graph.level)
    timings["total"] = (timings.get("level", 0.0) + timings.get("graph", 0.0)
                        + 1e3 * (time.perf_counter() - t_start))
    return out


def to_map_frames(reg: Registration, src_level: Levelling | None,
                  ref_level: Levelling | None) -> Registration:
    """Turn reg's T (and competitor), estimated between the levelled graphs, into T between the
    maps' own frames: T = R_ref^-1 T_levelled R_src. None: that map was not levelled."""
    S = src_level.T if src_level is not None else np.eye(4)
    R_inv = invert_transform(ref_level.T) if ref_level is not None else np.eye(4)
    reg.T = R_inv @ reg.T_levelled @ S
    if reg.T_competitor is not None:
        reg.T_competitor = R_inv @ reg.T_competitor @ S
    reg.levelling = {name: lev.to_json() for name, lev in (("src", src_level), ("ref", ref_level))
                     if lev is not None}
    return reg


def build_graphs(src_map: InstanceMap, ref_map: InstanceMap, cfg: PipelineConfig | None = None,
                 timings: dict | None = None) -> tuple[SceneGraph, SceneGraph]:
    """Scene graphs of both instance maps, each built on the levelled map (graph.level says
    how); timings["level"] and timings["graph"] get the time."""
    cfg = cfg or PipelineConfig()
    timings = {} if timings is None else timings
    t0 = time.perf_counter()
    (src_up, src_level), (ref_up, ref_level) = level_map(src_map, cfg.level), level_map(ref_map, cfg.level)
    _add(timings, "level", t0)
    t0 = time.perf_counter()
    graphs = build_scene_graph(src_up, cfg.graph), build_scene_graph(ref_up, cfg.graph)
    _add(timings, "graph", t0)
    graphs[0].level, graphs[1].level = src_level, ref_level
    graphs[0].map_points, graphs[1].map_points = src_up.points, ref_up.points
    return graphs
