"""Training and validation pairs of scene graphs with ground truth (paper section V).

A pair is cut on the fly from one of three sources and cached to disk (npz), so every later
epoch, run or resume reads it back in milliseconds:
  * "scan":   two overlapping partial views of one real scan (pairs.make_pair);
  * "rescan": a view of one capture of a room against a view of another capture of the same
              room, with the pseudo ground truth of rescan_gt.json (furniture moved, other
              coverage: the most realistic pairs we have);
  * "synth":  two views of a synthetic apartment or office (sgreg_core.simulation.synth).
Real scans of the validation room never enter training. Ground-truth node pairs come from the
voxel-occupancy IoU of the node clouds in the common frame (pairs.node_iou).

Each time a pair is used it is re-augmented: both graphs get their own random 4-DoF transform
(yaw in [-180, 180)), so the network never sees a pair twice in the same frames.

Public API:
    DataConfig
    GraphPair                      src, ref (SceneGraph), T_src_ref, gt (m, 2) node indices, gt_iou
    PairSource(cfg, split, seed)   .pair(i) -> GraphPair (cached), len() = pool size
    augment(pair, rng) -> GraphPair
    graph_pair_from_registration(pair, graph_cfg) -> GraphPair
"""
from __future__ import annotations

import dataclasses
import hashlib
import json
import os
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path

import numpy as np

from ..config import finite_number
from ..geometry import invert_transform, transform_points, yaw_transform
from ..maps.instance_map import labelled_mask, read_instance_map
from ..paths import RESCAN_GT, SCANS, require, resolve, source_digest
from ..rescan_gt import accepted_directions, load_rescan_gt, room_of
from ..simulation.noise import NoiseConfig
from ..simulation.pairs import PairConfig, RegistrationPair, make_pair, node_iou
from ..maps.level import LevelConfig, level_map
from ..maps.scene_graph import GraphConfig, build_scene_graph
from ..types import InstanceMap, SceneGraph


@dataclass
class DataConfig:
    """scans_dir:     real scans (instance map directories, docs/ARCHITECTURE.md); relative paths
                      start at the repository (sgreg_core/paths.py).
    scan_prefix:      scans used (the 50k-point "picwoon" subsamples; others duplicate rooms).
    rescan_gt:        pseudo ground truth between captures of one room ("" to skip rescans).
    test_rooms:       scene ids held out of training and of validation alike (all captures):
                      only benchmarks report on them (split "test": bench-match; bench-register
                      and the replay suites' held-out rows), so no choice of weights, settings
                      or thresholds can rest on them.
    val_room:         a scene id kept out of training (all its captures) to validate on; empty:
                      validation on synthetic scenes never trained on (seeds synth_scenes ..
                      synth_scenes + val_synth_scenes - 1). Never one of test_rooms.
    train_pairs / val_pairs: pool sizes; a training run cycles through its pool (the test
                      split's pool is val_pairs too).
    mix:              relative weight of the sources scan / rescan / synth in training.
    synth_scenes:     distinct synthetic scenes (seeds 0..n-1), 1-2 rooms each.
    val_synth_scenes: synthetic scenes of the validation split when val_room is empty.
    overlap:          overlap of two views, uniform in this range.
    halves_prob:      probability that views split every point (half density) rather than the band.
    noise_prob:       probability that a pair gets front-end noise.
    noise:            the NoiseConfig.preset names of that noise (default every kind a front end
                      makes: wrong classes, merged and invented objects, tilt, jitter, ...).
    min_matches:      a pair needs this many gt node matches at IoU >= iou_store, else re-cut.
    iou_store:        gt node pairs kept down to this IoU (the losses pick their own threshold).
    cache_dir:        root of the pair cache; a hash of this config names the sub-directory.
    level:            each view is levelled before its graph is built, as in the pipeline."""

    scans_dir: str = SCANS
    scan_prefix: str = "scannet-picwoon_"
    rescan_gt: str = RESCAN_GT
    test_rooms: tuple[str, ...] = ("scene0005",)
    val_room: str = ""
    train_pairs: int = 800
    val_pairs: int = 40
    mix: dict = field(default_factory=lambda: {"scan": 0.4, "rescan": 0.2, "synth": 0.4})
    synth_scenes: int = 200
    val_synth_scenes: int = 20
    overlap: tuple[float, float] = (0.3, 0.8)
    halves_prob: float = 0.3
    noise_prob: float = 0.5
    noise: str = NoiseConfig.FRONTEND
    min_matches: int = 3
    iou_store: float = 0.1
    cache_dir: str = "runs/cache/pairs"
    level: LevelConfig = field(default_factory=LevelConfig)
    graph: GraphConfig = field(default_factory=GraphConfig)

    def __post_init__(self):
        # a misspelt source would train on the others without a word
        bad = {k: v for k, v in self.mix.items() if k not in MIX_SOURCES or not finite_number(v) or v < 0}
        if bad:
            raise ValueError(f"data.mix: {bad} are not weights >= 0 of the sources {', '.join(MIX_SOURCES)}")
        # splits compare rooms (rescan_gt.room_of): a capture named here would match nothing
        captures = [r for r in (*self.test_rooms, self.val_room) if r and room_of(r) != r]
        if captures:
            raise ValueError(f"data.test_rooms / val_room: {captures} name captures, not rooms "
                             f"(e.g. {room_of(captures[0])!r})")
        if self.val_room and self.val_room in self.test_rooms:
            raise ValueError(f"data.val_room {self.val_room} is one of test_rooms: a room held out "
                             "for reporting must not select weights")
        if self.val_synth_scenes < 1:
            raise ValueError("data.val_synth_scenes must be >= 1")


