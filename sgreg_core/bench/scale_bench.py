"""How registration grows with the size of the graphs (`sgreg bench-scale`).

Graphs of n nodes are cut from one synthetic building (simulation/synth, kind "building", no
identical rooms: this measures time, not ambiguity): two stretches along the corridor, the
source view up to the n-th instance (by centroid), the reference view from the n/2-th to the
3n/2-th (so about half of each graph is shared), every shared point sampled by one view only,
the source moved by a random 4-DoF transform. Per size: scene-graph
construction, encoding (text, shape, GNN), a coarse registration (node centers, the 1 Hz path)
a dense one on every node, and a dense one as the nodes run it (the peer sends the points of
its PeersConfig.max_request_nodes best-matched nodes only), the estimator's own steps, the message sizes, and the process's peak
memory. Each size runs `repeats` times; medians are reported.

Where the quadratic parts are: the node similarity (n x n), the object edges (pairwise center
distances), and in the estimator the pairwise compatibility of correspondences (c x c) and the
clique search on it; point matching is per node match (Sinkhorn on K x K per pair), so linear in
the matches.

Public API:
    ScaleConfig
    scale_cases(cfg) -> list[(n, src InstanceMap, ref InstanceMap, T_gt)]
    run_scale(model, cfg, log) -> list[dict]   one row per size
    growth(rows, key) -> float                 the exponent k of time ~ n^k (least squares)
    verified_and_right(reg, T_gt) -> bool      how each row's *_ok is counted
"""
from __future__ import annotations

import resource
import time
from dataclasses import dataclass, replace

import numpy as np

from ..geometry import invert_transform, yaw_transform
from ..maps.instance_map import labelled_mask, select_points
from ..metrics import two_agent_success
from ..net.model import SGRegModel
from ..pipeline import PipelineConfig, build_graphs, node_cloud, reference_cloud, register_features, to_map_frames
from ..pose import ReferenceCloud
from ..runtime.peers import PeersConfig
from ..runtime.wire import DEFAULT_ENCODING, ENCODINGS, pack_features
from ..simulation.synth import SynthConfig, generate_scene
from ..types import InstanceMap


@dataclass
class ScaleConfig:
    """nodes: graph sizes; repeats: registrations per size (medians); seed: building and
    transforms; rooms_per_node: building rooms per graph node needed (about 25 instances a
    room, and the two views together hold 1.5 n); feature_encoding: of the coarse message."""

    nodes: tuple[int, ...] = (50, 100, 200, 400)
    repeats: int = 3
    seed: int = 0
    rooms_per_node: float = 1 / 14
    feature_encoding: str = DEFAULT_ENCODING


def _instances_along(imap: InstanceMap) -> tuple[np.ndarray, np.ndarray]:
    """Labelled instance ids ordered by their centroid's x (the corridor's direction), and
    those centroids' x."""
    mask = labelled_mask(imap)
    ids, inv = np.unique(imap.instance[mask], return_inverse=True)
    cx = np.bincount(inv, imap.points[mask, 0]) / np.bincount(inv)
    order = np.argsort(cx)
    return ids[order], cx[order]


