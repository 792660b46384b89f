"""`sgreg bench-replay SUITE.yaml [--out DIR] [--backend ros|offline]`: make every bag of a suite
(once; cached in the suite's bag_dir), replay each one after the other and score it, then write
DIR/results.json (summary rows, per-bag rows, reliability of the stated confidence, and how
many registrable frames the link rules could reach with the run's estimates),
DIR/config.json, one DIR/bags/<bag>.json per bag, DIR/summary.png, and print the tables.

Per-bag results are cached: a bag whose result was made with the same bag spec, backend,
weights, parameters and source code is not replayed again (--fresh replays everything), so an
interrupted run resumes where it stopped. A bag made with other settings is made again; a folder
in a bag's place that make-bag did not make is never replaced: the run stops and names it.

Backends: "ros" (default) starts real nodes as separate processes over DDS, as `sgreg replay`;
"offline" runs the same cores in one process on a virtual clock (sgreg_core/bench/offline_replay.py):
deterministic and fast, for choosing thresholds and covering every bag; "ros" measures the nodes
themselves (latency, bandwidth).
"""
from __future__ import annotations

import argparse
import hashlib
import json
import re
import sys
import time
from dataclasses import asdict, fields
from pathlib import Path

NAME = "bench-replay"
HELP = "make and replay a suite of bags; success, wrong verified, time to success"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("suite", help="suite file (YAML), e.g. config/suites/real.yaml")
    p.add_argument("--out", help="output directory (default results/bench_replay_<suite>"
                   "[_seeds<N-M>][_offline])")
    p.add_argument("--backend", choices=["ros", "offline"], default="ros",
                   help="ros: real nodes over DDS; offline: the same cores in one process, faster")
    p.add_argument("--only", nargs="+", metavar="TEXT", help="only bags whose name contains one of these")
    p.add_argument("--weights", help="model weights (.safetensors); default: the shipped model")
    p.add_argument("--params-file", help="ros backend: ROS parameter YAML of the nodes (default "
                   "config/sgreg.yaml; a profile of config/profiles)")
    p.add_argument("--seeds", nargs="+", type=int, metavar="N",
                   help="walk seeds instead of the suite's: new live cases of the same rooms (the "
                   "bags the suite takes as they are are left out), e.g. to check a change on "
                   "walks it was not chosen on")
    p.add_argument("--fresh", action="store_true", help="replay every bag even if a result is cached")
    p.add_argument("--make-only", action="store_true", help="make the bags, replay nothing")
    p.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                   help="offline backend: override an OfflineReplayConfig entry, e.g. "
                   "peers.confirm=false (repeatable)")


def _bag_digest(path: Path) -> str:
    """sha256 over every file of a bag (ground truth, rosbag2 metadata, the messages): a bag
    re-made or re-recorded under the same name is not taken for the one a result was cached
    from (a few seconds over a suite's bags)."""
    h = hashlib.sha256()
    for f in sorted(p for p in Path(path).iterdir() if p.is_file()):
        h.update(f.name.encode())
        with open(f, "rb") as stream:
            for block in iter(lambda: stream.read(1 << 20), b""):
                h.update(block)
    return h.hexdigest()[:16]


def _ensure_bag(job, log) -> dict:
    """Make the job's bag unless one made from the same spec is there; replace one this suite
    made with other settings, never anything else; the ground truth of every bag, checked."""
    import shutil

    from sgreg_core.bench.replay_suite import build_spec
    from sgreg_core.config import from_dict
    from sgreg_core.maps.instance_map import write_instance_map
    from sgreg_core.simulation.synth import SynthConfig, generate_scene
    from ..replay import ground_truth_of
    from .make_bag import BagSpec, BagSpecError, make_bag

    if job.spec is None:
        return ground_truth_of(job.path)
    spec = build_spec(BagSpec, job.spec)
    wanted = json.loads(json.dumps(asdict(spec)))
    if job.path.exists():
        made = _made_with(job.path)
        newer = _changed_since_made(job.path, spec) if made == wanted else None
        if made == wanted and newer is None:
            return ground_truth_of(job.path)
        if newer is not None:
            log(f"replacing {job.name}: {newer} changed after the bag was made")
        elif made is not None:
            changed = sorted(k for k in made.keys() | wanted.keys() if made.get(k) != wanted.get(k))
            log(f"replacing {job.name}: made with other settings ({', '.join(changed)})")
        elif _interrupted(job.path):
            log(f"replacing {job.name}: its making was interrupted (no ground truth yet)")
        else:
            raise BagSpecError(f"{job.path} is in the way: not a bag made by sgreg make-bag (no "
                               "ground_truth.json with its config); move it or choose another bag_dir")
        shutil.rmtree(job.path)
    scene = Path(spec.scan)
    # instances.json is written after the arrays: a folder without it (left by an older run
    # that was interrupted) is made again
    if job.synth is not None and not (scene / "instances.json").exists():
        settings = dict(job.synth)
        seed = int(settings.pop("seed", 0))
        shutil.rmtree(scene, ignore_errors=True)
        # written beside it and renamed when whole: an interrupted run leaves no scene that the
        # next one would take as made
        partial = scene.with_name(scene.name + ".partial")
        shutil.rmtree(partial, ignore_errors=True)
        write_instance_map(generate_scene(seed, from_dict(SynthConfig, settings)), partial)
        partial.rename(scene)
    job.path.parent.mkdir(parents=True, exist_ok=True)
    log(f"making {job.name}")
    make_bag(spec, job.path)
    return ground_truth_of(job.path)


