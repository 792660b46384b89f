"""Registration cases of the benchmark, cut from real scans, every one seeded.

Settings:
    clean / noisy      two partial views of one capture of a tested room that share no point
                       sample (pairs.make_pair), yaw uniform in [-180, 180); noisy adds the
                       geometric front-end imperfections (jitter, split, dropped and partial
                       instances, paraphrased labels) to each view.
    tilt               clean views, each tilted on its own by 0.5-2 deg (gravity from VIO).
    frontend           what a real mapping front end makes, all at once (NoiseConfig.FRONTEND):
                       the noisy errors plus wrong but plausible classes, merged and invented
                       instances and per-map tilt.
    rescan             one capture of a room against another capture of it (pseudo ground truth
                       from rescan_gt.json, accepted entries only), the source moved by a random
                       4-DoF transform per seed: held-out rooms in both directions with
                       `rescan_seeds` seeds each, rooms seen in training in the listed direction
                       with `rescan_seen_seeds` (they are many, and only a side note).
Every case says whether its room was held out of training (CaseConfig.held_out_rooms).
    different_rooms    a partial view of a tested room against a partial view of another room,
                       random 4-DoF: there is no right answer, any claimed success is false.

Public API:
    CaseConfig
    Case                  setting, name, src, ref, T_gt (None: no solution), gt node pairs,
                          held_out
    SETTINGS              the setting names, in report order
    build_cases(cfg) -> list[Case]
"""
from __future__ import annotations

from dataclasses import dataclass, field
from functools import lru_cache

import numpy as np

from ..geometry import invert_transform, transform_points, yaw_transform
from ..maps.instance_map import InstanceMapError, labelled_mask, read_instance_map
from ..paths import RESCAN_GT, SCANS, require, resolve
from ..rescan_gt import accepted_directions, load_rescan_gt, room_of
from ..simulation.noise import NoiseConfig
from ..simulation.pairs import PairConfig, make_pair, node_iou
from ..types import InstanceMap

SETTINGS = ("clean", "noisy", "tilt", "frontend", "rescan", "different_rooms")
# the noise of each view setting (NoiseConfig.preset names)
VIEW_NOISE = {"clean": "", "noisy": "jitter,overseg,drop,paraphrase,partial", "tilt": "tilt",
              "frontend": NoiseConfig.FRONTEND}
# seed index of each setting: settings added later draw their own cases, the others keep theirs
_SEED = {"clean": 0, "noisy": 1, "rescan": 2, "different_rooms": 3, "tilt": 4, "frontend": 5}


@dataclass
class CaseConfig:
    """scans_dir:        instance map directories of real scans (relative paths start at the
                         repository, sgreg_core/paths.py).
    scan_prefix:         scans used (picwoon: 50k-point subsamples; mmdet3d duplicates rooms).
    rooms:               tested rooms (scene ids); default the room held out of training.
    held_out_rooms:      rooms the network never saw in training (the others are flagged
                         "seen in training" in the report).
    other_rooms:         rooms for the different-room check; empty = every other room found
                         (a held-out room only for a held-out tested room).
    rescan_gt:           pseudo ground truth between captures ("" skips the rescan setting).
    n:                   pairs per setting for clean, noisy and different_rooms.
    rescan_seeds:        random 4-DoF transforms per rescan direction of a held-out room.
    rescan_seen_seeds:   random 4-DoF transforms per rescan pair of a room seen in training.
    overlap:             share of the points both views cover, uniform in this range (the
                         training range of the shipped model).
    halves_prob:         probability that the views split every point (half density each)
                         instead of the shared band only (see pairs.PairConfig.disjoint).
    max_translation:     m, horizontal translation of the random transforms.
    iou_voxel:           m, voxel of the ground-truth node IoU.
    seed:                seed of every random choice."""

    scans_dir: str = SCANS
    scan_prefix: str = "scannet-picwoon_"
    rooms: tuple[str, ...] = ("scene0005",)
    held_out_rooms: tuple[str, ...] = ("scene0005",)
    other_rooms: tuple[str, ...] = ()
    rescan_gt: str = RESCAN_GT
    n: int = 10
    rescan_seeds: int = 3
    rescan_seen_seeds: int = 1
    overlap: tuple[float, float] = (0.3, 0.8)
    halves_prob: float = 0.3
    max_translation: float = 10.0
    iou_voxel: float = 0.1
    seed: int = 0

    def __post_init__(self):
        if not (self.n >= 1 and self.rescan_seeds >= 0 and self.rescan_seen_seeds >= 0
                and self.seed >= 0):
            raise ValueError(f"cases: n must be >= 1, rescan_seeds, rescan_seen_seeds and seed "
                             f">= 0 (n={self.n}, seed={self.seed})")
        lo, hi = self.overlap
        if not (0.0 < lo <= hi <= 1.0 and 0.0 <= self.halves_prob <= 1.0
                and 0.0 <= self.max_translation < np.inf and 0.0 < self.iou_voxel < np.inf):
            raise ValueError("cases: overlap must be 0 < low <= high <= 1, halves_prob in [0, 1], "
                             "max_translation finite and >= 0, iou_voxel finite and > 0")