def scale_cases(cfg: ScaleConfig) -> list[tuple[int, InstanceMap, InstanceMap, np.ndarray]]:
    rng = np.random.default_rng(cfg.seed)
    rooms = max(10, int(np.ceil(1.5 * max(cfg.nodes) * cfg.rooms_per_node)))
    scene = generate_scene(cfg.seed, SynthConfig(kind="building", rooms=rooms, run=1))
    order, cx = _instances_along(scene)
    owner = rng.random(len(scene.points)) < 0.5       # each point sampled by one view only
    x = scene.points[:, 0]
    out = []
    for n in cfg.nodes:
        if 1.5 * n > len(order):
            raise ValueError(f"the building has {len(order)} instances, {int(1.5 * n)} needed for {n} nodes")
        in_src = x <= cx[n - 1]
        in_ref = (x >= cx[n // 2]) & (x <= cx[n // 2 + n - 1])
        shared = in_src & in_ref
        src = select_points(scene, in_src & (owner | ~shared))
        ref = select_points(scene, in_ref & (~owner | ~shared))
        T = yaw_transform(rng.uniform(-np.pi, np.pi), (*rng.uniform(-10, 10, 2), 0.0))
        src = src.transformed(invert_transform(T))
        out.append((n, src, ref, T))
    return out


def _best_matched(reg, k: int) -> np.ndarray:
    """The source node ids of the k most confident node matches (Peers._maybe_request)."""
    ids = reg.node_pairs[np.argsort(-reg.node_scores, kind="stable"), 0]
    _, first = np.unique(ids, return_index=True)
    return ids[np.sort(first)][:k]


def verified_and_right(reg, T_gt: np.ndarray) -> bool:
    """What a user counts as a registration: verified, and right by ground truth (an estimate
    claiming success at a wrong pose is not one)."""
    return bool(reg.success and two_agent_success(reg.T, T_gt))


def _peak_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def run_scale(model: SGRegModel, cfg: ScaleConfig, log=print) -> list[dict]:
    pipe = PipelineConfig()
    encoding = ENCODINGS[cfg.feature_encoding]
    rows = []
    for n, src_map, ref_map, T_gt in scale_cases(cfg):
        samples = []
        for _ in range(cfg.repeats):
            t: dict = {}
            t0 = time.perf_counter()
            g_src, g_ref = build_graphs(src_map, ref_map, pipe, t)
            t1 = time.perf_counter()
            f_src, f_ref = model.encode(g_src, dense=True, timings=t), model.encode(g_ref, dense=True, timings=t)
            t2 = time.perf_counter()
            coarse_cfg = replace(pipe, mode="coarse")
            reference = ReferenceCloud(reference_cloud(g_ref), coarse_cfg.pose_config().verify_voxel,
                                       coarse_cfg.pose_config().footprint_cell)
            t3 = time.perf_counter()
            coarse = to_map_frames(register_features(model, f_src, f_ref, node_cloud(g_src), reference,
                                                     coarse_cfg), g_src.level, g_ref.level)
            t4 = time.perf_counter()
            dense = to_map_frames(register_features(model, f_src, f_ref, node_cloud(g_src), reference,
                                                    replace(pipe, mode="dense")), g_src.level, g_ref.level)
            t5 = time.perf_counter()
            # what a node runs: the peer sends the points of its best-matched nodes only
            best = _best_matched(coarse, PeersConfig().max_request_nodes)
            keep = np.isin(f_src.node_ids, best)
            f_req = replace(f_src, node_ids=f_src.node_ids[keep], centers=f_src.centers[keep],
                            descriptor=f_src.descriptor[keep], points=f_src.points[keep],
                            valid=f_src.valid[keep], z=f_src.z[keep])
            t6 = time.perf_counter()
            requested = to_map_frames(register_features(model, f_req, f_ref, f_req.points[f_req.valid], reference,
                                                        replace(pipe, mode="dense")), g_src.level, g_ref.level)
            t7 = time.perf_counter()
            samples.append({"dense_requested_ms": 1e3 * (t7 - t6),"level_graph_ms": 1e3 * (t1 - t0), "encode_ms": 1e3 * (t2 - t1),
                            "map_prep_ms": 1e3 * (t3 - t2), "coarse_ms": 1e3 * (t4 - t3),
                            "dense_ms": 1e3 * (t5 - t4),
                            **{f"dense_pose_{k}_ms": v for k, v in dense.pose_timing_ms.items()},
                            "dense_point_match_ms": dense.timing_ms.get("point_match", 0.0)})
        payload, scales = pack_features(f_src.descriptor, encoding)
        coarse_bytes = len(payload) + 4 * len(scales) + f_src.num_nodes * (4 + 12 + 12) + 64
        dense_bytes = coarse_bytes + 16 * int(f_src.valid.sum())
        row = {"nodes": n, "src_nodes": g_src.num_nodes, "ref_nodes": g_ref.num_nodes,
               "edges": g_src.num_edges, "node_matches": dense.node_matches,
               "correspondences": dense.correspondences,
               "coarse_ok": verified_and_right(coarse, T_gt),
               "dense_requested_ok": verified_and_right(requested, T_gt),
               "dense_ok": verified_and_right(dense, T_gt),
               "coarse_message_kb": coarse_bytes / 1e3, "dense_message_kb": dense_bytes / 1e3,
               "peak_rss_mb": _peak_mb()}
        for k in samples[0]:
            row[k] = float(np.median([s.get(k, 0.0) for s in samples]))
        rows.append(row)
        log(f"{n} nodes: coarse {row['coarse_ms']:.0f} ms, dense {row['dense_ms']:.0f} ms, "
            f"{row['correspondences']} correspondences, peak {row['peak_rss_mb']:.0f} MB")
    return rows


MIN_TIMED_MS = 0.1   # a stage this fast at some size is below the timer's resolution there


def growth(rows: list[dict], key: str) -> float:
    """k in time ~ n^k, a least-squares line through log time against log nodes; NaN with one
    size, or where the stage took less than MIN_TIMED_MS at some size (its log says nothing)."""
    if len(rows) < 2 or min(r[key] for r in rows) < MIN_TIMED_MS:
        return float("nan")
    n = np.log([r["nodes"] for r in rows])
    v = np.log([r[key] for r in rows])
    return float(np.polyfit(n, v, 1)[0])
