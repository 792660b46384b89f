"""Run sgreg (dense and coarse) and the classical peers on the same cases and score each run.

What a method is timed on:
    sgreg_dense   instance maps in -> T out: both scene graphs built, both encoded (text,
                  shape, GNN), node + point matching, pose estimation with verification.
    sgreg_coarse  node matching + pose estimation (with verification and ICP on the node
                  clouds) from graphs already encoded, against a reference cloud already
                  prepared: an agent encodes and prepares its map once per map update, not
                  per peer message. That preparation is reported as ms_map_prep.
    peers         raw points in -> T out (downsampling, normals, features, ICP; see baselines).
Wall time (time_ms) is what the targets name; cpu_ms (process CPU time over all threads) is
reported next to it because the machine is shared.

Every method's claim of success is checked against the ground truth: success means
registration RMSE < max_rmse (metrics.registration_success); a claim without it is a false
claim. Cases without a solution (different rooms) make every claim false.

Public API:
    METHODS
    BenchConfig
    run_case(model, case, cfg) -> list of per-method row dicts
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field, replace

import numpy as np

from .baselines import BASELINES, BaselineConfig
from ..geometry import invert_transform
from ..metrics import (inlier_ratio, node_match_scores, registration_rmse, registration_success,
                       rre, rte)
from ..pose import ReferenceCloud
from ..pipeline import (PipelineConfig, Registration, build_graphs, node_cloud, reference_cloud,
                        register_features, register_graphs, to_map_frames)
from .cases import SETTINGS, Case, CaseConfig

SGREG_METHODS = ("sgreg_dense", "sgreg_coarse")
METHODS = SGREG_METHODS + tuple(BASELINES)


@dataclass
class BenchConfig:
    """cases:          which pairs (see bench.cases.CaseConfig).
    pipeline:          sgreg's pipeline; its mode is set per method (dense / coarse).
    baseline:          settings of the classical peers.
    methods:           methods run on every case (subset of METHODS).
    settings:          case settings run (subset of bench.cases.SETTINGS).
    weights:           model .safetensors ("" = the shipped model).
    max_rmse:          m, registration success threshold (registration recall).
    min_iou:           a ground-truth node pair needs this IoU (node recall / precision).
    inlier_threshold:  m, a correspondence is a true inlier when its ground-truth residual is
                       below this.
    threads:           torch threads."""

    cases: CaseConfig = field(default_factory=CaseConfig)
    pipeline: PipelineConfig = field(default_factory=PipelineConfig)
    baseline: BaselineConfig = field(default_factory=BaselineConfig)
    methods: tuple[str, ...] = METHODS
    settings: tuple[str, ...] = SETTINGS
    weights: str = ""
    max_rmse: float = 0.2
    min_iou: float = 0.3
    inlier_threshold: float = 0.1
    threads: int = 1

    def __post_init__(self):
        if self.threads < 1:
            raise ValueError(f"threads must be >= 1, got {self.threads}")
        bad = [m for m in self.methods if m not in METHODS]
        if bad:
            raise ValueError(f"unknown method(s) {bad}; choose from {list(METHODS)}")
        bad = [s for s in self.settings if s not in SETTINGS]
        if bad:
            raise ValueError(f"unknown setting(s) {bad}; choose from {list(SETTINGS)}")


def _score(case: Case, method: str, T: np.ndarray, claimed: bool, time_ms: float,
           cpu_ms: float, max_rmse: float) -> dict:
    row = {"group": case.setting if case.held_out else f"{case.setting}_seen",
           "setting": case.setting, "case": case.name, "held_out": case.held_out,
           "method": method, "claimed": bool(claimed), "time_ms": float(time_ms),
           "cpu_ms": float(cpu_ms),
           "T": np.asarray(T, np.float64).round(6).tolist()}
    if case.T_gt is None:
        row.update(success=False, rmse=float("nan"), rre=float("nan"), rte=float("nan"))
    else:
        row.update(success=registration_success(case.src.points, T, case.T_gt, max_rmse),
                   rmse=registration_rmse(case.src.points, T, case.T_gt),
                   rre=rre(T, case.T_gt), rte=rte(T, case.T_gt))
    row["false_claim"] = row["claimed"] and not row["success"]
    return row


def _level_T(level) -> np.ndarray:
    return np.eye(4) if level is None else level.T


def _sgreg_row(case: Case, method: str, reg: Registration, cpu_ms: float,
               cfg: BenchConfig, levels: tuple = (None, None)) -> dict:
    row = _score(case, method, reg.T, reg.success, reg.timing_ms["total"], cpu_ms, cfg.max_rmse)
    nodes = node_match_scores(reg.node_pairs, case.gt_node_pairs, case.gt_iou, cfg.min_iou)
    nan = float("nan")
    has_gt = case.T_gt is not None
    # correspondences are between the levelled graphs: so is the truth they are scored against
    T_gt = None if not has_gt else (_level_T(levels[1]) @ case.T_gt @ invert_transform(_level_T(levels[0])))
    row.update(reason=reg.reason, node_matches=reg.node_matches, gt_node_matches=nodes.ground_truth,
               node_recall=nodes.recall if has_gt else nan,
               node_precision=nodes.precision if has_gt else nan,
               correspondences=reg.correspondences, inliers=reg.inliers,
               inlier_nodes=reg.inlier_nodes,
               fitness=reg.fitness, footprint_fitness=reg.footprint_fitness,
               confidence=reg.confidence, ambiguity=reg.evidence.ambiguity,
               # share of the correspondences that are right (before pose estimation)
               inlier_ratio=(inlier_ratio(reg.corr.src_xyz, reg.corr.ref_xyz, T_gt, cfg.inlier_threshold)
                             if has_gt and reg.correspondences else nan),
               # share of what the estimator kept as inliers that is right
               pseudo_inlier_ratio=(inlier_ratio(reg.corr.src_xyz[reg.inlier_mask],
                                                 reg.corr.ref_xyz[reg.inlier_mask], T_gt,
                                                 cfg.inlier_threshold)
                                    if has_gt and reg.inlier_mask.any() else nan))
    row.update({f"ms_{k}": float(v) for k, v in reg.timing_ms.items()})
    row.update({f"ms_pose_{k}": float(v) for k, v in reg.pose_timing_ms.items()})
    row["refined"] = reg.refined
    row["guided"] = reg.guided
    row["geometric"] = reg.geometric
    row["unrepeated"] = reg.unrepeated
    row["repeat"] = reg.repeat
    row["evidence"] = dict(vars(reg.evidence))     # what the verdict weighed (choose_verdict.py)
    return row


def _run_sgreg(model, case: Case, cfg: BenchConfig) -> list[dict]:
    """The rows of the sgreg methods of cfg.methods: each method's own failure is its own error
    row (a coarse estimate that raises leaves the dense row standing); graphs that cannot be
    built fail both."""
    rows = []
    timings: dict = {}
    t0, cpu0 = time.perf_counter(), time.process_time()
    wanted = [m for m in SGREG_METHODS if m in cfg.methods]
    try:
        src_graph, ref_graph = build_graphs(case.src, case.ref, cfg.pipeline, timings)
    except Exception as exc:  # noqa: BLE001 - one broken case must not end the benchmark
        return [_error_row(case, m, exc, t0, cfg) for m in wanted]
    levels = (src_graph.level, ref_graph.level)

    def dense() -> dict:
        reg = register_graphs(model, src_graph, ref_graph, replace(cfg.pipeline, mode="dense"), timings)
        return _sgreg_row(case, "sgreg_dense", reg, _cpu_ms(cpu0), cfg, levels)

    def coarse() -> dict:
        # a coarse message carries what encode(dense=False) gives; only matching + pose timed
        src, ref = model.encode(src_graph, dense=False), model.encode(ref_graph, dense=False)
        settings = replace(cfg.pipeline, mode="coarse")
        t_prep = time.perf_counter()
        pose = settings.pose_config()
        reference = ReferenceCloud(reference_cloud(ref_graph), pose.verify_voxel, pose.footprint_cell)
        prep_ms = 1e3 * (time.perf_counter() - t_prep)
        cpu_match = time.process_time()
        reg = to_map_frames(register_features(model, src, ref, node_cloud(src_graph), reference, settings),
                            *levels)
        return _sgreg_row(case, "sgreg_coarse", reg, _cpu_ms(cpu_match), cfg, levels) | {"ms_map_prep": prep_ms}

    for method, estimate in (("sgreg_dense", dense), ("sgreg_coarse", coarse)):
        if method in wanted:
            t0 = time.perf_counter()
            try:
                rows.append(estimate())
            except Exception as exc:  # noqa: BLE001
                rows.append(_error_row(case, method, exc, t0, cfg))
    return rows


def _cpu_ms(cpu0: float) -> float:
    """CPU time of this process since cpu0 (all its threads): unlike wall time, barely moved by
    other jobs on the machine."""
    return 1e3 * (time.process_time() - cpu0)


def _error_row(case: Case, method: str, exc: Exception, t0: float, cfg: BenchConfig) -> dict:
    """A method that raised counts as a failure that did not claim success; the error is kept."""
    row = _score(case, method, np.eye(4), False, 1e3 * (time.perf_counter() - t0), float("nan"),
                 cfg.max_rmse)
    row["error"] = f"{type(exc).__name__}: {exc}"
    return row


def run_case(model, case: Case, cfg: BenchConfig) -> list[dict]:
    """One row per method of cfg.methods (in METHODS order) for this case."""
    rows = []
    if any(m in cfg.methods for m in SGREG_METHODS):
        rows += _run_sgreg(model, case, cfg)
    for name in BASELINES:
        if name not in cfg.methods:
            continue
        t0, cpu0 = time.perf_counter(), time.process_time()
        try:
            res = BASELINES[name](case.src.points, case.ref.points, cfg.baseline)
            rows.append(_score(case, name, res.T, res.success, res.time_ms, _cpu_ms(cpu0),
                               cfg.max_rmse) | {"fitness": res.fitness})
        except Exception as exc:  # noqa: BLE001
            rows.append(_error_row(case, name, exc, t0, cfg))
    return rows