def _interrupted(path: Path) -> bool:
    """Whether path holds what an interrupted make-bag leaves: nothing but rosbag2's own files
    as make-bag writes them, the MCAP named after the folder (make-bag writes the ground truth
    last), so that a run resumes where it stopped. A recording of another name is no such."""
    own = re.compile(rf"{re.escape(path.name)}(_\d+)?\.mcap")
    return path.is_dir() and any(path.iterdir()) and all(
        p.name == "metadata.yaml" or own.fullmatch(p.name) for p in path.iterdir())


def _other_bags_summarised(out: Path, names: set[str]) -> str | None:
    """What out/results.json summarises beyond `names` (a run of more bags), or None."""
    try:
        bags = json.loads((out / "results.json").read_text()).get("bags") or {}
    except (OSError, ValueError, AttributeError, RecursionError):
        return None
    extra = sorted(set(bags) - names)
    return f"{len(bags)} bags, {extra[0]} among them" if extra else None


def _changed_since_made(path: Path, spec) -> str | None:
    """A file of the bag's scans modified after its ground truth was written (a scan regenerated
    in place: the bag, and results cached from it, describe the old one), or None."""
    made = (path / "ground_truth.json").stat().st_mtime_ns
    for scan in (spec.scan, spec.scan_b):
        folder = Path(scan) if scan else None
        if folder is not None and folder.is_dir():
            for f in folder.iterdir():
                if f.is_file() and f.stat().st_mtime_ns > made:
                    return str(f)
    return None


def _made_with(path: Path) -> dict | None:
    """The make-bag config in a bag's ground_truth.json (None: not a bag made by make-bag, so
    not this suite's to replace)."""
    from .make_bag import BagSpec

    try:
        doc = json.loads((path / "ground_truth.json").read_text())
    except (OSError, ValueError, RecursionError):
        return None
    config = doc.get("config") if isinstance(doc, dict) else None
    known = {f.name for f in fields(BagSpec)}
    return config if isinstance(config, dict) and "scan" in config and set(config) <= known else None


def _peers_word(backend: str, offline_cfg: dict, params: bytes):
    """What the run's link rules let the peer's word do (replay_suite.PeersWord, for the bound
    out_of_reach): the offline settings, or the PeersConfig agent a's registration node runs
    with this parameter file (a suite runs every agent on one file). ValueError (one line) when
    a value in the file is not one the node takes."""
    from dataclasses import fields

    from sgreg_core.bench.replay_suite import PeersWord
    from sgreg_core.runtime.peers import PeersConfig
    from ..processes import node_config_of

    names = [f.name for f in fields(PeersWord)]
    peers = offline_cfg["peers"] if backend == "offline" else \
        {k: getattr(node_config_of(PeersConfig, params or None, "a"), k) for k in names}
    return PeersWord(**{k: float(peers[k]) for k in names})


def _offline_config(overrides: list[str]):
    """OfflineReplayConfig from its defaults and --set overrides."""
    from sgreg_core.config import apply_overrides, from_dict, to_dict
    from sgreg_core.bench.offline_replay import OfflineReplayConfig

    return from_dict(OfflineReplayConfig, apply_overrides(to_dict(OfflineReplayConfig()), overrides))


