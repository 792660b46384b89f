#!/usr/bin/env python
"""Footprint fitness of right and wrong poses for several footprint rims and probes
(docs/VERDICT.md sections 7 and 10).

For bench-register pairs of the given rooms (clean, noisy and frontend views), the fitness the
verdict sees is computed at the true pose and at ten wrong ones (yaw 90/180/270 deg about the
source's centre, slides of 0.8-1.5 m), for each combination of rim and footprint probe (m, 0:
off). Wrong poses that put less than the verdict's minimum footprint share on the reference's
plan are left out (the verdict refuses them anyway). Prints a table and writes JSON. Choose on
rooms seen in training only.

    python scripts/compare_footprint_rims.py --rooms scene0000 scene0001 scene0002 scene0003 \
        scene0004 --n 20 --rims 0 1 2 --probes 0 --out results/footprint_rims.json
    python scripts/compare_footprint_rims.py --rooms ... --rims 0 --probes 0 0.3 0.5 0.8
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from sgreg_core.bench.cases import CaseConfig, build_cases
from sgreg_core.geometry import yaw_transform
from sgreg_core.pipeline import PipelineConfig, build_graphs, node_cloud, reference_cloud
from sgreg_core.pose import CloudVerifier, ReferenceCloud

SETTINGS = ("clean", "noisy", "frontend")


def wrong_poses(T: np.ndarray, centre: np.ndarray) -> list[np.ndarray]:
    to_c, from_c = np.eye(4), np.eye(4)
    to_c[:3, 3], from_c[:3, 3] = -centre, centre
    poses = [T @ from_c @ yaw_transform(np.radians(yaw)) @ to_c for yaw in (90, 180, 270)]
    for dx, dy in ((1.5, 0), (0, 1.5), (-1.5, 0), (0, -1.5), (0.8, 0), (0, -0.8), (0.6, 0.6)):
        slide = np.eye(4)
        slide[:2, 3] = dx, dy
        poses.append(slide @ T)
    return poses


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--rooms", nargs="+", required=True)
    p.add_argument("--n", type=int, default=20)
    p.add_argument("--seed", type=int, default=7)
    p.add_argument("--rims", nargs="+", type=int, default=[0, 1, 2])
    p.add_argument("--probes", nargs="+", type=float, default=[0.0])
    p.add_argument("--out", default="results/footprint_rims.json")
    args = p.parse_args()

    cases = build_cases(CaseConfig(n=args.n, seed=args.seed, rooms=tuple(args.rooms)), SETTINGS)
    pipe = PipelineConfig()    # dense
    pose = pipe.pose_config()
    min_share = pipe.pose.verdict.min_footprint_share
    combos = [(rim, probe) for rim in args.rims for probe in args.probes]
    scores = {c: {s: {"right": [], "wrong": []} for s in SETTINGS} for c in combos}
    for k, case in enumerate(cases):
        src_graph, ref_graph = build_graphs(case.src, case.ref, pipe)
        T = ref_graph.level.T @ case.T_gt @ np.linalg.inv(src_graph.level.T)  # levelled frames
        src = node_cloud(src_graph)
        wrong = wrong_poses(T, src.mean(0))
        reference = ReferenceCloud(reference_cloud(ref_graph), pose.verify_voxel, pose.footprint_cell)
        for rim, probe in combos:
            verify = CloudVerifier(src, reference, pose.verify_voxel, pose.verify_tau,
                                   pose.verify_max_points, pose.seed, footprint_rim=rim,
                                   footprint_probe=probe)
            bucket = scores[rim, probe][case.setting]
            bucket["right"].append(verify(T).footprint_fitness)
            bucket["wrong"] += [v.footprint_fitness for v in map(verify, wrong)
                                if v.footprint_share >= min_share]
        print(f"\r{k + 1}/{len(cases)} cases", end="", flush=True)
    print()

    rows = []
    print(f"{'rim':>3} {'probe':>5} {'setting':9} {'right p10':>9} {'right p50':>9} "
          f"{'wrong p50':>9} {'wrong p99':>9} {'wrong max':>9}  (n right / wrong)")
    for rim, probe in combos:
        for s in SETTINGS:
            bucket = scores[rim, probe][s]
            r, w = np.array(bucket["right"]), np.array(bucket["wrong"])
            row = {"rim": rim, "probe": probe, "setting": s, "right": len(r), "wrong": len(w),
                   "right_p10": float(np.percentile(r, 10)), "right_p50": float(np.median(r)),
                   "wrong_p50": float(np.median(w)), "wrong_p99": float(np.percentile(w, 99)),
                   "wrong_max": float(w.max())}
            rows.append(row)
            print(f"{rim:3d} {probe:5.2f} {s:9} {row['right_p10']:9.2f} {row['right_p50']:9.2f} "
                  f"{row['wrong_p50']:9.2f} {row['wrong_p99']:9.2f} {row['wrong_max']:9.2f}"
                  f"  ({len(r)} / {len(w)})")
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps({"args": vars(args), "rows": rows}, indent=1))
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