MIX_SOURCES = ("scan", "rescan", "synth")


@dataclass
class GraphPair:
    src: SceneGraph
    ref: SceneGraph
    T_src_ref: np.ndarray  # (4, 4) src graph frame -> ref graph frame
    gt: np.ndarray         # (m, 2) int64 (src node index, ref node index)
    gt_iou: np.ndarray     # (m,) float32
    source: str = ""

    def matches(self, min_iou: float) -> np.ndarray:
        return self.gt[self.gt_iou >= min_iou]


# ---- construction ----------------------------------------------------------------------
def _node_index(graph: SceneGraph, ids: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Node index of each instance id, and whether the id is a node at all (small instances
    are not)."""
    if graph.num_nodes == 0:
        return np.zeros(len(ids), np.int64), np.zeros(len(ids), bool)
    order = np.argsort(graph.node_ids)
    pos = np.searchsorted(graph.node_ids[order], ids).clip(0, graph.num_nodes - 1)
    return order[pos], graph.node_ids[order][pos] == ids


def graph_pair_from_registration(pair: RegistrationPair, graph_cfg: GraphConfig,
                                 source: str = "", level_cfg: LevelConfig | None = None) -> GraphPair:
    """Scene graphs of both views, each levelled first as the pipeline levels maps (so tilted
    views train the network on what it will see); gt instance-id pairs become node-index
    pairs, and T_src_ref maps the levelled source graph onto the levelled reference graph."""
    (src_map, src_level), (ref_map, ref_level) = (level_map(pair.src, level_cfg),
                                                  level_map(pair.ref, level_cfg))
    src, ref = build_scene_graph(src_map, graph_cfg), build_scene_graph(ref_map, graph_cfg)
    T = ref_level.T @ np.asarray(pair.T_src_ref, np.float64) @ invert_transform(src_level.T)
    si, s_ok = _node_index(src, pair.gt_node_pairs[:, 0])
    ri, r_ok = _node_index(ref, pair.gt_node_pairs[:, 1])
    keep = s_ok & r_ok
    return GraphPair(src=src, ref=ref, T_src_ref=T,
                     gt=np.stack([si[keep], ri[keep]], 1).astype(np.int64),
                     gt_iou=pair.gt_iou[keep].astype(np.float32), source=source)


def _rescan_pair(a: InstanceMap, b: InstanceMap, T_ab: np.ndarray, cfg: PairConfig,
                 rng: np.random.Generator) -> RegistrationPair:
    """A view of capture a (moved at random) against a view of capture b, gt from T_ab."""
    view_a, view_b = make_pair(a, cfg, rng), make_pair(b, cfg, rng)
    src, ref = view_a.src, view_b.ref
    # src view -> a's ref view (a tilted by its ref tilt) -> a -> b -> b's ref view (b tilted)
    tilt_a, tilt_b = (np.asarray(v.meta.get("ref_tilt", np.eye(4)), np.float64) for v in (view_a, view_b))
    T = tilt_b @ T_ab @ invert_transform(tilt_a) @ view_a.T_src_ref
    ms, mr = labelled_mask(src), labelled_mask(ref)
    pairs, iou = node_iou(transform_points(T, src.points[ms]), src.instance[ms],
                          ref.points[mr], ref.instance[mr], cfg.iou_voxel)
    keep = iou >= cfg.iou_store
    return RegistrationPair(src=src, ref=ref, T_src_ref=T, gt_node_pairs=pairs[keep],
                            gt_iou=iou[keep], meta={"rescan": True})


@lru_cache(maxsize=32)
def _read_scan(path: str) -> InstanceMap:
    return read_instance_map(path)


@lru_cache(maxsize=8)
def _synth_scene(seed: int) -> InstanceMap:
    from ..simulation.synth import SynthConfig, generate_scene

    rng = np.random.default_rng([seed, 7])
    cfg = SynthConfig(kind=("apartment", "office")[int(rng.integers(2))], rooms=int(rng.integers(1, 3)))
    return generate_scene(seed, cfg)


SPLITS = ("train", "val", "test")


class PairSource:
    """The pool of pairs of one split, generated lazily and cached: "train" (every room but
    val_room and test_rooms, and synthetic scenes), "val" (val_room, or unseen synthetic
    scenes) or "test" (test_rooms: what benchmarks report, never what runs choose on)."""

    def __init__(self, cfg: DataConfig, split: str, seed: int = 0):
        if split not in SPLITS:
            raise ValueError(f"split must be one of {SPLITS}, got {split!r}")
        self.cfg, self.split, self.seed = cfg, split, seed
        scans = sorted(p.name for p in require(cfg.scans_dir, "scans folder").glob(cfg.scan_prefix + "*")
                       if p.is_dir())

        def split_of(name: str) -> str:
            room = room_of(name)
            if room in cfg.test_rooms:
                return "test"
            return "val" if cfg.val_room and room == cfg.val_room else "train"
        self.scans = [s for s in scans if split_of(s) == split]
        self.rescans = self._rescan_list(set(self.scans))
        sources = {"scan": bool(self.scans), "rescan": bool(self.rescans),
                   "synth": split == "train" and cfg.synth_scenes > 0}
        if split == "train":
            weights = dict(cfg.mix)
        elif split == "val" and not cfg.val_room:    # synthetic scenes no training pair came from
            weights, sources["synth"] = {"synth": 1.0}, True
        else:   # real pairs of the held-out rooms only
            weights = {"scan": 0.7, "rescan": 0.3}
        self.weights = {k: float(w) for k, w in weights.items() if sources.get(k) and w > 0}
        if not self.weights:
            raise FileNotFoundError(f"no data for split {split!r}: scans {cfg.scans_dir}/"
                                    f"{cfg.scan_prefix}* (test rooms {', '.join(cfg.test_rooms) or '-'}, "
                                    f"val room {cfg.val_room or '-'}), synthetic scenes {cfg.synth_scenes}")
        self.size = cfg.train_pairs if split == "train" else cfg.val_pairs
        self.cache = Path(cfg.cache_dir) / f"{split}-{self._key()}"

    def __len__(self) -> int:
        return self.size

    def _rescan_list(self, scans: set[str]) -> list[tuple[str, str, np.ndarray]]:
        if not self.cfg.rescan_gt or not resolve(self.cfg.rescan_gt).exists():
            return []
        return accepted_directions(load_rescan_gt(resolve(self.cfg.rescan_gt)), scans, both_ways=True)

    def _key(self) -> str:
        """Cache name: everything that changes the pairs (not the pool size: pair i is pair i):
        the settings, the scans, the rescan pairs with their transforms (not only the file's
        name) and the code that cuts pairs and builds their graphs."""
        cfg = dataclasses.asdict(self.cfg)
        for k in ("train_pairs", "val_pairs", "cache_dir"):
            cfg.pop(k)
        rescans = [(a, b, np.round(T, 9).tolist()) for a, b, T in self.rescans]
        code = source_digest("sgreg_core/net/dataset.py", "sgreg_core/simulation", "sgreg_core/maps",
                             "sgreg_core/geometry.py")
        blob = json.dumps([cfg, self.seed, self.scans, self.weights, rescans, code], sort_keys=True, default=str)
        return hashlib.sha256(blob.encode()).hexdigest()[:10]

    def pair(self, index: int) -> GraphPair:
        path = self.cache / f"{index:05d}.npz"
        if path.exists():
            return load_graph_pair(path)
        pair = self._make(index)
        save_graph_pair(pair, path)
        return pair

    def _make(self, index: int) -> GraphPair:
        cfg = self.cfg
        # held-out pairs draw as the validation pairs of the held-out room always did
        rng = np.random.default_rng([self.seed, index, 0 if self.split == "train" else 1])
        kinds = list(self.weights)
        p = np.array([self.weights[k] for k in kinds])
        for _ in range(20):  # re-cut until the views share enough nodes
            kind = kinds[int(rng.choice(len(kinds), p=p / p.sum()))]
            pair_cfg = PairConfig(
                overlap=float(rng.uniform(*cfg.overlap)),
                disjoint="halves" if rng.random() < cfg.halves_prob else "band",
                iou_store=cfg.iou_store,
                noise=NoiseConfig.preset(cfg.noise) if rng.random() < cfg.noise_prob else NoiseConfig())
            if kind == "rescan":
                a, b, T_ab = self.rescans[int(rng.integers(len(self.rescans)))]
                reg = _rescan_pair(self._scan(a), self._scan(b), T_ab, pair_cfg, rng)
                name = f"rescan:{a}->{b}"
            elif kind == "scan":
                scan = self.scans[int(rng.integers(len(self.scans)))]
                reg, name = make_pair(self._scan(scan), pair_cfg, rng), f"scan:{scan}"
            else:
                seed = int(rng.integers(cfg.synth_scenes)) if self.split == "train" else \
                    cfg.synth_scenes + int(rng.integers(cfg.val_synth_scenes))
                reg, name = make_pair(_synth_scene(seed), pair_cfg, rng), f"synth:{seed}"
            pair = graph_pair_from_registration(reg, cfg.graph, name, cfg.level)
            if len(pair.gt) >= cfg.min_matches and min(pair.src.num_nodes, pair.ref.num_nodes) >= 3:
                return pair
        raise RuntimeError(f"could not cut a {self.split} pair {index} with {cfg.min_matches} matches")

    def _scan(self, name: str) -> InstanceMap:
        return _read_scan(str(resolve(self.cfg.scans_dir) / name))


# ---- augmentation ----------------------------------------------------------------------
def _move(graph: SceneGraph, T: np.ndarray) -> SceneGraph:
    counts = np.fromiter(map(len, graph.points), dtype=np.int64, count=graph.num_nodes)
    flat = np.concatenate(graph.points) if graph.num_nodes else np.zeros((0, 3), np.float32)
    return dataclasses.replace(graph, centers=transform_points(T, graph.centers),
                               points=np.split(transform_points(T, flat), np.cumsum(counts)[:-1]))


def random_4dof(rng: np.random.Generator, max_translation: float = 10.0) -> np.ndarray:
    return yaw_transform(rng.uniform(-np.pi, np.pi),
                         np.r_[rng.uniform(-max_translation, max_translation, 2), rng.uniform(-1, 1)])


def augment(pair: GraphPair, rng: np.random.Generator) -> GraphPair:
    """Move each graph by its own random 4-DoF transform; T_src_ref follows."""
    A_src, A_ref = random_4dof(rng), random_4dof(rng)
    return dataclasses.replace(pair, src=_move(pair.src, A_src), ref=_move(pair.ref, A_ref),
                               T_src_ref=A_ref @ pair.T_src_ref @ invert_transform(A_src))


# ---- storage ---------------------------------------------------------------------------
def _graph_arrays(graph: SceneGraph, prefix: str) -> dict[str, np.ndarray]:
    counts = np.fromiter(map(len, graph.points), dtype=np.int64, count=graph.num_nodes)
    return {
        f"{prefix}node_ids": graph.node_ids, f"{prefix}labels": np.array(graph.labels, dtype=str),
        f"{prefix}scores": graph.scores, f"{prefix}centers": graph.centers,
        f"{prefix}extents": graph.extents, f"{prefix}edges": graph.edges,
        f"{prefix}structural": graph.structural, f"{prefix}counts": counts,
        f"{prefix}points": (np.concatenate(graph.points) if graph.num_nodes
                            else np.zeros((0, 3), np.float32)),
    }


def _graph_from(data, prefix: str) -> SceneGraph:
    counts = data[f"{prefix}counts"]
    return SceneGraph(
        node_ids=data[f"{prefix}node_ids"], labels=data[f"{prefix}labels"].tolist(),
        scores=data[f"{prefix}scores"], centers=data[f"{prefix}centers"],
        extents=data[f"{prefix}extents"], edges=data[f"{prefix}edges"].reshape(-1, 2),
        structural=data[f"{prefix}structural"],
        points=np.split(data[f"{prefix}points"].reshape(-1, 3), np.cumsum(counts)[:-1]),
    )


def save_graph_pair(pair: GraphPair, path: Path) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.stem + f".{os.getpid()}.tmp.npz")
    np.savez(tmp, T_src_ref=pair.T_src_ref, gt=pair.gt, gt_iou=pair.gt_iou,
             source=np.array(pair.source), **_graph_arrays(pair.src, "src_"),
             **_graph_arrays(pair.ref, "ref_"))
    os.replace(tmp, path)  # atomic: an interrupted run never leaves half a pair


def load_graph_pair(path: Path) -> GraphPair:
    with np.load(path, allow_pickle=False) as data:
        return GraphPair(src=_graph_from(data, "src_"), ref=_graph_from(data, "ref_"),
                         T_src_ref=data["T_src_ref"], gt=data["gt"].reshape(-1, 2),
                         gt_iou=data["gt_iou"], source=str(data["source"]))
