"""`sgreg register SRC_DIR REF_DIR [--json OUT] [--coarse] [--no-icp] [--png OUT] [--weights W]
[--set KEY=VALUE ...]`: register two instance map directories with SG-Reg (sgreg_core.pipeline);
--set overrides a PipelineConfig entry (e.g. pose.footprint_rim=1; coarse_pose.* with --coarse).
`sgreg register --pairs FILE [--json OUT]`: many pairs (one "SRC_DIR REF_DIR" per line), the
model loaded once; --json then writes a list of results, and a pair with bad input (or one
that fails in the pipeline) is an entry with an "error" instead of the end of the run; a
single pair with bad input or that fails in the pipeline is written as such an "error" too
(one line on stderr, exit 2): once the maps are read, --json gets this run's result or error.

Prints the 4x4 transform mapping SRC points into REF's frame and a one-line verdict; --json
writes the result of docs/ARCHITECTURE.md ("Contracts") (+ reason, weights_id, mode, correspondences,
fitness, node pairs). Exit status: 0 registered, 1 not registered (the result is still
printed and written), 2 bad input or a failure in the pipeline (one line on stderr; either
is written to --json as an "error"; what is refused before the maps are read, a bad flag,
pairs file or weights, writes nothing, so an earlier file stays). timing_ms covers the registration
(graphs, encoding, matching, pose); loading the network and the text encoder is startup_ms.
--png is checked before registering and drawn after --json is written, so that a picture that
cannot be drawn loses no result.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from collections.abc import Callable

    from sgreg_core.pipeline import PipelineConfig

NAME = "register"
HELP = "register two instance maps (prints T, writes JSON)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("src_dir", nargs="?", help="instance map directory of the source (SRC)")
    parser.add_argument("ref_dir", nargs="?", help="instance map directory of the reference (REF)")
    parser.add_argument("--pairs", metavar="FILE",
                        help="register every 'SRC_DIR REF_DIR' line of FILE (# comments), loading once")
    parser.add_argument("--json", dest="json_out", help="write the result here")
    parser.add_argument("--coarse", action="store_true",
                        help="node-center correspondences only (no point matching)")
    parser.add_argument("--no-icp", action="store_true",
                        help="judge the estimate as it is, without ICP refinement (by default "
                             "the better supported of the estimate and its ICP refinement is)")
    parser.add_argument("--png", help="draw both clouds after registration (top view)")
    parser.add_argument("--weights", help="model .safetensors (default: the shipped model)")
    parser.add_argument("--threads", type=int, default=1,
                        help="torch threads (small graphs: 1 is fastest)")
    parser.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                        help="override a PipelineConfig entry, e.g. pose.footprint_rim=1 "
                             "(coarse_pose.* with --coarse; repeatable; see docs/VERDICT.md)")


def _fail(message: str) -> int:
    print(f"sgreg register: {message}", file=sys.stderr)
    return 2


def read_pairs(path: str) -> list[tuple[str, str]]:
    """The 'SRC_DIR REF_DIR' lines of a pairs file; ValueError names a bad line."""
    pairs = []
    for number, line in enumerate(open(path, encoding="utf-8"), 1):
        words = line.split("#", 1)[0].split()
        if not words:
            continue
        if len(words) != 2:
            raise ValueError(f"{path}:{number}: expected 'SRC_DIR REF_DIR', got {line.strip()!r}")
        pairs.append((words[0], words[1]))
    if not pairs:
        raise ValueError(f"{path} lists no pair")
    return pairs


def run(args: argparse.Namespace) -> int:
    import time

    import torch

    from sgreg_core.net.model import load_model
    from sgreg_core.pipeline import warm_up
    from sgreg_core.plots import figure_path

    one_pair = bool(args.src_dir and args.ref_dir)
    if args.pairs and args.src_dir:
        return _fail("give SRC_DIR REF_DIR or --pairs FILE, not both")
    if one_pair == bool(args.pairs) or (args.src_dir and not one_pair):
        return _fail("give SRC_DIR REF_DIR, or --pairs FILE")
    if args.pairs and args.png:
        return _fail("--png draws one pair; leave it out with --pairs")
    try:
        pairs = read_pairs(args.pairs) if args.pairs else [(args.src_dir, args.ref_dir)]
    except (OSError, ValueError) as exc:
        return _fail(str(exc))
    try:
        cfg = pipeline_config(args)
    except (TypeError, ValueError) as exc:
        return _fail(f"--set: {exc}")
    try:
        if args.png:
            figure_path(args.png)
    except (OSError, ValueError) as exc:
        return _fail(f"--png: {exc}")
    if args.threads < 1:
        return _fail(f"--threads must be >= 1, got {args.threads}")
    torch.set_num_threads(args.threads)
    t0 = time.perf_counter()
    try:
        model = load_model(args.weights)
    except (FileNotFoundError, RuntimeError, ValueError, OSError) as exc:
        return _fail(f"cannot load weights: {' '.join(str(exc).split())}")
    warm_up(model)
    startup_ms = 1e3 * (time.perf_counter() - t0)

    results, codes = [], []
    try:
        draw = _register_all(pairs, args, model, cfg, startup_ms, results, codes)
    except KeyboardInterrupt:
        # Ctrl-C in a long --pairs run keeps what was registered (main says "interrupted")
        if args.pairs and args.json_out and results:
            _write_json(Path(args.json_out), results)
            print(f"\n{len(results)} of {len(pairs)} pairs registered before Ctrl-C: {args.json_out}",
                  file=sys.stderr)
        raise
    if args.pairs:
        ok = sum(c == 0 for c in codes)
        print(f"{ok} of {len(pairs)} pairs registered ({codes.count(2)} with bad input or failed); "
              f"model loaded once in {startup_ms:.0f} ms")
    if args.json_out:
        out = Path(args.json_out)
        try:
            _write_json(out, results if args.pairs else results[0])
        except OSError as exc:
            return _fail(f"cannot write {out}: {exc.strerror or exc}")
    if args.png and codes[0] != 2:
        try:
            draw(args.png)
        except (OSError, ValueError, RuntimeError) as exc:
            return _fail(f"cannot draw {args.png}: {' '.join(str(exc).split())}")
    return max(codes)


def _write_json(out: Path, doc) -> None:
    import json

    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(doc, indent=1) + "\n")


def _register_all(pairs, args, model, cfg, startup_ms, results: list, codes: list):
    """Register every pair, appending to results and codes as each is done; returns the
    drawing of the last pair registered (--png takes the one pair's)."""
    from sgreg_core.maps.instance_map import InstanceMapError, read_instance_map

    draw = None
    for src_dir, ref_dir in pairs:
        try:
            maps = read_instance_map(src_dir), read_instance_map(ref_dir)
        except InstanceMapError as exc:
            # written to --json like any other result, so no stale file of an earlier run stays
            if not args.pairs:
                _fail(str(exc))
            results.append(_pair_error(src_dir, ref_dir, "bad input", str(exc), say=bool(args.pairs)))
            codes.append(2)
            continue
        try:
            result, draw = _register_one(model, cfg, src_dir, ref_dir, *maps, startup_ms,
                                         single=not args.pairs)
        except Exception as exc:
            # a pair that breaks the pipeline is a result too (an "error" entry, exit 2), and with
            # --pairs it must not lose the results of the others
            what = " ".join(str(exc).split())
            results.append(_pair_error(src_dir, ref_dir, "failed", f"{type(exc).__name__}: {what} "
                                       f"(at {_where(exc)}; please report it with the two maps)"))
            codes.append(2)
            continue
        results.append(result)
        codes.append(0 if result["success"] else 1)
    return draw


def _where(exc: BaseException) -> str:
    """file:line where exc was raised, as a bug report needs it: the innermost frame in sgreg's
    own packages, then the frame it came from where that lies elsewhere (a library)."""
    import traceback

    frames = traceback.extract_tb(exc.__traceback__)
    ours = [f for f in frames if {"sgreg_core", "sgreg_cli", "sgreg_ros"} & set(Path(f.filename).parts)]
    at = [f for f in (ours[-1] if ours else None, frames[-1]) if f is not None]
    return " -> ".join(dict.fromkeys(f"{Path(f.filename).name}:{f.lineno}" for f in at))


def _pair_error(src_dir: str, ref_dir: str, what: str, message: str, say: bool = True) -> dict:
    """The result of a pair that was not registered, said on stderr too (unless said already)."""
    if say:
        print(f"{src_dir} -> {ref_dir}: {what}: {message}", file=sys.stderr)
    return {"src": src_dir, "ref": ref_dir, "success": False, "error": message}


def pipeline_config(args: argparse.Namespace) -> PipelineConfig:
    """PipelineConfig from the flags, then the --set overrides."""
    from sgreg_core.config import apply_overrides, from_dict, to_dict
    from sgreg_core.pipeline import PipelineConfig

    # (mode, its pose settings, the other mode's): taken silently, the other's would change nothing
    mode, own, other = ("--coarse", "coarse_pose.", "pose.") if args.coarse else ("dense", "pose.", "coarse_pose.")
    ignored = [o for o in args.overrides if o.startswith(other)]
    if ignored:
        raise ValueError(f"{', '.join(ignored)}: {mode} registration takes {own}*, not {other}*")
    data = to_dict(PipelineConfig(mode="coarse" if args.coarse else "dense",
                                  icp="never" if args.no_icp else "always"))
    return from_dict(PipelineConfig, apply_overrides(data, args.overrides))


def _register_one(model, cfg, src_dir, ref_dir, src_map, ref_map, startup_ms,
                  single) -> tuple[dict, Callable[[str], None]]:
    """The result of one pair, and what draws it (a path -> the picture)."""
    from functools import partial

    import numpy as np

    from sgreg_core.pipeline import build_graphs, register_graphs

    timings: dict = {}
    src_graph, ref_graph = build_graphs(src_map, ref_map, cfg, timings)
    reg = register_graphs(model, src_graph, ref_graph, cfg, timings)
    result = {**reg.to_json(), "weights_id": model.weights_id, "icp": cfg.icp,
              "src": str(src_dir), "ref": str(ref_dir),
              "nodes": {"src": src_graph.num_nodes, "ref": ref_graph.num_nodes},
              "startup_ms": round(startup_ms, 1)}
    verdict = "registered" if reg.success else f"NOT registered ({reg.reason})"
    draw = partial(_draw, src_graph, ref_graph, reg, verdict)
    if not single:
        print(f"{src_dir} -> {ref_dir}: {verdict}, {reg.inliers} inliers, confidence "
              f"{reg.confidence:.2f}, {reg.timing_ms['total']:.0f} ms")
        return result, draw
    with np.printoptions(precision=6, suppress=True):
        print(f"T (SRC -> REF):\n{np.asarray(reg.T)}")
    print(f"{verdict}: {reg.mode}, {reg.node_matches} node matches, {reg.correspondences} "
          f"correspondences, {reg.inliers} inliers over {reg.inlier_nodes} node matches, "
          f"fitness {reg.fitness:.3f} (on the reference footprint {reg.footprint_fitness:.3f}), "
          f"ambiguity {reg.evidence.ambiguity:.2f}, confidence {reg.confidence:.2f}, "
          f"{reg.timing_ms['total']:.0f} ms (+ {startup_ms:.0f} ms loading the model)")
    if reg.levelling:
        print("levelled: " + ", ".join(f"{k} tilted {v['tilt_deg']:.2f} deg" + ("" if v["ok"] else
                                       f" (left as it is: {v['reason']})") for k, v in reg.levelling.items()))
    return result, draw


def _draw(src_graph, ref_graph, reg, verdict: str, png: str) -> None:
    from sgreg_core.pipeline import node_cloud
    from sgreg_core.plots.registration import plot_registration

    lookup = [{int(i): k for k, i in enumerate(g.node_ids)} for g in (src_graph, ref_graph)]
    si = [lookup[0][int(i)] for i in reg.node_pairs[:, 0]]
    ri = [lookup[1][int(i)] for i in reg.node_pairs[:, 1]]
    plot_registration(node_cloud(src_graph), node_cloud(ref_graph), reg.T_levelled, png,
                      src_graph.centers[si], ref_graph.centers[ri],
                      title=f"{verdict}: {reg.node_matches} node matches, {reg.inliers} inliers")
