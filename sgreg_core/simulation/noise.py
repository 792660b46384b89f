"""The imperfections of a semantic-mapping front end, as a seeded noise model for training pairs,
benchmarks and synthetic scenes.

The errors real front ends (FM-Fusion, Hydra, ConceptGraphs) make, one NoiseConfig field each;
every kind is off at 0 and `NoiseConfig.preset` turns it on at the strength in brackets:

    confuse     [0.15]  probability per instance that its label becomes a wrong but plausible
                        class (CONFUSIONS: a chair called "sofa", a door "wall"), never a synonym
    paraphrase  [0.3]   probability per instance that its label becomes another name for the
                        same thing (PARAPHRASES: "sofa" -> "couch")
    merge       [0.1]   probability per object instance that it is fused with its nearest object
                        instance (centers within `merge_dist`, 1.0 m): the one with more points
                        gives the id and label (a chair swallowed by its table, books by the shelf)
    invent      [0.1]   invented instances per real instance (stochastic rounding): a ball of
                        `invent_radius` (0.3-0.8 m) of wall / floor / ceiling or unlabelled points
                        becomes an instance with a fresh id and a common object label
    overseg     [0.1]   probability per instance that it is split in two along a random direction
    partial     [0.2]   probability per instance that only a `partial_keep` share of it (0.4-0.8)
                        is observed, cut along a random horizontal direction
    drop        [0.1]   probability per instance that it is not detected (its points unlabelled)
    jitter      [0.01]  m, std of Gaussian noise on every point
    tilt        [2.0]   deg, largest tilt of a map's gravity direction (visual-inertial odometry
                        off by a little): a rotation by uniform [`tilt_min`, tilt] deg (0.5-2.0;
                        [0, tilt] when tilt < tilt_min) about a random horizontal axis through
                        the map's centroid. It moves points and changes the ground truth, so
                        apply_noise leaves it alone: pairs.make_pair tilts each view after the
                        other noise and composes T_src_ref with it.

Labels are confused, then paraphrased (a chair confused as "sofa" may be written "couch"); then
instances merge, split, gain invented neighbours, are cut partial and dropped; points jitter last.
Each kind draws from its own generator, seeded from the caller's rng in a fixed order, and per
instance of the input map where it acts on instances, so turning one kind on or off changes
nothing about which instances the others hit.

Public API:
    NoiseConfig                 seeded front-end imperfections (all off by default);
        NoiseConfig.preset("confuse,merge=0.2,tilt=1.5,jitter") turns named ones on, a bare
        name at its preset (NoiseConfig.PRESETS), name=value at that rate;
        NoiseConfig.FRONTEND names every kind at once
    PARAPHRASES                 label -> other names for the same thing (>= 30 labels)
    CONFUSIONS                  label -> wrong but plausible classes (>= 30 labels)
    INVENT_LABELS               labels given to invented instances
    confusions_of(label) -> list[str]
        the classes `label` can be confused with (case-insensitive; a paraphrase of a listed
        label is confused like it)
    apply_noise(imap, noise, rng) -> InstanceMap      every kind but tilt
    tilt_transform(noise, rng) -> (4, 4) float64      a random tilt about the origin (identity
                                                      when tilt is off)
    tilt_rotation(angle_deg, axis_deg) -> (4, 4)      a given tilt about the origin
    tilt_about(center, T) -> (4, 4) float64           T's rotation about `center` instead
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components
from scipy.spatial.transform import Rotation

from ..maps.instance_map import labelled_mask, select_points
from ..maps.scene_graph import is_structural
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

# What a front end calls an object when it gets the class wrong: a look-alike in shape, size or
# place, never another name for the same thing (that is PARAPHRASES) and never a broader class
# (a coffee table called "table" is not wrong). Floor and ceiling are never confused; walls only
# with doors and windows, which are flat and in them.
CONFUSIONS: dict[str, list[str]] = {
    "chair": ["sofa", "armchair", "stool", "bench"],
    "office chair": ["armchair", "stool", "sofa"],
    "armchair": ["sofa", "office chair", "ottoman"],
    "stool": ["chair", "ottoman", "trash can"],
    "sofa": ["chair", "armchair", "bed", "bench"],
    "bench": ["sofa", "table", "stool"],
    "ottoman": ["stool", "box", "armchair"],
    "bed": ["sofa", "ottoman"],
    "table": ["desk", "counter", "coffee table", "night stand"],
    "dining table": ["desk", "counter", "coffee table"],
    "desk": ["counter", "coffee table", "dresser", "night stand"],
    "coffee table": ["desk", "ottoman", "night stand", "bench"],
    "counter": ["table", "desk", "cabinet"],
    "night stand": ["dresser", "cabinet", "coffee table", "box"],
    "tv stand": ["cabinet", "dresser", "table"],
    "cabinet": ["shelves", "dresser", "wardrobe", "bookshelf", "door", "refrigerator"],
    "kitchen cabinet": ["shelves", "counter", "refrigerator", "microwave"],
    "wall cabinet": ["shelves", "whiteboard", "microwave"],
    "file cabinet": ["dresser", "printer", "night stand", "shelves"],
    "shelves": ["cabinet", "wardrobe", "dresser"],
    "bookshelf": ["cabinet", "wardrobe", "dresser", "door"],
    "dresser": ["cabinet", "night stand", "desk", "wardrobe"],
    "wardrobe": ["cabinet", "door", "refrigerator", "bookshelf"],
    "refrigerator": ["wardrobe", "cabinet", "door"],
    "door": ["wall", "cabinet", "wardrobe", "curtain"],
    "wall": ["door", "window"],
    "window": ["picture", "mirror", "curtain", "wall"],
    "curtain": ["window", "door", "blinds"],
    "blinds": ["curtain", "window", "picture"],
    "picture": ["window", "mirror", "whiteboard", "tv"],
    "mirror": ["picture", "window", "door"],
    "whiteboard": ["picture", "tv", "window"],
    "tv": ["monitor", "picture", "window", "mirror"],
    "wall tv": ["picture", "whiteboard", "window", "monitor"],
    "monitor": ["tv", "picture", "laptop"],
    "laptop": ["keyboard", "monitor", "books"],
    "keyboard": ["laptop", "books"],
    "printer": ["microwave", "box", "monitor"],
    "microwave": ["oven", "printer", "box"],
    "oven": ["microwave", "cabinet", "washing machine"],
    "washing machine": ["oven", "refrigerator", "cabinet"],
    "lamp": ["plant", "fan"],
    "floor lamp": ["plant", "coat rack", "fan"],
    "plant": ["lamp", "floor lamp", "trash can"],
    "fan": ["lamp", "plant"],
    "coat rack": ["floor lamp", "plant"],
    "sink": ["toilet", "bathtub", "counter"],
    "toilet": ["sink", "bathtub", "trash can"],
    "bathtub": ["sink", "toilet", "counter"],
    "pillow": ["bag", "box", "towel"],
    "towel": ["curtain", "pillow", "bag"],
    "bag": ["pillow", "box", "trash can"],
    "box": ["trash can", "bag", "pillow", "books"],
    "storage bin": ["box", "trash can", "bag"],
    "trash can": ["box", "bag", "stool"],
    "books": ["box", "bag", "picture"],
    "radiator": ["cabinet", "bench", "shelves"],
    "rug": ["towel", "blanket"],
    "clock": ["picture", "mirror", "fan"],
}


def _confusion_lookup() -> dict[str, list[str]]:
    """CONFUSIONS, plus each paraphrase of a listed label (synth and real front ends write
    "desk chair" or "television") confused like that label, less its own synonyms."""
    table = dict(CONFUSIONS)
    for label, alts in CONFUSIONS.items():
        for name in PARAPHRASES.get(label, []):
            if name not in table:  # a listed label, or the first one that paraphrases it, wins
                table[name] = [a for a in alts if a != name and a not in PARAPHRASES.get(name, [])
                               and name not in PARAPHRASES.get(a, [])]
    return table


_CONFUSE = _confusion_lookup()


def confusions_of(label: str) -> list[str]:
    """The classes `label` may be mistaken for (case-insensitive); [] when it is never confused."""
    return _CONFUSE.get(label.strip().lower(), [])


INVENT_LABELS = ("chair", "table", "cabinet", "box", "picture", "shelves", "lamp", "door",
                 "trash can", "window", "curtain", "plant", "bag", "pillow", "monitor", "desk")

# the order in which the per-kind generators are seeded from the caller's rng; append new kinds
_STREAMS = ("confuse", "paraphrase", "merge", "overseg", "invent", "partial", "drop", "jitter")
_PROBABILITIES = ("confuse", "paraphrase", "merge", "overseg", "partial", "drop")


@dataclass
class NoiseConfig:
    """Imperfections of a semantic-mapping front end (the module docstring tells what each does).

    confuse:        probability per instance of a wrong but plausible label (CONFUSIONS).
    paraphrase:     probability per instance of another name for its class (PARAPHRASES).
    merge:          probability per object instance of being fused with its nearest object
                    instance, if their centers are within merge_dist (m).
    invent:         invented instances per real instance, each a ball of radius uniform in
                    invent_radius (m) cut from one structural or unlabelled region.
    overseg:        probability per instance of being split in two.
    partial:        probability per instance of being partly observed, keeping a share uniform
                    in partial_keep.
    drop:           probability per instance of not being detected.
    jitter:         m, std of Gaussian noise added to every point.
    tilt:           deg, largest gravity tilt of a map, uniform in [tilt_min, tilt] ([0, tilt]
                    when tilt < tilt_min); applied by pairs.make_pair, not apply_noise.
    PRESETS:        the rate of each kind when named bare in preset().
    FRONTEND:       every kind at once, for preset().
    """

    confuse: float = 0.0
    paraphrase: float = 0.0
    merge: float = 0.0
    merge_dist: float = 1.0
    invent: float = 0.0
    invent_radius: tuple[float, float] = (0.3, 0.8)
    overseg: float = 0.0
    partial: float = 0.0
    partial_keep: tuple[float, float] = (0.4, 0.8)
    drop: float = 0.0
    jitter: float = 0.0
    tilt: float = 0.0
    tilt_min: float = 0.5

    PRESETS = {"confuse": 0.15, "paraphrase": 0.3, "merge": 0.1, "invent": 0.1, "overseg": 0.1,
               "partial": 0.2, "drop": 0.1, "jitter": 0.01, "tilt": 2.0}
    FRONTEND = "confuse,merge,invent,tilt,jitter,overseg,drop,paraphrase,partial"

    def __post_init__(self):
        for name in self.PRESETS:
            rate = getattr(self, name)
            top = 1.0 if name in _PROBABILITIES else 90.0 if name == "tilt" else np.inf   # tilt: deg
            if not 0.0 <= rate <= top:
                raise ValueError(f"noise option {name}: rate {rate} out of range")

    @classmethod
    def preset(cls, names: str | list[str]) -> "NoiseConfig":
        """NoiseConfig from "name,name=rate,...": a bare name at its PRESETS rate."""
        if isinstance(names, str):
            names = [n.strip() for n in names.split(",") if n.strip()]
        rates = {}
        for item in names:
            name, has_rate, value = (s.strip() for s in item.partition("="))
            if name not in cls.PRESETS:
                raise ValueError(f"unknown noise option {name!r}; choose from {sorted(cls.PRESETS)}")
            try:
                rates[name] = float(value) if has_rate else cls.PRESETS[name]
            except ValueError:
                raise ValueError(f"noise option {name}: rate {value!r} is not a number") from None
        return cls(**rates)


def tilt_rotation(angle_deg: float, axis_deg: float) -> np.ndarray:
    """(4, 4): a rotation by angle_deg about the horizontal axis at axis_deg from x, through
    the origin."""
    return _tilt(np.radians(angle_deg), np.radians(axis_deg))


def _tilt(angle: float, axis: float) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = Rotation.from_rotvec(angle * np.array([np.cos(axis), np.sin(axis), 0.0])).as_matrix()
    return T


def tilt_transform(noise: NoiseConfig, rng: np.random.Generator) -> np.ndarray:
    """A random tilt of the gravity direction, about the origin (identity when tilt is off)."""
    if noise.tilt <= 0:
        return np.eye(4)
    low = noise.tilt_min if noise.tilt >= noise.tilt_min else 0.0
    angle, axis = np.radians(rng.uniform(low, noise.tilt)), rng.uniform(0, 2 * np.pi)
    return _tilt(angle, axis)


def tilt_about(center: np.ndarray, T: np.ndarray) -> np.ndarray:
    """The rotation of T about `center` instead of the origin."""
    out, c = np.array(T, dtype=np.float64), np.asarray(center, dtype=np.float64)
    out[:3, 3] = c - out[:3, :3] @ c
    return out


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


def _relabel(labels: dict[int, str], ids: np.ndarray, rate: float, table: dict[str, list[str]],
             rng: np.random.Generator) -> None:
    """With probability `rate` per instance, its label becomes one of table[label] (if listed)."""
    hit, pick = rng.random((2, len(ids)))  # drawn for every instance: the draws do not depend on labels
    for k, h, u in zip(ids.tolist(), hit < rate, pick):
        alts = table.get(labels[k].strip().lower())
        if h and alts:
            labels[k] = alts[int(u * len(alts))]


def _merge_owner(points: np.ndarray, idx: np.ndarray, ids: np.ndarray, structural: np.ndarray,
                 noise: NoiseConfig, rng: np.random.Generator) -> np.ndarray:
    """Per instance of `ids`, the id it carries after merges (its own when not merged)."""
    n = len(ids)
    chosen = rng.random(n) < noise.merge
    counts = np.bincount(idx, minlength=n + 1)[:n]
    sums = np.stack([np.bincount(idx, points[:, d], n + 1)[:n] for d in range(3)], axis=1)
    centers = sums / np.maximum(counts, 1)[:, None]
    dist = np.linalg.norm(centers[:, None] - centers[None], axis=2)
    blocked = structural | (counts == 0)
    dist[blocked], dist[:, blocked] = np.inf, np.inf
    np.fill_diagonal(dist, np.inf)
    nearest = dist.argmin(axis=1)
    chosen &= dist[np.arange(n), nearest] <= noise.merge_dist
    # chains (a chair into the table another chair went into) become one instance
    links = sp.coo_matrix((np.ones(chosen.sum()), (np.flatnonzero(chosen), nearest[chosen])), shape=(n, n))
    _, group = connected_components(links, directed=False)
    order = np.lexsort((-counts, group))  # per group, the instance with the most points first
    _, first = np.unique(group[order], return_index=True)
    return ids[order[first]][group]


def _invent(points: np.ndarray, idx: np.ndarray, loose: np.ndarray, n_real: int, first_id: int,
            noise: NoiseConfig, rng: np.random.Generator) -> tuple[np.ndarray, dict[int, str]]:
    """Per point the invented instance it now belongs to (0: none), and the invented labels.
    `loose[i]`: instance index i (the last one: unlabelled points) is structural or unlabelled."""
    want = noise.invent * n_real
    count = int(want) + int(rng.random() < want - int(want))
    free = loose[idx]
    out, labels = np.zeros(len(idx), dtype=np.int64), {}
    for new_id in range(first_id, first_id + count):
        if not free.any():
            break
        seed = rng.choice(np.flatnonzero(free))
        radius = rng.uniform(*noise.invent_radius)
        near = np.flatnonzero(free & (idx == idx[seed]))  # one region: never a wall and the floor
        near = near[np.linalg.norm(points[near] - points[seed], axis=1) <= radius]
        out[near], free[near] = new_id, False
        labels[new_id] = INVENT_LABELS[rng.integers(len(INVENT_LABELS))]
    return out, labels


def apply_noise(imap: InstanceMap, noise: NoiseConfig, rng: np.random.Generator) -> InstanceMap:
    """A noisy copy of `imap` with every kind of `noise` but tilt (see the module docstring)."""
    streams = dict(zip(_STREAMS, map(np.random.default_rng, rng.integers(2**63, size=len(_STREAMS)))))
    ids = np.array(sorted(imap.labels), dtype=np.int64)
    n = len(ids)
    mask = labelled_mask(imap)
    idx = np.where(mask, np.searchsorted(ids, imap.instance), n)  # instance index; unlabelled: n
    labels, scores = dict(imap.labels), {k: imap.scores.get(k, 1.0) for k in imap.labels}
    structural = np.array([is_structural(labels[k]) for k in ids.tolist()], dtype=bool)  # true labels

    if noise.confuse > 0:
        _relabel(labels, ids, noise.confuse, _CONFUSE, streams["confuse"])
    if noise.paraphrase > 0:
        _relabel(labels, ids, noise.paraphrase, PARAPHRASES, streams["paraphrase"])

    owner = ids
    if noise.merge > 0 and n > 1:
        owner = _merge_owner(imap.points.astype(np.float64), idx, ids, structural, noise, streams["merge"])
    inst = np.r_[owner, 0][idx]
    top = int(ids.max(initial=0))
    twins = top + 1 + np.arange(n)  # the second halves of split instances; then invented ones
    if noise.overseg > 0:
        chosen = streams["overseg"].random(n) < noise.overseg
        frac = _instance_fraction(imap, idx, n + 1, streams["overseg"])
        second = np.r_[chosen, False][idx] & (frac >= 0.5)
        inst[second] = twins[idx[second]]
        for k in np.flatnonzero(chosen).tolist():
            labels[int(twins[k])], scores[int(twins[k])] = labels[int(owner[k])], scores[int(owner[k])]
    if noise.invent > 0:
        invented, new_labels = _invent(imap.points, idx, np.r_[structural, True], n, top + 1 + n,
                                       noise, streams["invent"])
        inst = np.where(invented > 0, invented, inst)
        labels.update(new_labels)
        scores.update(dict.fromkeys(new_labels, 1.0))
    keep_pts = np.ones(len(inst), dtype=bool)
    if noise.partial > 0:
        chosen = np.r_[streams["partial"].random(n) < noise.partial, False]
        keep_frac = streams["partial"].uniform(*noise.partial_keep, n + 1)
        keep_pts = ~chosen[idx] | (_instance_fraction(imap, idx, n + 1, streams["partial"]) < keep_frac[idx])
    if noise.drop > 0:
        hit = streams["drop"].random(n) < noise.drop
        gone = np.isin(inst, np.r_[ids[hit], twins[hit]])
        if gone.any() and not (inst[~gone] > 0).any():  # never drop everything: a map needs a labelled point
            kept, counts = np.unique(inst[gone], return_counts=True)
            gone &= inst != kept[counts.argmax()]
        inst[gone] = 0
    points = imap.points
    if noise.jitter > 0:
        points = points + streams["jitter"].normal(0.0, noise.jitter, points.shape).astype(np.float32)
    noisy = InstanceMap(points=points.astype(np.float32), instance=inst.astype(np.int32),
                        labels=labels, scores=scores, colors=imap.colors)
    return select_points(noisy, keep_pts)
