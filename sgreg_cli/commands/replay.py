"""sgreg replay BAG [--json OUT] [--png OUT]: replay a bag of two or more agents through real nodes
(separate processes over DDS) and score every published estimate, and the merged frame the
agents publish on /tf, against the bag's ground truth. --png also draws the merged map
(<png>_merged.png: every agent's map, top-down, placed by its merged pose)."""
from __future__ import annotations

import json
import os
import sys
import tempfile
import time
from pathlib import Path

NAME = "replay"
HELP = "replay a multi-agent bag through real nodes and score every estimate and the merged map"


def add_arguments(p):
    p.add_argument("bag", help="rosbag2 directory made by sgreg make-bag (with ground_truth.json)")
    p.add_argument("--json", help="write the report here (default: the report is only printed)")
    p.add_argument("--png", help="plot success, RTE and bandwidth over time (and the merged map "
                                 "beside it, *_merged.png)")
    p.add_argument("--rate", type=float, default=1.0, help="playback speed")
    p.add_argument("--tail", type=float, metavar="SECONDS",
                   help="keep the nodes running this long after the bag ends (default: long enough "
                        "to measure the link's traffic once the maps are static; a short tail "
                        "leaves that unmeasured)")
    p.add_argument("--weights", help="model weights (.safetensors); default: the shipped model")
    p.add_argument("--params-file", help="ROS parameter YAML for the nodes (default: config/sgreg.yaml)")
    p.add_argument("--log-dir", help="node logs (default: next to the JSON; without --json, a new "
                                     "temporary folder, named at the end)")
    p.add_argument("--restart", metavar="AGENT@SECONDS",
                   help="kill that agent's nodes that long into the replay and restart them")


def _fmt_T(T) -> str:
    return "\n".join("  [" + "  ".join(f"{v:8.3f}" for v in row) + "]" for row in T)


def _time_to_success(links: dict) -> str:
    """Per link registrable by ground truth: the seconds to its first success, or never."""
    parts = [f"{name} " + ("never" if link["time_to_success_s"] is None else f"{link['time_to_success_s']:.1f} s")
             for name, link in sorted(links.items()) if link.get("registrable_since_bag_s") is not None]
    return ", ".join(parts) or "-"


