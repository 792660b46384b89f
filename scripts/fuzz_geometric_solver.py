"""Which clouds crash KISS-Matcher (the geometric pose's solver), against their surface count.

The solver segfaults on some clouds (the process ends; nothing can catch it), so the geometric
pose hands it no cloud with fewer than GeometricConfig.min_surface surface voxels on either side
(pose/geometric.py). This script is how that floor was chosen: each seeded random cloud (scattered
points, flat patches, blobs, lines, parts of a room) is given to the solver against a furnished
room, as source and as reference, in a process of its own; it prints every cloud's surface count
and whether the solver crashed, then the largest surface count of a crash.

    python scripts/fuzz_geometric_solver.py --clouds 250        # about 10 minutes on 2 cores
"""
from __future__ import annotations

import argparse
import subprocess
import sys

import numpy as np

ONE = """
import sys, numpy as np
sys.path.insert(0, {root!r})
from scripts.fuzz_geometric_solver import cloud, room
from sgreg_core.pose.geometric import GeometricConfig, surface_count
from sgreg_core.pose.verify import finite_voxel_downsample
import kiss_matcher
small, big = cloud({seed}).astype(np.float32), room(np.random.default_rng(0)).astype(np.float32)
voxel = GeometricConfig().voxel
print(surface_count(finite_voxel_downsample(small, voxel), voxel), flush=True)
src, ref = (big, small) if {as_ref} else (small, big)
kiss_matcher.KISSMatcher(kiss_matcher.KISSMatcherConfig(voxel)).estimate(src, ref)
"""


def room(rng: np.random.Generator, n: int = 40000) -> np.ndarray:
    """Floor and four walls of a 4 x 5 x 2.5 m room."""
    face, u, v = rng.integers(5, size=n), rng.random(n), rng.random(n)
    faces = [np.c_[4 * u, 5 * v, 0 * u], np.c_[0 * u, 5 * u, 2.5 * v], np.c_[4 + 0 * u, 5 * u, 2.5 * v],
             np.c_[4 * u, 0 * u, 2.5 * v], np.c_[4 * u, 5 + 0 * u, 2.5 * v]]
    return np.choose(face[:, None], faces)


def cloud(seed: int) -> np.ndarray:
    """A seeded random small cloud: scattered points, flat patches and blobs, a line, or part of
    a room, each point repeated a few times (as a sampled dense message may)."""
    rng = np.random.default_rng(seed)
    kind, k = int(rng.integers(5)), int(rng.integers(1, 1500))
    extent = float(rng.choice([0.5, 1.0, 2.0, 5.0, 10.0]))
    if kind == 0:
        pts = rng.random((k, 3)) * extent
    elif kind == 1:
        patches = [rng.random(3) * 5 + np.c_[rng.random((64, 2)) * 0.4, np.zeros(64)]
                   @ np.linalg.qr(rng.normal(size=(3, 3)))[0].T for _ in range(int(rng.integers(8)))]
        pts = np.concatenate([rng.random((k // 3, 3)) * extent] + patches)
    elif kind == 2:
        blobs = rng.random((max(1, k // 50), 3)) * extent
        pts = np.repeat(blobs, 50, axis=0) + rng.normal(0, 0.05, (blobs.shape[0] * 50, 3))
    elif kind == 3:
        pts = rng.random((k, 3)) * [extent, 0.01, 0.01]
    else:
        pts = room(rng)[: 10 * k] * extent / 5
    pts = pts if len(pts) else np.zeros((1, 3))
    return np.repeat(pts, int(rng.choice([1, 5, 20])), axis=0) + 0.05


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--clouds", type=int, default=250, help="random clouds (each run twice)")
    parser.add_argument("--seed", type=int, default=0, help="first cloud's seed")
    args = parser.parse_args()
    from pathlib import Path
    root = str(Path(__file__).resolve().parent.parent)
    crashed, survived = [], []
    for i, seed in enumerate(range(args.seed, args.seed + args.clouds)):
        for as_ref in (True, False):
            out = subprocess.run([sys.executable, "-c", ONE.format(root=root, seed=seed, as_ref=as_ref)],
                                 capture_output=True, text=True, timeout=300)
            surface = int(out.stdout.split()[0]) if out.stdout.split() else -1
            (crashed if out.returncode < 0 or out.returncode == 139 else survived).append(surface)
            print(f"[{i + 1}/{args.clouds}] cloud {seed} as {'reference' if as_ref else 'source'}: "
                  f"surface {surface}, exit {out.returncode}", flush=True)
    print(f"{len(crashed)} crashes in {len(crashed) + len(survived)} runs; largest surface of a "
          f"crash: {max(crashed, default=None)}; smallest surface that ran: {min(survived, default=None)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
