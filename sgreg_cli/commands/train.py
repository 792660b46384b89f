"""`sgreg train --config FILE [--resume] [--set KEY=VALUE ...]`: train the SG-Reg network.

Examples:
    sgreg train --config config/train.yaml
    sgreg train --config config/train.yaml --resume           # continue an interrupted run
    sgreg train --config config/train.yaml --set run_dir=runs/abl_notriplet \\
        --set model.gnn.use_triplets=false --set optim.steps=600   # an ablation
"""
from __future__ import annotations

import argparse
import sys

NAME = "train"
HELP = "train the SG-Reg network"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--config", required=True, help="training config (YAML, see config/train.yaml)")
    parser.add_argument("--resume", action="store_true", help="continue from run_dir/checkpoint.pt")
    parser.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                        help="override a config entry, dotted path (e.g. optim.steps=100); repeatable")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")


def run(args: argparse.Namespace) -> int:
    from pathlib import Path

    import yaml

    from sgreg_core.config import apply_overrides, from_dict
    from sgreg_core.net.train import TrainConfig, train

    try:
        data = yaml.safe_load(Path(args.config).read_text()) or {}
        cfg = from_dict(TrainConfig, apply_overrides(data, args.overrides))
    except (OSError, yaml.YAMLError, ValueError, TypeError) as exc:
        print(f"sgreg train: {args.config}: {exc}", file=sys.stderr)
        return 2
    try:
        model_path = train(cfg, resume=args.resume, progress=not args.no_progress)
    except (FileExistsError, FileNotFoundError, ValueError) as exc:
        print(f"sgreg train: {exc}", file=sys.stderr)
        return 2
    print(f"model: {model_path} (+ {model_path.with_suffix('.json').name}); run dir {cfg.run_dir}")
    return 0