def _replay(job, gt: dict, backend: str, args, model, out_dir: Path, params: bytes) -> dict:
    """The report of one bag, scored against its checked ground truth gt (_ensure_bag); params:
    the parameter file the ROS nodes read (b"": none)."""
    from sgreg_core.bench.merge_score import merge_report
    from sgreg_core.bench.replay_score import score_replay
    from sgreg_core.bench.replay_report import replay_report

    if backend == "offline":
        from ..bags import instance_maps_in_bag

        from sgreg_core.bench.offline_replay import offline_replay

        maps = instance_maps_in_bag(job.path, gt.get("t_origin", 0.0))
        counters: dict = {}
        cfg = _offline_config(args.overrides)
        records = offline_replay(maps, model, cfg, counters=counters)
        score = score_replay(records, gt["T_scene_map"], gt.get("objects"))
        return replay_report(job.path, score, None, {"backend": "offline"},
                             merge=merge_report(records, gt["T_scene_map"], cfg=cfg.merge)[1], counters=counters)
    from ..processes import merge_config_of
    from ..replay import ReplayConfig, run_replay

    # the merge the agents run, read before the replay so that a value they refuse stops it
    merge_cfg = merge_config_of(params or None, min(gt["T_scene_map"]))

    # a short tail: a suite scores registration; `sgreg replay` measures the quiet link
    cfg = ReplayConfig(params_file=args.params_file, tail_s=6.0,
                       overrides={"weights_path": args.weights} if args.weights else {},
                       log_dir=out_dir / "logs" / job.name)
    run_ = run_replay(job.path, cfg, log=lambda s: None)
    score = score_replay(run_.records, gt["T_scene_map"], gt.get("objects"))
    # the final poses scored are those /tf carried, as `sgreg replay` scores them
    tf_poses = run_.merged_poses(merge_cfg.merged_frame)
    merge = merge_report(run_.records, gt["T_scene_map"], tf_poses or None, cfg=merge_cfg)[1]
    merge["published_on_tf"] = bool(tf_poses)
    return replay_report(job.path, score, run_, {"backend": "ros", "params_file": args.params_file,
                                                 "overrides": cfg.overrides}, merge=merge)


