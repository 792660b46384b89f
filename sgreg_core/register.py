"""The registration pipeline: two scene graphs (or their encoded features) -> a verified T.

One pipeline for every caller (the `sgreg register` CLI, `sgreg bench-register`, the ROS
registration node), so that what is benchmarked is what runs.

    dense:  encode both graphs -> node matches (dual softmax) -> point matches (Sinkhorn)
            -> estimate_pose on the point correspondences
    coarse: node matches -> estimate_pose on the matched node centers only

Either way the verification clouds are all node points of each graph (what a dense message
carries), so even a coarse estimate is checked against geometry when the clouds are at hand.
Node centers of partly seen objects move with what was seen, so coarse mode has its own
PoseConfig with a wider inlier bound and ICP reach. By default every estimate that passes the
correspondence checks is refined by ICP on the verification clouds, and the estimator's verdict
is taken on the better supported of the estimate and its refinement (pose/estimator.py).

Public API:
    RegisterConfig                 graph, dense / coarse PoseConfig, mode, icp, min_nodes
    Registration                   T (SRC -> REF), verdict, matches, correspondences, timings
    register_graphs(model, src_graph, ref_graph, cfg, timings=None) -> Registration
    build_graphs(src_map, ref_map, cfg, timings) -> (src_graph, ref_graph)   ("graph" stage)
    register_features(model, src_feats, ref_feats, src_cloud, ref_cloud, cfg, timings)
    node_cloud(graph) -> (N, 3)    all node points of a graph (the verification cloud)
    warm_up(model)                 load the text encoder now, so that no timing includes it
    TIMING_STAGES                  the keys of Registration.timing_ms, in pipeline order
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field, replace

import numpy as np

from .net.model import NodeFeatures, SGRegModel
from .pose import PoseConfig, ReferenceCloud, estimate_pose
from .scene_graph import GraphConfig, build_scene_graph
from .types import InstanceMap, SceneGraph

MODES = ("dense", "coarse")
ICP_MODES = ("never", "coarse", "always")
# graph: scene graphs of both maps; text / sample / shape / gnn: encoding of both graphs
# (label embeddings, node point sampling, shape + point features, GNN); node_match /
# point_match: matching; pose: estimation, verification and ICP; total: the whole call.
TIMING_STAGES = ("graph", "text", "sample", "shape", "gnn", "node_match", "point_match", "pose",
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
    return PoseConfig(noise_bound=0.3, nms_radius=0.0, min_inliers=4,
                      clique_deltas=(0.2, 0.4, 0.8), verify_voxel=0.1, icp_distance=0.2,
                      verify_max_points=600, icp_max_iters=15)


@dataclass
class RegisterConfig:
    """graph:       scene-graph construction (only used when starting from instance maps).
    pose:           estimator settings of dense mode (point correspondences).
    coarse_pose:    estimator settings of coarse mode (node-center correspondences).
    mode:           "dense" (points) or "coarse" (node centers only).
    icp:            when the estimate is refined with point-to-plane ICP on the
                    verification clouds before the verdict: "never", "coarse" (coarse mode
                    only) or "always" (default: even centimetre-accurate point matches leave
                    a degree of rotation that costs a low-overlap pair its support); overrides
                    the pose configs' own `icp`.
    min_nodes:      graphs with fewer nodes are not registered (reason "too_few_nodes")."""

    graph: GraphConfig = field(default_factory=GraphConfig)
    pose: PoseConfig = field(default_factory=_dense_pose)
    coarse_pose: PoseConfig = field(default_factory=_coarse_pose)
    mode: str = "dense"
    icp: str = "always"
    min_nodes: int = 3

    def __post_init__(self):
        if self.mode not in MODES:
            raise ValueError(f"mode must be one of {MODES}, got {self.mode!r}")
        if self.icp not in ICP_MODES:
            raise ValueError(f"icp must be one of {ICP_MODES}, got {self.icp!r}")

    def pose_config(self) -> PoseConfig:
        icp = self.icp == "always" or (self.icp == "coarse" and self.mode == "coarse")
        return replace(self.pose if self.mode == "dense" else self.coarse_pose, icp=icp)


@dataclass
class Registration:
    """Outcome of one registration.

    T:               (4, 4) float64 mapping SRC points into REF's frame (ICP-refined when
                     RegisterConfig.icp asks for it and ICP kept the fitness); identity when
                     nothing was estimated.
    success:         True only when the pose estimator accepted the estimate.
    reason:          "ok", "too_few_nodes", "no_node_matches" or the estimator's reason.
    mode:            "dense" or "coarse".
    node_pairs:      (m, 2) int64 matched (src node id, ref node id); node_scores (m,).
    src_xyz, ref_xyz: (c, 3) the correspondences handed to the estimator (points in dense
                     mode, node centers in coarse mode), SRC and REF frames.
    inlier_mask:     (c,) bool, inliers of the estimator's pose (before any ICP).
    inliers, inlier_ratio: their count and share.
    inlier_nodes:    node matches with at least one inlier correspondence.
    fitness:         verification fitness of T: share of SRC points on REF surfaces (NaN
                     without clouds).
    footprint_fitness: the same share among the SRC points that land on REF's footprint, the
                     measure of the verdict (pose/verify.py; NaN without clouds).
    refined:         True when T is the ICP refinement.
    timing_ms:       milliseconds per TIMING_STAGES entry that ran, and "total".
    pose_timing_ms:  the estimator's own steps (nms, gnc, clique, candidates, verify, icp)."""

    T: np.ndarray = field(default_factory=lambda: np.eye(4))
    success: bool = False
    reason: str = "too_few_nodes"
    mode: str = "dense"
    node_pairs: np.ndarray = field(default_factory=lambda: np.zeros((0, 2), np.int64))
    node_scores: np.ndarray = field(default_factory=lambda: np.zeros(0, np.float32))
    src_xyz: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    ref_xyz: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    inlier_mask: np.ndarray = field(default_factory=lambda: np.zeros(0, bool))
    inliers: int = 0
    inlier_ratio: float = 0.0
    inlier_nodes: int = 0
    fitness: float = float("nan")
    footprint_fitness: float = float("nan")
    refined: bool = False
    timing_ms: dict[str, float] = field(default_factory=dict)
    pose_timing_ms: dict[str, float] = field(default_factory=dict)

    @property
    def node_matches(self) -> int:
        return int(self.node_pairs.shape[0])

    @property
    def correspondences(self) -> int:
        return int(self.src_xyz.shape[0])

    def to_json(self) -> dict:
        """The result JSON of DESIGN.md section 3 (+ reason, mode, counts, node pairs)."""
        return {
            "T": np.asarray(self.T, np.float64).tolist(),
            "success": bool(self.success),
            "reason": self.reason,
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
            "timing_ms": {k: round(float(v), 3) for k, v in self.timing_ms.items()},
        }


