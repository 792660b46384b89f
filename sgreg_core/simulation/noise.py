"""The imperfections of a semantic-mapping front end, as a seeded noise model for training pairs,
benchmarks and synthetic scenes.

Public API:
    NoiseConfig                 seeded front-end imperfections (all off by default);
        NoiseConfig.preset("jitter,overseg,drop,paraphrase,partial") turns named ones on
    PARAPHRASES                 label -> other names for the same thing (>= 30 labels)
    apply_noise(imap, noise, rng) -> InstanceMap
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..maps.instance_map import labelled_mask, select_points
from ..types import InstanceMap

PARAPHRASES: dict[str, list[str]] = {
    "sofa": ["couch", "settee"],
    "couch": ["sofa"],
    "refrigerator": ["fridge", "refridgerator"],
    "refridgerator": ["refrigerator", "fridge"],
    "fridge": ["refrigerator"],
    "tv": ["television", "tv screen"],
    "television": ["tv", "tv screen"],
    "monitor": ["computer monitor", "screen", "display"],
    "table": ["desk table", "tabletop"],
    "coffee table": ["low table", "side table"],
    "desk": ["writing desk", "work desk", "table"],
    "chair": ["seat"],
    "office chair": ["desk chair", "swivel chair", "chair"],
    "armchair": ["easy chair", "lounge chair"],
    "stool": ["bar stool", "seat"],
    "bed": ["double bed", "mattress"],
    "night stand": ["nightstand", "bedside table"],
    "nightstand": ["night stand", "bedside table"],
    "cabinet": ["cupboard", "storage cabinet"],
    "kitchen cabinet": ["cupboard", "cabinet"],
    "shelves": ["shelf", "shelving"],
    "shelf": ["shelves", "rack"],
    "bookshelf": ["bookcase", "book shelf"],
    "bookcase": ["bookshelf", "book shelf"],
    "dresser": ["chest of drawers", "drawers"],
    "wardrobe": ["closet", "armoire"],
    "lamp": ["light", "table lamp"],
    "floor lamp": ["standing lamp", "lamp"],
    "plant": ["potted plant", "houseplant", "flower pot"],
    "toilet": ["wc", "toilet bowl"],
    "sink": ["basin", "washbasin"],
    "bathtub": ["tub", "bath"],
    "pillow": ["cushion"],
    "box": ["carton", "cardboard box"],
    "trash can": ["bin", "garbage can", "wastebasket"],
    "picture": ["painting", "photo", "frame"],
    "mirror": ["looking glass"],
    "whiteboard": ["white board", "board"],
    "curtain": ["drape", "drapes"],
    "door": ["doorway", "entrance door"],
    "window": ["windowpane", "glass window"],
    "counter": ["countertop", "kitchen counter", "worktop"],
    "microwave": ["microwave oven"],
    "oven": ["stove", "cooker"],
    "bag": ["backpack", "handbag"],
    "backpack": ["bag", "rucksack"],
    "radiator": ["heater"],
    "printer": ["copier", "printing machine"],
    "keyboard": ["computer keyboard"],
    "laptop": ["notebook computer", "computer"],
    "file cabinet": ["filing cabinet", "drawer cabinet"],
    "washing machine": ["washer", "laundry machine"],
    "ottoman": ["footstool", "pouf"],
    "rug": ["carpet", "mat"],
    "floor": ["ground", "flooring"],
    "wall": ["walls", "partition"],
    "ceiling": ["roof"],
    "otherfurniture": ["furniture"],
    "otherprop": ["object", "item"],
    "otherstructure": ["structure"],
    "books": ["book", "pile of books"],
    "clock": ["wall clock"],
    "fan": ["electric fan"],
    "bench": ["seat bench"],
}


@dataclass
class NoiseConfig:
    """Imperfections of a semantic-mapping front-end; every probability is per instance."""

    jitter: float = 0.0          # m, std of Gaussian noise added to every point
    overseg: float = 0.0         # probability that an instance is split in two
    drop: float = 0.0            # probability that an instance is not detected (unlabelled)
    paraphrase: float = 0.0      # probability that a label is replaced by a paraphrase
    partial: float = 0.0         # probability that an instance is only partly observed
    partial_keep: tuple[float, float] = (0.4, 0.8)  # kept fraction of a partial instance

    PRESETS = {"jitter": 0.01, "overseg": 0.1, "drop": 0.1, "paraphrase": 0.3, "partial": 0.2}

    @classmethod
    def preset(cls, names: str | list[str]) -> "NoiseConfig":
        """NoiseConfig with the named options at their preset strengths (see PRESETS)."""
        if isinstance(names, str):
            names = [n.strip() for n in names.split(",") if n.strip()]
        unknown = [n for n in names if n not in cls.PRESETS]
        if unknown:
            raise ValueError(f"unknown noise option(s) {unknown}; choose from {sorted(cls.PRESETS)}")
        return cls(**{n: cls.PRESETS[n] for n in names})



def _instance_fraction(imap: InstanceMap, inst_index: np.ndarray, n_inst: int, rng: np.random.Generator) -> np.ndarray:
    """Per point, its rank in [0, 1) along a random horizontal direction of its instance."""
    ang = rng.uniform(0, 2 * np.pi, n_inst)
    d = np.stack([np.cos(ang), np.sin(ang)], axis=1)[inst_index]
    proj = np.einsum("ij,ij->i", imap.points[:, :2].astype(np.float64), d)
    order = np.lexsort((proj, inst_index))
    counts = np.bincount(inst_index, minlength=n_inst)
    starts = np.r_[0, np.cumsum(counts)[:-1]]
    rank = np.empty(len(proj))
    rank[order] = np.arange(len(proj)) - starts[inst_index[order]]
    return rank / counts[inst_index]


def apply_noise(imap: InstanceMap, noise: NoiseConfig, rng: np.random.Generator) -> InstanceMap:
    """A noisy copy of `imap`: partial instances, over-segmentation, drops, paraphrases, jitter."""
    mask = labelled_mask(imap)
    ids = np.array(sorted(imap.labels), dtype=np.int64)
    inst = np.where(mask, imap.instance, 0).astype(np.int64)
    idx = np.searchsorted(ids, inst)
    idx[~mask] = len(ids)  # the unlabelled points form one extra group
    n = len(ids) + 1
    frac = _instance_fraction(imap, idx, n, rng)
    labels, scores = dict(imap.labels), dict(imap.scores)

    keep_pts = np.ones(len(inst), dtype=bool)
    if noise.partial > 0:
        chosen = np.r_[rng.random(len(ids)) < noise.partial, False]
        keep_frac = rng.uniform(*noise.partial_keep, n)
        keep_pts = ~chosen[idx] | (frac < keep_frac[idx])
    out_inst = inst.copy()
    if noise.overseg > 0:
        chosen = np.r_[rng.random(len(ids)) < noise.overseg, False]
        new_ids = int(ids.max(initial=0)) + 1 + np.arange(n)
        second = chosen[idx] & (frac >= 0.5)
        out_inst[second] = new_ids[idx[second]]
        for k in np.flatnonzero(chosen):
            labels[int(new_ids[k])] = labels[int(ids[k])]
            scores[int(new_ids[k])] = scores.get(int(ids[k]), 1.0)
    if noise.drop > 0:
        dropped = ids[rng.random(len(ids)) < noise.drop]
        if len(dropped) == len(ids):  # never drop everything: a map needs a labelled point
            dropped = dropped[1:]
        for k in dropped.tolist():
            labels.pop(k, None)
        out_inst[np.isin(inst, dropped)] = 0
    if noise.paraphrase > 0:
        for k in sorted(labels):
            alts = PARAPHRASES.get(labels[k].lower())
            if alts and rng.random() < noise.paraphrase:
                labels[k] = alts[rng.integers(len(alts))]
    points = imap.points
    if noise.jitter > 0:
        points = points + rng.normal(0.0, noise.jitter, points.shape).astype(np.float32)
    noisy = InstanceMap(points=points.astype(np.float32), instance=out_inst.astype(np.int32),
                        labels=labels, scores=scores, colors=imap.colors)
    return select_points(noisy, keep_pts)