def run(args: argparse.Namespace) -> int:
    from sgreg_core.bench.replay_report import foreign_warning
    from sgreg_core.bench.replay_suite import (ResultCache, SuiteError, format_summary, load_suite,
                                               reliability, summarize)
    from sgreg_core.maps.instance_map import InstanceMapError
    from sgreg_core.config import to_dict
    from sgreg_core.paths import make_folder
    from .make_bag import BagSpec, BagSpecError

    try:
        suite = load_suite(args.suite, args.seeds, bag_spec=BagSpec)
    except SuiteError as exc:
        print(f"sgreg bench-replay: {exc}", file=sys.stderr)
        return 2
    if args.overrides and args.backend != "offline":
        print("sgreg bench-replay: --set needs --backend offline (nodes read config/sgreg.yaml; "
              "use --params-file)", file=sys.stderr)
        return 2
    if args.params_file and args.backend == "offline":
        # the offline cores take no node parameters: replaying defaults under a profile's name
        # would report the defaults as the profile's figures
        print("sgreg bench-replay: --params-file needs --backend ros (offline, override settings "
              "with --set; each profile in config/profiles names its --set equivalent)", file=sys.stderr)
        return 2
    try:
        offline_cfg = to_dict(_offline_config(args.overrides))
    except (ValueError, TypeError) as exc:
        print(f"sgreg bench-replay: --set: {exc}", file=sys.stderr)
        return 2
    jobs = [j for j in suite.jobs if not args.only or any(t in j.name for t in args.only)]
    if not jobs:
        print(f"sgreg bench-replay: no bag of {suite.name} matches {args.only}", file=sys.stderr)
        return 2
    seeds = f"_seeds{'-'.join(map(str, args.seeds))}" if args.seeds else ""
    only = "_only-" + "-".join(re.sub(r"[^\w.-]", "_", t) for t in args.only) if args.only else ""
    out = Path(args.out or f"results/bench_replay_{suite.name}{seeds}{only}"
               + ("_offline" if args.backend == "offline" else ""))
    try:
        make_folder(out)
    except OSError as exc:
        print(f"sgreg bench-replay: --out: {exc}", file=sys.stderr)
        return 2
    other = _other_bags_summarised(out, {j.name for j in jobs}) if args.only and not args.make_only else None
    if other:
        print(f"sgreg bench-replay: --out {out} holds the summary of {other} (results.json): --only "
              "would overwrite it with its subset; choose another --out", file=sys.stderr)
        return 2
    from ..processes import merge_config_of, read_params

    # the nodes read the shipped file when given none; the offline backend reads none (a file
    # given is still part of the cache key)
    try:
        params = (read_params(args.params_file) if args.backend == "ros" or args.params_file else None) or b""
        if args.backend == "ros":       # a value the nodes refuse stops the suite before it starts
            merge_config_of(params or None, "a")
        word = _peers_word(args.backend, offline_cfg, params)
    except ValueError as exc:
        print(f"sgreg bench-replay: {exc}", file=sys.stderr)
        return 2

    from sgreg_core.net.model import load_model
    from sgreg_core.paths import source_digest

    # weights that cannot be loaded are said before minutes of making bags, not after
    try:
        model = None if args.make_only else load_model(args.weights)
    except (OSError, RuntimeError, ValueError) as exc:
        print(f"sgreg bench-replay: cannot load weights: {' '.join(str(exc).split())}", file=sys.stderr)
        return 2

    def log(s: str) -> None:
        print(f"[bench-replay] {s}", flush=True)

    log(f"suite {suite.name}: {len(jobs)} bags, backend {args.backend}, output {out}")
    truths = {}
    for i, job in enumerate(jobs):
        try:
            truths[job.name] = _ensure_bag(job, lambda s: log(f"{i + 1}/{len(jobs)} {s}"))
        except (BagSpecError, InstanceMapError, OSError, ValueError) as exc:
            print(f"sgreg bench-replay: bag {job.name}: {exc}", file=sys.stderr)
            return 2
    if args.make_only:
        log(f"{len(jobs)} bags ready under {suite.bag_dir}")
        return 0

    # the model's settings (the .json beside the weights) as well as its tensors: a changed
    # matching setting is another model even where the weights_id stays
    model_config = model.cfg.to_dict()
    context = {"backend": args.backend, "weights_id": model.weights_id,
               "model_config": hashlib.sha256(json.dumps(model_config, sort_keys=True).encode()).hexdigest()[:16],
               # the pipeline's sources: a code change invalidates cached results
               "source": source_digest("sgreg_core", "sgreg_ros", "sgreg_cli"),
               "params": hashlib.sha256(params).hexdigest()[:16], "overrides": args.overrides}
    if args.backend == "offline":
        import torch

        torch.set_num_threads(1)   # as each node runs
        model.text_encoder.encode(["object"])
    from sgreg_core.bench import machine

    host = machine.describe()    # not in the cache key: a bag's result does not depend on it
    before = machine.reference_ms()
    cache = ResultCache(out / "bags")
    results: dict[str, dict] = {}
    started = time.monotonic()
    for i, job in enumerate(jobs):
        key = hashlib.sha256(json.dumps({**context, "spec": job.spec, "bag": str(job.path),
                                         "bag_digest": _bag_digest(job.path)},
                                        sort_keys=True).encode()).hexdigest()[:16]
        cached = None if args.fresh else cache.load(job.name, key)
        if cached is not None:
            results[job.name] = cached
            log(f"{i + 1}/{len(jobs)} {job.name}: cached")
            continue
        t0 = time.monotonic()
        try:
            report = _replay(job, truths[job.name], args.backend, args, model, out, params)
        except (RuntimeError, ValueError) as exc:
            print(f"sgreg bench-replay: bag {job.name}: {exc}", file=sys.stderr)
            return 2
        if report.get("foreign"):
            log(f"{i + 1}/{len(jobs)} {job.name}: WARNING {foreign_warning(report['foreign'])}; not cached")
        cache.save(job.name, report, key)
        results[job.name] = report
        eta = (time.monotonic() - started) / (i + 1) * (len(jobs) - i - 1)
        sr = report["success_rate_registrable"]
        log(f"{i + 1}/{len(jobs)} {job.name}: {report['query_frames']} frames, success over "
            f"registrable {'-' if sr is None else f'{sr:.0%}'}, wrong verified "
            f"{report['wrong_verified']} ({time.monotonic() - t0:.0f} s; about {eta / 60:.0f} min left)")
    summary = summarize(results, suite, word)
    frames = [f for r in results.values() for f in r["frames"]]
    summary["reliability"] = reliability(frames)
    summary["context"] = context
    summary["foreign"] = {n: r["foreign"] for n, r in results.items() if r.get("foreign")}
    # latencies of cached bags are those of the run that made them
    summary["machine"] = host | {"reference_ms": {"before": before, "after": machine.reference_ms()}}
    (out / "results.json").write_text(json.dumps(summary, indent=1, default=float) + "\n")
    (out / "config.json").write_text(json.dumps({
        "suite": str(Path(args.suite).resolve()), "suite_text": Path(args.suite).read_text(),
        "backend": args.backend, "weights": args.weights, "weights_id": model.weights_id,
        "model_config": model_config,
        "params_file": args.params_file, "only": args.only, "seeds": args.seeds,
        "overrides": args.overrides,
        "offline_config": offline_cfg if args.backend == "offline" else None,
        "jobs": [{"name": j.name, "spec": j.spec, "synth": j.synth, "path": str(j.path)} for j in jobs],
    }, indent=1) + "\n")
    print(format_summary(summary))
    print(f"\nconfidence calibration: ECE {summary['reliability']['ece']:.3f} over "
          f"{summary['reliability']['n']} estimates")
    print(machine.summary_line(summary["machine"]))
    from sgreg_core.plots.replay import plot_suite

    plot_suite(summary, out / "summary.png")
    print(f"\nresults: {out / 'results.json'}; plot: {out / 'summary.png'}")
    if summary["foreign"]:
        print(f"sgreg bench-replay: another fleet shared the DDS domain while {', '.join(summary['foreign'])} "
              "played: those results are not to be trusted; run again on a free ROS_DOMAIN_ID "
              "(they are not cached)", file=sys.stderr)
        return 1
    return 0