@dataclass
class Case:
    setting: str
    name: str
    src: InstanceMap
    ref: InstanceMap
    T_gt: np.ndarray | None                      # src -> ref; None when there is no solution
    gt_node_pairs: np.ndarray = field(default_factory=lambda: np.zeros((0, 2), np.int64))
    gt_iou: np.ndarray = field(default_factory=lambda: np.zeros(0, np.float32))
    held_out: bool = True                        # False: the room was seen in training


@lru_cache(maxsize=16)
def _scan(path: str) -> InstanceMap:
    return read_instance_map(path)


def _scans(cfg: CaseConfig) -> list[str]:
    try:
        root = require(cfg.scans_dir, "scans folder")
    except FileNotFoundError as exc:
        raise InstanceMapError(str(exc)) from None
    scans = sorted(p.name for p in root.glob(cfg.scan_prefix + "*") if p.is_dir())
    if not scans:
        raise InstanceMapError(f"{root}: no scan directory named {cfg.scan_prefix}*")
    return scans


def _random_4dof(rng: np.random.Generator, max_translation: float) -> np.ndarray:
    r, phi = max_translation * np.sqrt(rng.random()), rng.uniform(0, 2 * np.pi)
    return yaw_transform(rng.uniform(-np.pi, np.pi),
                         [r * np.cos(phi), r * np.sin(phi), rng.uniform(-0.5, 0.5)])


def _pair_config(cfg: CaseConfig, rng: np.random.Generator, noise: str = "") -> PairConfig:
    return PairConfig(overlap=float(rng.uniform(*cfg.overlap)),
                      disjoint="halves" if rng.random() < cfg.halves_prob else "band",
                      max_translation=cfg.max_translation, iou_voxel=cfg.iou_voxel,
                      noise=NoiseConfig.preset(noise))


def _view_cases(cfg: CaseConfig, scans: list[str], setting: str) -> list[Case]:
    out = []
    for k in range(cfg.n):
        rng = np.random.default_rng([cfg.seed, _SEED[setting], k])
        scan = scans[k % len(scans)]
        pair = make_pair(_scan(str(resolve(cfg.scans_dir) / scan)),
                         _pair_config(cfg, rng, VIEW_NOISE[setting]), rng)
        out.append(Case(setting, f"{scan}#{k}", pair.src, pair.ref, pair.T_src_ref,
                        pair.gt_node_pairs, pair.gt_iou, room_of(scan) in cfg.held_out_rooms))
    return out


