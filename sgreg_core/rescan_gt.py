"""The pseudo ground truth between captures of one room (rescan_gt.json), read in one place.

Training pairs, bench-register's rescan cases and make-bag's second capture all rest on it, so
they read it by one rule: an entry is used only when its `accepted` is the JSON boolean true
(the string "no" is truthy and must not read as accepted) and its T_src_to_ref is a rigid 4x4.
A malformed file or entry is refused with one line naming it, never skipped: a pair silently
dropped from training or a benchmark changes the numbers without a word.

Public API:
    RescanGTError                         ValueError with a one-line reason
    RescanPair                            one entry: src, ref, accepted, T (src -> ref), reasons
    load_rescan_gt(path) -> [RescanPair]  every entry, validated
    accepted_directions(pairs, scans, both_ways) -> [(src, ref, T_src_to_ref)]
                                          the accepted pairs between scans, each also reversed
                                          when both_ways
    transform_between(pairs, a, b) -> T   T mapping b's points into a's frame, or RescanGTError
                                          saying why there is none (rejected with its reasons,
                                          or no entry)
    room_of(scan) -> str                  the room a capture is of (what held-out rooms name)
    SCANNET_CAPTURE                       the pattern of a ScanNet capture in a folder name
"""
from __future__ import annotations

import json
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .geometry import invert_transform, is_rigid


class RescanGTError(ValueError):
    """A pseudo ground truth that cannot be used as it is: one line, naming the file."""


@dataclass(frozen=True)
class RescanPair:
    src: str
    ref: str
    accepted: bool
    T: np.ndarray | None = None                 # src -> ref, set when accepted
    reasons: tuple[str, ...] = ()               # why a rejected pair was rejected


def load_rescan_gt(path: str | Path) -> list[RescanPair]:
    """Every entry of the file at path, validated: {"pairs": [{src, ref, accepted, ...}]}."""
    try:
        data = json.loads(Path(path).read_text())
    except (OSError, ValueError) as exc:
        raise RescanGTError(f"cannot read pseudo ground truth {path}: {exc}") from None
    entries = data.get("pairs") if isinstance(data, dict) else None
    if not isinstance(entries, list) or not all(isinstance(e, dict) for e in entries):
        raise RescanGTError(f"{path} is not a pseudo ground truth: expected {{\"pairs\": [objects]}}")
    return [_pair(e, path) for e in entries]


def _pair(entry: dict, path) -> RescanPair:
    src, ref = entry.get("src"), entry.get("ref")
    if not (isinstance(src, str) and isinstance(ref, str) and src and ref):
        raise RescanGTError(f"{path}: an entry's src and ref must be scan names, got {src!r}, {ref!r}")
    name = f"{ref} x {src}"
    accepted = entry.get("accepted")
    if not isinstance(accepted, bool):
        raise RescanGTError(f"{path}: 'accepted' of {name} must be true or false, got {accepted!r}")
    if not accepted:
        reasons = entry.get("reasons") or [entry.get("reason") or "no reason given"]
        return RescanPair(src, ref, False, reasons=tuple(map(str, reasons if isinstance(reasons, list) else [reasons])))
    # a bag's or a case's ground truth must be rigid, or every score against it is wrong
    if not is_rigid(entry.get("T_src_to_ref")):
        raise RescanGTError(f"{path}: T_src_to_ref of {name} is not a 4x4 rigid transform")
    return RescanPair(src, ref, True, np.asarray(entry["T_src_to_ref"], np.float64))


def accepted_directions(pairs: list[RescanPair], scans: set[str],
                        both_ways: bool = False) -> list[tuple[str, str, np.ndarray]]:
    out = []
    for p in pairs:
        if p.accepted and p.src in scans and p.ref in scans:
            out.append((p.src, p.ref, p.T))
            if both_ways:
                out.append((p.ref, p.src, invert_transform(p.T)))
    return out


def transform_between(pairs: list[RescanPair], a: str, b: str, path="the pseudo ground truth") -> np.ndarray:
    for p in pairs:
        if {p.src, p.ref} != {a, b}:
            continue
        if not p.accepted:
            raise RescanGTError(f"{path} rejects {a} x {b}: {'; '.join(p.reasons)}")
        # np.linalg.inv, as make-bag always used: the bags it made stay bit for bit the same
        return p.T if p.src == b else np.linalg.inv(p.T)
    raise RescanGTError(f"{path} has no entry for {a} x {b}")


# a ScanNet capture's name within a scan folder's: its room, then the capture number
SCANNET_CAPTURE = re.compile(r"(scene\d{4})_\d{2}")


def room_of(scan: str | Path) -> str:
    """The room a scan folder is a capture of, by one rule for training splits, benchmark cases
    and replay suites: 'scannet-picwoon_scene0005_01' -> 'scene0005'; otherwise the folder name
    less a trailing capture number ('lab_01' -> 'lab'); a name without one is its own room."""
    name = Path(scan).name
    m = SCANNET_CAPTURE.search(name)
    if m:
        return m.group(1)
    stem, _, capture = name.rpartition("_")
    return stem if stem and capture.isdigit() else name