def _finite_or_none(v: float) -> float | None:
    return float(v) if np.isfinite(v) else None


def node_cloud(graph: SceneGraph) -> np.ndarray:
    """All node points of a graph, (N, 3) float32 (the verification cloud)."""
    if graph.num_nodes == 0:
        return np.zeros((0, 3), np.float32)
    return np.concatenate(graph.points).astype(np.float32, copy=False)


def warm_up(model: SGRegModel) -> None:
    """Load the text encoder's weights (seconds, on first use) so that registration timings
    measure registration."""
    model.text_encoder.encode(["object"])


def _add(timings: dict, stage: str, t0: float) -> None:
    timings[stage] = timings.get(stage, 0.0) + 1e3 * (time.perf_counter() - t0)


def register_features(model: SGRegModel, src_feats: NodeFeatures, ref_feats: NodeFeatures,
                      src_cloud: np.ndarray | None = None,
                      ref_cloud: np.ndarray | ReferenceCloud | None = None,
                      cfg: RegisterConfig | None = None,
                      timings: dict | None = None) -> Registration:
    """Match encoded graphs and estimate T (SRC -> REF). Dense mode needs dense features.

    src_cloud / ref_cloud: verification clouds in each graph's frame (all node points;
    ref_cloud may be a prebuilt pose.ReferenceCloud); without them success rests on inlier
    count and spread only. timings: stages already
    spent by the caller (graph, encoding) are kept and the matching / pose stages added;
    "total" is left to the caller when it passes timings in (it knows where it started)."""
    cfg = cfg or RegisterConfig()
    t_start = time.perf_counter()
    own_total = timings is None
    timings = {} if timings is None else timings
    out = Registration(mode=cfg.mode, timing_ms=timings)
    if min(src_feats.num_nodes, ref_feats.num_nodes) < cfg.min_nodes:
        return _finish(out, timings, t_start, own_total)
    if cfg.mode == "dense":
        dm = model.match_dense(src_feats, ref_feats, timings)
        nodes = dm.nodes
        src_xyz, ref_xyz, weights = dm.points.src_xyz, dm.points.ref_xyz, dm.points.score
        corr_node = np.asarray(dm.points.node_match, np.int64)
    else:
        nodes = model.match_coarse(src_feats, ref_feats, timings)
        src_xyz, ref_xyz, weights = nodes.src_xyz, nodes.ref_xyz, nodes.score
        corr_node = np.arange(len(nodes))
    out.node_pairs = np.stack([np.asarray(src_feats.node_ids)[nodes.src_idx],
                               np.asarray(ref_feats.node_ids)[nodes.ref_idx]], 1).astype(np.int64)
    out.node_scores = np.asarray(nodes.score, np.float32)
    out.src_xyz = np.asarray(src_xyz, np.float64).reshape(-1, 3)
    out.ref_xyz = np.asarray(ref_xyz, np.float64).reshape(-1, 3)
    out.inlier_mask = np.zeros(out.correspondences, bool)
    if len(nodes) == 0:
        out.reason = "no_node_matches"
        return _finish(out, timings, t_start, own_total)

    t0 = time.perf_counter()
    res = estimate_pose(out.src_xyz, out.ref_xyz, weights, src_cloud, ref_cloud,
                        cfg.pose_config())
    _add(timings, "pose", t0)
    out.success, out.reason, out.T, out.refined = bool(res.success), res.reason, res.T, res.refined
    out.inlier_mask = res.inlier_mask
    out.inliers, out.inlier_ratio = int(res.inliers), float(res.inlier_ratio)
    out.inlier_nodes = int(np.unique(corr_node[res.inlier_mask]).size)
    out.fitness, out.footprint_fitness = float(res.fitness), float(res.footprint_fitness)
    out.pose_timing_ms = {k: v for k, v in res.timing_ms.items() if k != "total"}
    return _finish(out, timings, t_start, own_total)