def _gt_nodes(src: InstanceMap, ref: InstanceMap, T: np.ndarray,
              voxel: float) -> tuple[np.ndarray, np.ndarray]:
    """Ground-truth node pairs (src id, ref id) and their IoU in the common frame."""
    ms, mr = labelled_mask(src), labelled_mask(ref)
    return node_iou(transform_points(T, src.points[ms]), src.instance[ms],
                    ref.points[mr], ref.instance[mr], voxel)


def _rescan_cases(cfg: CaseConfig, scans: set[str]) -> list[Case]:
    if not cfg.rescan_gt:
        return []
    directions = []
    for src, ref, T in accepted_directions(load_rescan_gt(resolve(cfg.rescan_gt)), scans):
        directions.append((src, ref, T))
        if room_of(src) in cfg.held_out_rooms:
            directions.append((ref, src, invert_transform(T)))
    # held-out rooms first: they are the headline
    directions.sort(key=lambda d: (room_of(d[0]) not in cfg.held_out_rooms, d[0], d[1]))
    out = []
    for d, (a, b, T_ab) in enumerate(directions):
        src0 = _scan(str(resolve(cfg.scans_dir) / a))
        ref = _scan(str(resolve(cfg.scans_dir) / b))
        pairs, iou = _gt_nodes(src0, ref, T_ab, cfg.iou_voxel)
        held_out = room_of(a) in cfg.held_out_rooms
        for s in range(cfg.rescan_seeds if held_out else cfg.rescan_seen_seeds):
            rng = np.random.default_rng([cfg.seed, _SEED["rescan"], d, s])
            A = _random_4dof(rng, cfg.max_translation)
            out.append(Case("rescan", f"{a}->{b}#{s}", src0.transformed(A), ref,
                            T_ab @ invert_transform(A), pairs, iou, held_out))
    return out


def _other_rooms_of(cfg: CaseConfig, a: str, scans: list[str]) -> list[str]:
    """Scans of rooms other than a's for a different-room pair: other_rooms when given, else
    any, but a held-out room only beside another held-out room (the different-room poses of
    training rooms feed threshold fits, which the held-out room must never enter)."""
    held, room = set(cfg.held_out_rooms), room_of(a)
    rooms = {s: room_of(s) for s in scans}
    return [s for s in scans if rooms[s] != room
            and (rooms[s] in cfg.other_rooms if cfg.other_rooms
                 else rooms[s] not in held or room in held)]


def _different_room_cases(cfg: CaseConfig, tested: list[str], scans: list[str]) -> list[Case]:
    out = []
    root = resolve(cfg.scans_dir)
    for k in range(cfg.n):
        a = tested[k % len(tested)]
        others = _other_rooms_of(cfg, a, scans)
        if not others:
            continue
        rng = np.random.default_rng([cfg.seed, _SEED["different_rooms"], k])
        b = others[k % len(others)]
        view = make_pair(_scan(str(root / a)), _pair_config(cfg, rng), rng).src
        ref = make_pair(_scan(str(root / b)), _pair_config(cfg, rng), rng).ref
        out.append(Case("different_rooms", f"{a}|{b}#{k}", view, ref, None,
                        held_out=room_of(a) in cfg.held_out_rooms))
    return out


def build_cases(cfg: CaseConfig, settings: tuple[str, ...] = SETTINGS) -> list[Case]:
    """Every case of the requested settings, in SETTINGS order (rescans: held-out first)."""
    scans = _scans(cfg)
    tested = [s for s in scans if room_of(s) in cfg.rooms]
    if not tested:
        raise InstanceMapError(f"{cfg.scans_dir}: no {cfg.scan_prefix}* scan of rooms "
                               f"{list(cfg.rooms)}")
    cases: list[Case] = []
    for setting in SETTINGS:
        if setting not in settings:
            continue
        if setting in VIEW_NOISE:
            cases += _view_cases(cfg, tested, setting)
        elif setting == "rescan":
            cases += _rescan_cases(cfg, set(scans))
        else:
            cases += _different_room_cases(cfg, tested, scans)
    return cases
