"""Read, write, check and cut instance maps (the directory contract of docs/ARCHITECTURE.md ("Contracts")).

Public API:
    class InstanceMapError(ValueError)       one-line message naming the file and the problem
    read_instance_map(path) -> InstanceMap   points.npy, instance.npy, instances.json, colors.npy?
                                             (extra files such as semantic.npy are ignored)
    write_instance_map(imap, path) -> None   the same layout; creates the directory
    points_problem(points) -> str | None     why points cannot be used (not finite, too far)
    validate_instance_map(imap, where="instance map") -> InstanceMap
                                             shapes, dtypes, finite points, >= 1 labelled point;
                                             returns a copy with canonical dtypes
    labelled_mask(imap) -> (N,) bool         points whose id is > 0 and has a label
    select_points(imap, mask) -> InstanceMap the points under mask; labels/scores of instances
                                             that lost every point are dropped

Ids in instance.npy that instances.json does not name are kept in the array but count as
unlabelled (docs/ARCHITECTURE.md); a map with no labelled point at all is an error.
"""
from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from ..geometry import MAX_COORD_M
from ..types import InstanceMap


class InstanceMapError(ValueError):
    """A malformed instance map; the message is one line and names the file."""


def points_problem(points) -> str | None:
    """Why map points cannot be used (NaN or infinite, or beyond MAX_COORD_M), else None."""
    pts = np.asarray(points)
    if not np.isfinite(pts).all():
        bad = int((~np.isfinite(pts)).any(axis=1).sum())
        return f"{bad} points are NaN or infinite"
    if pts.size and np.abs(pts).max() > MAX_COORD_M:   # a building, not a continent: grids over it must fit
        return f"points lie more than {MAX_COORD_M:g} m from the origin"
    return None


def labelled_mask(imap: InstanceMap) -> np.ndarray:
    ids = np.fromiter(imap.labels.keys(), dtype=np.int64, count=len(imap.labels))
    return (imap.instance > 0) & np.isin(imap.instance, ids)


def validate_instance_map(imap: InstanceMap, where: str = "instance map") -> InstanceMap:
    """Check an in-memory map; raise InstanceMapError naming `where` on the first problem."""
    pts = np.asarray(imap.points)
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise InstanceMapError(f"{where}: points must have shape (N, 3), got {pts.shape}")
    if not np.issubdtype(pts.dtype, np.floating):
        raise InstanceMapError(f"{where}: points must be float, got dtype {pts.dtype}")
    if len(pts) == 0:
        raise InstanceMapError(f"{where}: empty map (0 points)")
    problem = points_problem(pts)
    if problem:
        raise InstanceMapError(f"{where}: {problem}")
    inst = np.asarray(imap.instance)
    if inst.shape != (len(pts),):
        raise InstanceMapError(f"{where}: instance must have shape ({len(pts)},), got {inst.shape}")
    if not np.issubdtype(inst.dtype, np.integer):
        raise InstanceMapError(f"{where}: instance ids must be integers, got dtype {inst.dtype}")
    if inst.size and (inst.max() > _INT32[1] or inst.min() < _INT32[0]):
        raise InstanceMapError(f"{where}: instance ids do not fit in int32")
    if any(isinstance(k, bool) or not isinstance(k, (int, np.integer)) or not _INT32[0] <= k <= _INT32[1]
           for k in imap.labels):
        raise InstanceMapError(f"{where}: label ids must be int32 instance ids")
    colors = imap.colors
    if colors is not None:
        colors = np.asarray(colors)
        if colors.shape != (len(pts), 3):
            raise InstanceMapError(f"{where}: colors must have shape ({len(pts)}, 3), got {colors.shape}")
        if colors.dtype != np.uint8:
            raise InstanceMapError(f"{where}: colors must be uint8, got dtype {colors.dtype}")
    for k, v in imap.labels.items():
        if not isinstance(v, str) or not v.strip():
            raise InstanceMapError(f"{where}: instance {k} has an empty or non-text label")
    out = InstanceMap(
        points=pts.astype(np.float32, copy=False),
        instance=inst.astype(np.int32, copy=False),
        labels={int(k): str(v) for k, v in imap.labels.items()},
        scores={int(k): float(imap.scores.get(k, 1.0)) for k in imap.labels},
        colors=colors,
    )
    if not labelled_mask(out).any():
        raise InstanceMapError(f"{where}: no labelled point (no id of instance.npy is in the labels)")
    return out


def select_points(imap: InstanceMap, mask: np.ndarray) -> InstanceMap:
    inst = imap.instance[mask]
    present = set(np.unique(inst).tolist())
    return InstanceMap(
        points=imap.points[mask],
        instance=inst,
        labels={k: v for k, v in imap.labels.items() if k in present},
        scores={k: v for k, v in imap.scores.items() if k in present},
        colors=None if imap.colors is None else imap.colors[mask],
    )


