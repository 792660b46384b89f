"""Registration pairs with ground truth, cut from one instance map (paper VII-A4, SGAligner-style).

Public API:
    PairConfig                  overlap, how views avoid sharing samples, transform ranges, IoU
    RegistrationPair            src, ref (InstanceMap), T_src_ref (4x4: src points -> ref frame),
                                gt_node_pairs (m, 2) int64 (src id, ref id), gt_iou (m,) float32,
                                meta dict (with "src_tilt_deg" / "ref_tilt_deg" and the 4x4
                                "src_tilt" / "ref_tilt" applied to each view in the common
                                frame); .matches(min_iou=0.3) -> the pairs at/above min_iou
    make_pair(imap, cfg, rng) -> RegistrationPair
    node_iou(src_points, src_inst, ref_points, ref_inst, voxel) -> (pairs (m, 2), iou (m,))
        IoU of voxel occupancy of every overlapping (src instance, ref instance), common frame
    write_pair(pair, out_dir) / read_pair(dir)
        out_dir/src/, out_dir/ref/ (instance map directories) and out_dir/gt.json

How the two views are cut: points are projected on a random horizontal direction; the source
view keeps the points below the (0.5 + overlap / 2) quantile, the reference view those above
the (0.5 - overlap / 2) quantile, so the shared band holds `overlap` of the points. No point
sample may be in both views: with disjoint="band" each band point goes to one view at random
(views keep full density outside the band), with disjoint="halves" every point is first given
to one random half (uniform half density everywhere). Noise is then applied to each view on
its own, ids are renumbered at random (disjoint sets) and the ground-truth node pairs are found
in the common frame. With tilt noise each view is then tilted on its own about its centroid
(src1 = S src0, ref1 = R ref0: each front end has its own gravity error), and the source view
is moved by a random 4-DoF transform A (src2 = A^-1 src1); T_src_ref = R S^-1 A maps the final
source onto the final reference.
"""
from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import scipy.sparse as sp

from ..geometry import invert_transform, pack_keys, transform_points, voxel_coords, yaw_transform
from ..maps.level import tilt_deg
from ..maps.instance_map import InstanceMapError, labelled_mask, read_instance_map, select_points, write_instance_map
from ..types import InstanceMap
from .noise import NoiseConfig, apply_noise, tilt_about, tilt_transform


@dataclass
class PairConfig:
    overlap: float = 0.5            # fraction of the points in the band both views cover
    disjoint: str = "band"          # "band" or "halves": how views avoid sharing samples
    max_yaw_deg: float = 180.0      # yaw of T uniform in [-max, max)
    max_translation: float = 10.0   # m, horizontal translation of T uniform in the disk
    max_z_translation: float = 0.5  # m, vertical translation of T uniform in [-max, max]
    iou_voxel: float = 0.1          # m, voxel of the occupancy IoU; coarser than the point
                                    # spacing so that disjoint samples of a surface still meet
    iou_store: float = 0.1          # keep gt node pairs with IoU >= this
    min_iou: float = 0.3            # default threshold of RegistrationPair.matches
    noise: NoiseConfig = field(default_factory=NoiseConfig)


@dataclass
class RegistrationPair:
    src: InstanceMap
    ref: InstanceMap
    T_src_ref: np.ndarray
    gt_node_pairs: np.ndarray
    gt_iou: np.ndarray
    meta: dict = field(default_factory=dict)

    def matches(self, min_iou: float = 0.3) -> np.ndarray:
        """(k, 2) (src id, ref id) ground-truth node matches with IoU >= min_iou."""
        return self.gt_node_pairs[self.gt_iou >= min_iou]


def node_iou(src_points, src_inst, ref_points, ref_inst, voxel: float) -> tuple[np.ndarray, np.ndarray]:
    """IoU of the voxel occupancy of every (src instance, ref instance) sharing a voxel."""
    vs, vr = voxel_coords(src_points, voxel), voxel_coords(ref_points, voxel)
    both = np.concatenate([vs, vr])
    cell = pack_keys([both[:, 0], both[:, 1], both[:, 2]])
    _, cell = np.unique(cell, return_inverse=True)
    cs, cr = cell[: len(vs)], cell[len(vs):]
    sid, si = np.unique(src_inst, return_inverse=True)
    rid, ri = np.unique(ref_inst, return_inverse=True)
    n_cells = int(cell.max()) + 1 if len(cell) else 0
    A = sp.csr_matrix((np.ones(len(cs)), (si, cs)), shape=(len(sid), n_cells))
    B = sp.csr_matrix((np.ones(len(cr)), (ri, cr)), shape=(len(rid), n_cells))
    A.data[:] = 1.0  # duplicates were summed: occupancy is binary
    B.data[:] = 1.0
    inter = (A @ B.T).tocoo()
    size_a, size_b = np.asarray(A.sum(1)).ravel(), np.asarray(B.sum(1)).ravel()
    iou = inter.data / (size_a[inter.row] + size_b[inter.col] - inter.data)
    pairs = np.stack([sid[inter.row], rid[inter.col]], axis=1).astype(np.int64)
    order = np.lexsort((pairs[:, 1], pairs[:, 0]))
    return pairs[order], iou[order].astype(np.float32)


