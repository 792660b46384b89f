"""`sgreg pairs SCAN_DIR OUT_DIR --n K --seed S [--overlap F] [--noise ...]`: cut K registration
pairs with ground truth from one instance map into OUT_DIR/pair_000, pair_001, ...

OUT_DIR must be new or empty, so that pairs of two runs never mix; --overwrite replaces an
earlier run's pairs (a folder of nothing but pair_XXX folders) and still refuses anything else.

--noise "confuse,merge=0.2,tilt=1.5,jitter" turns front-end errors on (NoiseConfig.preset);
every kind at once is "confuse,merge,invent,tilt,jitter,overseg,drop,paraphrase,partial"."""
from __future__ import annotations

import argparse
import re
import shutil
import sys
from pathlib import Path

import numpy as np

NAME = "pairs"
HELP = "cut registration pairs with ground truth from a scan"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("scan_dir", help="instance map directory")
    parser.add_argument("out_dir", help="where pair_XXX directories go: a new or empty folder")
    parser.add_argument("--overwrite", action="store_true",
                        help="replace the pairs of an earlier run in OUT_DIR (a folder holding "
                             "anything else is still refused)")
    parser.add_argument("--n", type=int, default=10, help="number of pairs")
    parser.add_argument("--seed", type=int, default=0, help="seed of the cuts and transforms")
    parser.add_argument("--overlap", type=float, default=0.5, help="fraction of points both views cover")
    parser.add_argument("--disjoint", choices=["band", "halves"], default="band",
                        help="how the views avoid sharing samples: band (only where they overlap) or halves")
    parser.add_argument(
        "--noise", default="",
        help="front-end errors, comma list of NAME (its preset rate) or NAME=RATE: confuse (0.15, "
             "wrong class), merge (0.1, fused with a neighbour), invent (0.1, invented instances "
             "per instance), tilt (2.0, largest gravity tilt of a view, deg), jitter (0.01 m), "
             "overseg (0.1), drop (0.1), paraphrase (0.3), partial (0.2); see "
             "sgreg_core/simulation/noise.py (default: none)")


def _clear_out_dir(out_dir: Path, overwrite: bool) -> None:
    """Let pairs go into out_dir: new or empty, or (overwrite) holding only an earlier run's
    pairs, which are removed; else ValueError. Pairs of two runs must not mix."""
    if out_dir.exists() and not out_dir.is_dir():
        raise ValueError(f"{out_dir} is a file, not a folder")
    entries = sorted(out_dir.iterdir()) if out_dir.is_dir() else []
    if not entries:
        return
    foreign = [e.name for e in entries if not _is_pair_dir(e)]
    if foreign:
        raise ValueError(f"{out_dir} is not empty and holds {foreign[0]}, which no pairs run wrote; "
                         "choose a new or empty folder")
    if not overwrite:
        raise ValueError(f"{out_dir} holds {len(entries)} pairs of an earlier run; pass --overwrite "
                         "to replace them, or choose a new folder")
    for e in entries:
        shutil.rmtree(e)


def _is_pair_dir(path: Path) -> bool:
    """A folder that write_pair wrote: pair_NNN with src/, ref/, gt.json and nothing else."""
    return (path.is_dir() and not path.is_symlink() and re.fullmatch(r"pair_\d{3,}", path.name) is not None
            and {e.name for e in path.iterdir()} <= {"src", "ref", "gt.json"})


def run(args: argparse.Namespace) -> int:
    from sgreg_core.maps.instance_map import InstanceMapError, read_instance_map
    from sgreg_core.simulation.noise import NoiseConfig
    from sgreg_core.simulation.pairs import PairConfig, make_pair, write_pair

    try:
        imap = read_instance_map(args.scan_dir)
        cfg = PairConfig(overlap=args.overlap, disjoint=args.disjoint, noise=NoiseConfig.preset(args.noise))
        if not 0 < args.overlap <= 1:
            raise ValueError(f"--overlap must be in (0, 1], got {args.overlap}")
        if args.seed < 0 or args.n < 1:
            raise ValueError(f"--seed must be >= 0 and --n >= 1, got {args.seed} and {args.n}")
        _clear_out_dir(Path(args.out_dir), args.overwrite)
    except (InstanceMapError, ValueError, OSError) as exc:
        print(f"sgreg pairs: {exc}", file=sys.stderr)
        return 2
    rng = np.random.default_rng(args.seed)
    for k in range(args.n):
        try:
            pair = make_pair(imap, cfg, rng)
            write_pair(pair, f"{args.out_dir}/pair_{k:03d}")
        except (InstanceMapError, OSError) as exc:
            print(f"sgreg pairs: pair {k}: {exc}", file=sys.stderr)
            return 2
        print(f"[{k + 1}/{args.n}] pair_{k:03d}: src {len(pair.src.points)} pts / {len(pair.src.labels)} inst, "
              f"ref {len(pair.ref.points)} pts / {len(pair.ref.labels)} inst, "
              f"gt matches {len(pair.matches(cfg.min_iou))}", flush=True)
    return 0