def _load_npy(path: Path) -> np.ndarray:
    if not path.is_file():
        raise InstanceMapError(f"{path}: missing file")
    try:
        data = np.load(path, allow_pickle=False)
    except Exception as exc:  # numpy raises several types for corrupt files
        raise InstanceMapError(f"{path}: not a readable .npy file ({type(exc).__name__})") from None
    if not isinstance(data, np.ndarray):
        data.close()   # np.load opens an .npz archive whatever the file's name
        raise InstanceMapError(f"{path}: an .npz archive, not an .npy array")
    return data


_INT32 = (int(np.iinfo(np.int32).min), int(np.iinfo(np.int32).max))


def _finite(x: int | float) -> bool:
    """A finite number (an int too large for a float is none)."""
    try:
        return math.isfinite(x)
    except OverflowError:
        return False


def _load_instances_json(path: Path) -> tuple[dict[int, str], dict[int, float]]:
    if not path.is_file():
        raise InstanceMapError(f"{path}: missing file")
    try:
        entries = json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise InstanceMapError(f"{path}: malformed JSON ({exc})") from None
    except RecursionError:
        raise InstanceMapError(f"{path}: malformed JSON (nested too deep)") from None
    if not isinstance(entries, list):
        raise InstanceMapError(f"{path}: expected a list of {{id, label, score?}}, got {type(entries).__name__}")
    labels: dict[int, str] = {}
    scores: dict[int, float] = {}
    for n, e in enumerate(entries):
        if not isinstance(e, dict) or "id" not in e or "label" not in e:
            raise InstanceMapError(f"{path}: entry {n} must be an object with 'id' and 'label'")
        iid, label, score = e["id"], e["label"], e.get("score", 1.0)
        if isinstance(iid, bool) or not isinstance(iid, int):
            raise InstanceMapError(f"{path}: entry {n} has a non-integer id {iid!r}")
        if not _INT32[0] <= iid <= _INT32[1]:
            raise InstanceMapError(f"{path}: entry {n} has an id {iid} beyond int32")
        if not isinstance(label, str) or not label.strip():
            raise InstanceMapError(f"{path}: entry {n} (id {iid}) has an empty or non-text label")
        if isinstance(score, bool) or not isinstance(score, (int, float)) or not _finite(score):
            raise InstanceMapError(f"{path}: entry {n} (id {iid}) has a non-numeric score {score!r}")
        if iid in labels:
            raise InstanceMapError(f"{path}: id {iid} appears twice")
        labels[iid] = label
        scores[iid] = float(score)
    return labels, scores


def read_instance_map(path: str | Path) -> InstanceMap:
    """Read an instance map directory; raise InstanceMapError on any malformed input."""
    path = Path(path)
    if not path.is_dir():
        raise InstanceMapError(f"{path}: not a directory")
    points = _load_npy(path / "points.npy")
    instance = _load_npy(path / "instance.npy")
    labels, scores = _load_instances_json(path / "instances.json")
    colors = _load_npy(path / "colors.npy") if (path / "colors.npy").exists() else None
    if points.ndim != 2 or points.shape[1:] != (3,):
        raise InstanceMapError(f"{path / 'points.npy'}: expected shape (N, 3), got {points.shape}")
    if not np.issubdtype(points.dtype, np.floating):
        raise InstanceMapError(f"{path / 'points.npy'}: expected float32, got dtype {points.dtype}")
    if instance.shape != (points.shape[0],):
        raise InstanceMapError(
            f"{path / 'instance.npy'}: expected shape ({points.shape[0]},) to match points.npy, got {instance.shape}"
        )
    if not np.issubdtype(instance.dtype, np.integer):
        raise InstanceMapError(f"{path / 'instance.npy'}: expected int32, got dtype {instance.dtype}")
    if colors is not None and (colors.shape != points.shape or colors.dtype != np.uint8):
        raise InstanceMapError(
            f"{path / 'colors.npy'}: expected uint8 {points.shape}, got {colors.dtype} {colors.shape}"
        )
    imap = InstanceMap(points=points, instance=instance, labels=labels, scores=scores, colors=colors)
    return validate_instance_map(imap, where=str(path))


def write_instance_map(imap: InstanceMap, path: str | Path) -> None:
    """Write `imap` as an instance map directory (validated first)."""
    imap = validate_instance_map(imap)
    path = Path(path)
    path.mkdir(parents=True, exist_ok=True)
    np.save(path / "points.npy", imap.points)
    np.save(path / "instance.npy", imap.instance)
    entries = [
        {"id": k, "label": v, "score": round(float(imap.scores.get(k, 1.0)), 6)}
        for k, v in sorted(imap.labels.items())
    ]
    (path / "instances.json").write_text(json.dumps(entries, indent=1))
    if imap.colors is not None:
        np.save(path / "colors.npy", imap.colors)
    elif (path / "colors.npy").exists():
        (path / "colors.npy").unlink()
