#!/usr/bin/env python
"""How long one merge of a fleet's links takes (runtime/merge.py), by fleet size.

Every agent's registration node merges every agent's links once a merge period (1 s) on its
single-threaded executor, so a merge must stay well under that. Fleets of n agents, every
ordered pair linked by a slightly noisy right measurement (the worst case: the most links and
triangles to check), each size timed `--repeats` times (best kept). Prints a table and writes
JSON.

    python scripts/time_merge.py --sizes 5 9 17 33 --out results/time_merge.json
"""
from __future__ import annotations

import argparse
import itertools
import json
import time
from pathlib import Path

import numpy as np

from sgreg_core.bench.machine import describe
from sgreg_core.geometry import invert_transform
from sgreg_core.geometry import yaw_transform
from sgreg_core.runtime.merge import Link, MergeConfig, merge


def fleet_links(n: int, rng: np.random.Generator) -> list[Link]:
    """Every ordered pair of n agents, whose maps lie up to 30 m apart, linked with 0.03 deg /
    5 mm of noise."""
    world = [yaw_transform(rng.uniform(-np.pi, np.pi), rng.uniform(-30, 30, 3) * (1, 1, 0)) for _ in range(n)]
    names = [f"r{i:03d}" for i in range(n)]
    return [Link(names[s], names[d], yaw_transform(rng.normal(0, 5e-4), rng.normal(0, 5e-3, 3))
                 @ invert_transform(world[d]) @ world[s], 0.9)
            for s, d in itertools.permutations(range(n), 2)]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", type=int, nargs="+", default=[5, 9, 17, 33])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", type=Path, default=Path("results/time_merge.json"))
    args = ap.parse_args()
    if min(args.sizes) < 2 or args.repeats < 1:
        ap.error("--sizes must be >= 2 agents and --repeats >= 1")
    cfg, rows = MergeConfig(), []
    print(f"{'agents':>6}  {'links':>5}  {'merge ms':>8}  attached")
    for n in args.sizes:
        links = fleet_links(n, np.random.default_rng(args.seed + n))
        times = []
        for _ in range(args.repeats):
            t0 = time.perf_counter()
            result = merge(links, cfg=cfg)
            times.append(1e3 * (time.perf_counter() - t0))
        rows.append({"agents": n, "links": len(links), "merge_ms": min(times), "attached": len(result.attached)})
        print(f"{n:>6}  {len(links):>5}  {min(times):>8.1f}  {len(result.attached)}")
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps({"config": vars(cfg), "args": {k: str(v) for k, v in vars(args).items()},
                                    "machine": describe(), "rows": rows}, indent=2))
    print(f"results: {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