def _finish(out: Registration, timings: dict, t_start: float, own_total: bool) -> Registration:
    if own_total:
        timings["total"] = 1e3 * (time.perf_counter() - t_start)
    return out


def register_graphs(model: SGRegModel, src_graph: SceneGraph, ref_graph: SceneGraph,
                    cfg: RegisterConfig | None = None,
                    timings: dict | None = None) -> Registration:
    """Encode both graphs and register them; timings gets the encoding stages and "total"
    (from this call's start, plus whatever the caller already put in "graph")."""
    cfg = cfg or RegisterConfig()
    t_start = time.perf_counter()
    timings = {} if timings is None else timings
    dense = cfg.mode == "dense"
    src = model.encode(src_graph, dense=dense, timings=timings)
    ref = model.encode(ref_graph, dense=dense, timings=timings)
    out = register_features(model, src, ref, node_cloud(src_graph), node_cloud(ref_graph), cfg,
                            timings)
    timings["total"] = timings.get("graph", 0.0) + 1e3 * (time.perf_counter() - t_start)
    return out


def build_graphs(src_map: InstanceMap, ref_map: InstanceMap, cfg: RegisterConfig | None = None,
                 timings: dict | None = None) -> tuple[SceneGraph, SceneGraph]:
    """Scene graphs of both instance maps; their build time goes to timings["graph"]."""
    cfg = cfg or RegisterConfig()
    t0 = time.perf_counter()
    graphs = build_scene_graph(src_map, cfg.graph), build_scene_graph(ref_map, cfg.graph)
    if timings is not None:
        _add(timings, "graph", t0)
    return graphs