def run(args) -> int:

    from ..bags import BagError
    from ..processes import merge_config_of, read_params
    from ..replay import ReplayConfig, ground_truth_of, run_replay

    from sgreg_core.bench.bandwidth import HEADER, format_table
    from sgreg_core.bench.merge_score import merge_report
    from sgreg_core.bench.replay_report import (PAPER_KB_PER_FRAME, PAPER_SUCCESS_RATE, foreign_warning,
                                                replay_report)
    from sgreg_core.bench.replay_score import ground_truth, score_replay
    from sgreg_core.metrics import rre, rte
    from sgreg_core.paths import make_folder, output_file, weights_files
    from sgreg_core.plots import figure_path

    out_json = Path(args.json) if args.json else None
    try:
        # what would fail only once the bag has been replayed, or leave the nodes unready
        if out_json is not None:
            output_file(out_json)
        if args.png:
            figure_path(args.png)
        if args.weights:
            weights_files(args.weights)
        if args.log_dir:
            make_folder(args.log_dir)
        gt = ground_truth_of(args.bag)
        # the merge the agents run, read before the replay: a value they refuse stops it here
        merge_cfg = merge_config_of(read_params(args.params_file), min(gt["T_scene_map"]))
    except (BagError, OSError, ValueError) as exc:
        print(f"sgreg replay: {exc}", file=sys.stderr)
        return 2
    restart = None
    if args.restart:
        agent, _, when = args.restart.partition("@")
        try:
            restart = (agent, float(when))
        except ValueError:
            print(f"sgreg replay: --restart wants AGENT@SECONDS, got {args.restart!r}", file=sys.stderr)
            return 2
    if args.log_dir:
        log_dir = Path(args.log_dir)
    elif out_json is not None:
        log_dir = out_json.parent / (out_json.stem + "_logs")
    else:    # made only when the nodes start (processes.start_agents), so a refusal leaves none
        log_dir = Path(tempfile.gettempdir()) / f"sgreg_replay_logs_{time.strftime('%Y%m%d-%H%M%S')}_{os.getpid()}"
    cfg = ReplayConfig(rate=args.rate, restart=restart, params_file=args.params_file,
                       overrides={"weights_path": args.weights} if args.weights else {},
                       log_dir=log_dir)
    if args.tail is not None:
        cfg.tail_s = args.tail
    from rclpy.executors import ExternalShutdownException
    try:
        run_ = run_replay(args.bag, cfg, log=lambda s: print(f"[replay] {s}", flush=True))
    except ExternalShutdownException:     # SIGTERM: rclpy's handler shut the context down
        print("sgreg replay: stopped (SIGTERM); the nodes were stopped, nothing was scored", file=sys.stderr)
        return 143
    except (BagError, RuntimeError, ValueError) as exc:
        where = f" (node logs: {cfg.log_dir})" if cfg.log_dir.is_dir() else ""
        print(f"sgreg replay: {exc}{where}", file=sys.stderr)
        return 2
    score = score_replay(run_.records, gt["T_scene_map"], gt.get("objects"))
    tf_poses = run_.merged_poses(merge_cfg.merged_frame)
    merged, merge = merge_report(run_.records, gt["T_scene_map"], tf_poses or None, cfg=merge_cfg)
    merge["published_on_tf"] = bool(tf_poses)
    report = replay_report(args.bag, score, run_, {"rate": cfg.rate, "tail_s": cfg.tail_s,
                                                   "params_file": cfg.params_file,
                                                   "overrides": cfg.overrides,
                                                   "restart": args.restart}, settle_s=cfg.settle_s,
                           merge=merge)
    kb_per_frame = report["kb_per_query_frame"]
    if out_json is not None:
        out_json.write_text(json.dumps(report, indent=1, default=float) + "\n")

    print()
    print(format_table(HEADER, [b.as_row() for b in run_.bandwidth]))
    print()
    rows = [
        ["query frames", str(score.query_frames)],
        ["success rate (verified, RTE<0.5 m, RRE<5 deg)", f"{score.success_rate:.1%}  (paper: {PAPER_SUCCESS_RATE:.1%}, other data)"],
        ["success rate (any estimate)", f"{score.success_rate_any:.1%}"],
        ["success rate over registrable frames", f"{score.success_rate_registrable:.1%} of {score.registrable_frames}"
         if score.success_rate_registrable is not None else "-"],
        ["verified estimates / wrong verified", f"{score.verified} / {score.wrong_verified}"],
        ["registrable frames not verified", _missed(report["frames"])],
        ["first success", f"{score.first_success_s:.1f} s" if score.first_success_s is not None else "never"],
        ["time from registrable (ground truth) to first success", _time_to_success(score.links)],
        ["kB per query frame", f"{kb_per_frame:.1f}  (paper: {PAPER_KB_PER_FRAME:.0f})" if kb_per_frame is not None else "-"],
        ["coarse latency median / p90", _lat(score.coarse_latency_ms)],
        ["dense latency median / p90", _lat(score.dense_latency_ms)],
    ] + [[f"merged frame ({merged.anchor}'s map)",
          f"{merge['attached']} of {merge['agents']} agents attached, {merge['wrong_links_kept']} wrong links "
          f"kept, {merge['links_rejected']} rejected, wrong for "
          f"{merge['while_replayed']['wrong_s']:.0f} s of the replay; max pose error " +
          (f"{merge['max_pose_error_m']:.3f} m / {merge['max_pose_error_deg']:.2f} deg"
           if merge["max_pose_error_m"] is not None else "-")]
    ] + [[f"link during the bag, agent {a}", f"{b / 1e3:.2f} kB/s"]
         for a, b in report["during_bag"]["bytes_per_s"].items()
    ] + [[f"link after the bag, agent {a}", f"{b / 1e3:.2f} kB/s (static maps, {report['after_bag']['window_s']:.0f} s)"]
         for a, b in report["after_bag"]["bytes_per_s"].items()
         ] + [[f"node {k}", f"CPU {v['cpu_share']:.0%}, peak {v['peak_rss_mb']:.0f} MB"] for k, v in run_.processes.items()]
    if run_.corrupted:
        rows.append(["corrupted bag messages skipped", str(len(run_.corrupted))])
    refused = {a: c for a, c in report["refused_from_fleet"].items() if c}
    if refused:
        # another fleet's messages are refused too: a bug only when no other fleet was there
        rows.append(["messages refused by the nodes" + ("" if report["foreign"] else " (a bug: see the node logs)"),
                     "; ".join(f"{a}: {c}" for a, c in sorted(refused.items()))])
    if report["foreign"]:
        print(f"sgreg replay: WARNING {foreign_warning(report['foreign'])}", file=sys.stderr)
    print(format_table(["replay", "value"], rows))
    last = {}
    for r in run_.records:
        if r.verified:
            last[(r.agent, r.peer)] = r
    for (agent, peer), r in sorted(last.items()):
        T_gt = ground_truth(gt["T_scene_map"], agent, peer)
        print(f"\nlast verified T_{agent}^{peer} ({r.mode}, t={r.t:.1f} s):\n{_fmt_T(r.T)}")
        print(f"ground truth:\n{_fmt_T(T_gt)}")
        print(f"RTE {rte(r.T, T_gt):.3f} m, RRE {rre(r.T, T_gt):.2f} deg")
    if not last:
        print("\nno verified estimate was published")
    if out_json is not None:
        print(f"\nreport: {out_json}")
    else:
        print(f"\nnode logs: {cfg.log_dir} (--json FILE keeps the report)")
    if args.png:
        from sgreg_core.plots.merged import plot_merged_map
        from sgreg_core.plots.replay import plot_replay

        from ..bags import final_maps

        plot_replay(score, run_.timeline, args.png, title=f"replay of {Path(args.bag).name}")
        merged_png = str(Path(args.png).with_name(Path(args.png).stem + "_merged.png"))
        plot_merged_map(final_maps(args.bag, gt), tf_poses or merged.poses, merged_png,
                        title=f"merged map of {Path(args.bag).name} ({merge_cfg.merged_frame}: {merged.anchor}/map)",
                        note=(f"max pose error {merge['max_pose_error_m']:.2f} m / "
                              f"{merge['max_pose_error_deg']:.1f} deg against the ground truth"
                              if merge["max_pose_error_m"] is not None else ""))
        print(f"plot: {args.png}, {merged_png}")
    return 0


def _missed(frames: list[dict]) -> str:
    """Why registrable frames were not verified (replay_suite.missed), in one table cell."""
    from sgreg_core.bench.replay_suite import MISSED_LABELS, missed

    n = {cause: sum(reasons.values()) for cause, reasons in missed(frames).items()}
    return "; ".join(f"{label}: {n[cause]}" for cause, label in MISSED_LABELS.items())


def _lat(d: dict) -> str:
    if not d.get("n"):
        return "-"
    return f"{d['median']:.0f} / {d['p90']:.0f} ms (n={d['n']})"
