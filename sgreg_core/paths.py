"""Where the project's files are. Relative paths in configs start at the repository, so that
defaults are the same on every machine: the real scans live in ../shared/data next to the
repository (never inside it: their terms forbid redistribution).

Public API:
    REPO                                  the repository root
    SCANS, RESCAN_GT                      default locations of the real scans and the pseudo
                                          ground truth between their captures (relative)
    resolve(path) -> Path                 absolute, relative ones taken from REPO
    require(path, what) -> Path           resolve, or FileNotFoundError with a one-line reason
    make_folder(path) -> Path             create an output folder (and its parents) and check it
                                          is writable, or OSError with a one-line reason
    output_file(path) -> Path             the same for the folder of an output file, which must
                                          not be a folder itself
    weights_files(path) -> (Path, Path)   a model's .safetensors and its .json, or
                                          FileNotFoundError naming both
    source_digest(*paths) -> str          16 hex chars over the Python sources under paths
                                          (files or folders, relative to REPO): a cache key part
                                          that a code change invalidates
"""
from __future__ import annotations

import os
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
SCANS = "../shared/data/scans"
RESCAN_GT = "../shared/data/rescan_gt.json"


def source_digest(*paths: str) -> str:
    import hashlib

    h = hashlib.sha256()
    for path in paths:
        root = REPO / path
        for f in sorted(root.rglob("*.py")) if root.is_dir() else [root]:
            h.update(str(f.relative_to(REPO)).encode())
            h.update(f.read_bytes())
    return h.hexdigest()[:16]


def resolve(path: str | Path) -> Path:
    path = Path(path).expanduser()
    return path if path.is_absolute() else (REPO / path).resolve()


def require(path: str | Path, what: str) -> Path:
    p = resolve(path)
    if not p.exists():
        raise FileNotFoundError(f"{what} {p} not found (relative paths start at the repository "
                                f"{REPO}; the real scans are expected in ../shared/data next to it)")
    return p


def make_folder(path: str | Path) -> Path:
    """Create folder `path` (as given: relative to the working directory) before the work whose
    output goes there, so that an unusable one fails at once rather than after the work."""
    p = Path(path)
    try:
        p.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise OSError(f"cannot create folder {p}: {exc.strerror or exc}") from None
    if not os.access(p, os.W_OK):
        raise OSError(f"cannot write into folder {p}")
    return p


def output_file(path: str | Path) -> Path:
    """Check output file `path` before the work whose result goes there: its folder is made and
    writable, and it is not a folder (OSError with a one-line reason)."""
    p = Path(path)
    if p.is_dir():
        raise OSError(f"{p} is a folder; give a file name")
    make_folder(p.parent)
    return p


def weights_files(path: str | Path) -> tuple[Path, Path]:
    """The two files of model weights (the .safetensors and the .json of its config), checked
    without importing torch (`sgreg agents` checks them before starting any node)."""
    weights = Path(path)
    info = weights.with_suffix(".json")
    if not (weights.is_file() and info.is_file()):
        raise FileNotFoundError(f"model weights need {weights} and {info}")
    return weights, info