def _cut_views(imap: InstanceMap, cfg: PairConfig, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    if not 0.0 < cfg.overlap <= 1.0:
        raise ValueError(f"overlap must be in (0, 1], got {cfg.overlap}")
    ang = rng.uniform(0, 2 * np.pi)
    proj = imap.points[:, :2].astype(np.float64) @ np.array([np.cos(ang), np.sin(ang)])
    hi, lo = np.quantile(proj, [0.5 + cfg.overlap / 2, 0.5 - cfg.overlap / 2])
    in_a, in_b = proj <= hi, proj >= lo
    coin = rng.random(len(proj)) < 0.5
    if cfg.disjoint == "band":
        band = in_a & in_b
        return in_a & ~(band & ~coin), in_b & ~(band & coin)
    if cfg.disjoint == "halves":
        return in_a & coin, in_b & ~coin
    raise ValueError(f"disjoint must be 'band' or 'halves', got {cfg.disjoint!r}")


def _renumber(imap: InstanceMap, new_ids: np.ndarray) -> InstanceMap:
    old = np.array(sorted(imap.labels), dtype=np.int64)
    mask = labelled_mask(imap)
    inst = np.zeros(len(imap.instance), dtype=np.int32)
    inst[mask] = new_ids[np.searchsorted(old, imap.instance[mask])]
    mapping = dict(zip(old.tolist(), new_ids.tolist()))
    return InstanceMap(
        points=imap.points, instance=inst,
        labels={mapping[k]: v for k, v in imap.labels.items()},
        scores={mapping[k]: imap.scores.get(k, 1.0) for k in imap.labels},
        colors=imap.colors,
    )


def make_pair(imap: InstanceMap, cfg: PairConfig | None = None, rng: np.random.Generator | None = None) -> RegistrationPair:
    """Cut two overlapping views of `imap` with ground truth (see the module docstring)."""
    cfg = cfg or PairConfig()
    rng = rng if rng is not None else np.random.default_rng(0)
    in_a, in_b = _cut_views(imap, cfg, rng)
    tilt_rng = np.random.default_rng(rng.integers(2**63))  # its own stream, drawn with or without tilt
    views = []
    for m, name in ((in_a, "source"), (in_b, "reference")):
        view = apply_noise(select_points(imap, m), cfg.noise, rng)
        if not labelled_mask(view).any():
            raise InstanceMapError(f"{name} view has no labelled point (overlap {cfg.overlap})")
        views.append(view)
    ns, nr = len(views[0].labels), len(views[1].labels)
    ids = rng.choice(np.arange(1, 10 * (ns + nr) + 100), size=ns + nr, replace=False)
    src, ref = _renumber(views[0], ids[:ns]), _renumber(views[1], ids[ns:])

    ms, mr = labelled_mask(src), labelled_mask(ref)
    pairs, iou = node_iou(src.points[ms], src.instance[ms], ref.points[mr], ref.instance[mr], cfg.iou_voxel)
    keep = iou >= cfg.iou_store

    S, R = (tilt_about(v.points.mean(axis=0, dtype=np.float64), tilt_transform(cfg.noise, tilt_rng)) for v in (src, ref))
    yaw = np.radians(rng.uniform(-cfg.max_yaw_deg, cfg.max_yaw_deg))
    r, phi = cfg.max_translation * np.sqrt(rng.random()), rng.uniform(0, 2 * np.pi)
    t = [r * np.cos(phi), r * np.sin(phi), rng.uniform(-cfg.max_z_translation, cfg.max_z_translation)]
    A = yaw_transform(yaw, t)
    src.points = transform_points(invert_transform(A) @ S, src.points).astype(np.float32)
    ref.points = transform_points(R, ref.points).astype(np.float32)
    T_src_ref = R @ invert_transform(S) @ A
    meta = {"overlap": cfg.overlap, "disjoint": cfg.disjoint, "noise": asdict(cfg.noise),
            "src_points": int(len(src.points)), "ref_points": int(len(ref.points)),
            "src_tilt_deg": tilt_deg(S[:3, :3]), "ref_tilt_deg": tilt_deg(R[:3, :3]),
            "src_tilt": S.tolist(), "ref_tilt": R.tolist()}
    return RegistrationPair(src=src, ref=ref, T_src_ref=T_src_ref, gt_node_pairs=pairs[keep],
                            gt_iou=iou[keep], meta=meta)


def write_pair(pair: RegistrationPair, out_dir: str | Path) -> None:
    out_dir = Path(out_dir)
    write_instance_map(pair.src, out_dir / "src")
    write_instance_map(pair.ref, out_dir / "ref")
    gt = {
        "T_src_ref": np.asarray(pair.T_src_ref).tolist(),
        "gt_node_pairs": [[int(s), int(r), round(float(i), 6)] for (s, r), i in zip(pair.gt_node_pairs, pair.gt_iou)],
        "meta": pair.meta,
    }
    (out_dir / "gt.json").write_text(json.dumps(gt, indent=1))


def read_pair(pair_dir: str | Path) -> RegistrationPair:
    pair_dir = Path(pair_dir)
    gt_path = pair_dir / "gt.json"
    if not gt_path.is_file():
        raise InstanceMapError(f"{gt_path}: missing file")
    try:
        gt = json.loads(gt_path.read_text())
        T = np.array(gt["T_src_ref"], dtype=np.float64)
        rows = np.array(gt["gt_node_pairs"], dtype=np.float64).reshape(-1, 3)
    except (json.JSONDecodeError, KeyError, TypeError, ValueError) as exc:
        raise InstanceMapError(f"{gt_path}: malformed ground truth ({type(exc).__name__}: {exc})") from None
    if T.shape != (4, 4):
        raise InstanceMapError(f"{gt_path}: T_src_ref must be 4x4, got {T.shape}")
    return RegistrationPair(
        src=read_instance_map(pair_dir / "src"), ref=read_instance_map(pair_dir / "ref"), T_src_ref=T,
        gt_node_pairs=rows[:, :2].astype(np.int64), gt_iou=rows[:, 2].astype(np.float32),
        meta=gt.get("meta", {}),
    )
