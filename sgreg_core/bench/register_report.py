"""Summaries, printed tables and the recall chart of `sgreg bench-register`.

Public API:
    summarize(rows) -> {group: {method: stats}}
        group = setting, with "_seen" appended for rooms seen in training
        stats: n, recall (RMSE < max_rmse), verified_recall (claimed and right),
        claimed_rate, false_claims, errors, median RTE / RRE of successes, median / p90 wall
        time, median CPU time; sgreg rows add node recall / precision, inlier ratios, the
        share of ICP-refined poses, median stage times and the count of each failure reason
    format_tables(summary) -> str
    plot_recall(summary, out_path) -> None      PNG: verified recall bars with RMSE-recall ticks,
                                                false claims (matplotlib Agg, imported when called)
"""
from __future__ import annotations

from collections import Counter
from pathlib import Path

import numpy as np

from ..pipeline import TIMING_STAGES

SGREG_MEANS = ("node_recall", "node_precision", "inlier_ratio", "pseudo_inlier_ratio",
               "node_matches", "correspondences", "inliers", "refined")
NO_SOLUTION = "different_rooms"


def _finite(values) -> np.ndarray:
    a = np.asarray(list(values), dtype=np.float64)
    return a[np.isfinite(a)]


def _median(values) -> float:
    a = _finite(values)
    return float(np.median(a)) if a.size else float("nan")


def _stats(rows: list[dict]) -> dict:
    ok = [r for r in rows if r["success"]]
    times = _finite(r["time_ms"] for r in rows)
    out = {
        "n": len(rows),
        "recall": float(np.mean([r["success"] for r in rows])),
        # what a user can act on: claimed and right
        "verified_recall": float(np.mean([r["claimed"] and r["success"] for r in rows])),
        "claimed_rate": float(np.mean([r["claimed"] for r in rows])),
        "false_claims": int(sum(r["false_claim"] for r in rows)),
        "errors": int(sum("error" in r for r in rows)),
        "median_rte_m": _median(r["rte"] for r in ok),
        "median_rre_deg": _median(r["rre"] for r in ok),
        "time_ms_median": float(np.median(times)) if times.size else float("nan"),
        "time_ms_p90": float(np.percentile(times, 90)) if times.size else float("nan"),
        "cpu_ms_median": _median(r["cpu_ms"] for r in rows),
    }
    if any("reason" in r for r in rows):  # sgreg rows (error rows lack it)
        for key in SGREG_MEANS:
            a = _finite(r.get(key, np.nan) for r in rows)
            out[key] = float(a.mean()) if a.size else float("nan")
        found = {k[3:] for r in rows for k in r if k.startswith("ms_")}
        stages = [k for k in TIMING_STAGES if k in found] + sorted(found - set(TIMING_STAGES))
        out["stage_ms_median"] = {k: _median(r.get(f"ms_{k}", np.nan) for r in rows)
                                  for k in stages}
        out["reasons"] = dict(Counter(r.get("reason", "error") for r in rows))
    return out


def summarize(rows: list[dict]) -> dict:
    groups: dict = {}
    for r in rows:
        groups.setdefault(r["group"], {}).setdefault(r["method"], []).append(r)
    return {g: {m: _stats(rs) for m, rs in by_method.items()} for g, by_method in groups.items()}


def _fmt(v, spec: str) -> str:
    return "-" if v is None or (isinstance(v, float) and not np.isfinite(v)) else format(v, spec)


def format_tables(summary: dict) -> str:
    lines = []
    head = (f"{'method':<14}{'n':>4}{'recall':>8}{'verified':>9}{'claimed':>9}{'false':>7}"
            f"{'RTE m':>8}"
            f"{'RRE deg':>9}{'t med ms':>10}{'t p90 ms':>10}{'cpu med':>9}")
    for group, by_method in summary.items():
        title = group.replace("_seen", " (rooms seen in training)")
        if group.startswith(NO_SOLUTION):
            title += ": no right answer, every claimed success is false"
        lines += ["", f"== {title}", head, "-" * len(head)]
        for m, s in by_method.items():
            lines.append(f"{m:<14}{s['n']:>4}{_fmt(100 * s['recall'], '.1f'):>8}"
                         f"{_fmt(100 * s['verified_recall'], '.1f'):>9}"
                         f"{_fmt(100 * s['claimed_rate'], '.1f'):>9}{s['false_claims']:>7}"
                         f"{_fmt(s['median_rte_m'], '.3f'):>8}{_fmt(s['median_rre_deg'], '.2f'):>9}"
                         f"{_fmt(s['time_ms_median'], '.0f'):>10}"
                         f"{_fmt(s['time_ms_p90'], '.0f'):>10}"
                         f"{_fmt(s['cpu_ms_median'], '.0f'):>9}"
                         + (f"  ({s['errors']} errors)" if s["errors"] else ""))
    sg = [(g, m, s) for g, bm in summary.items() for m, s in bm.items() if "reasons" in s]
    if sg:
        head = (f"{'setting':<18}{'method':<14}{'node R':>7}{'node P':>7}{'inlier':>7}"
                f"{'pseudo':>7}{'matches':>8}{'corr':>6}  median stage ms")
        lines += ["", "== sgreg matching (means) and stage times (medians)", head, "-" * len(head)]
        for g, m, s in sg:
            stages = " ".join(f"{k} {v:.1f}" for k, v in s["stage_ms_median"].items()
                              if np.isfinite(v))
            lines.append(f"{g:<18}{m:<14}{_fmt(s['node_recall'], '.3f'):>7}"
                         f"{_fmt(s['node_precision'], '.3f'):>7}{_fmt(s['inlier_ratio'], '.3f'):>7}"
                         f"{_fmt(s['pseudo_inlier_ratio'], '.3f'):>7}"
                         f"{_fmt(s['node_matches'], '.1f'):>8}"
                         f"{_fmt(s['correspondences'], '.0f'):>6}"
                         f"  {stages}")
        lines.append("reasons: " + "; ".join(f"{g}/{m}: " + ", ".join(
            f"{k} x{v}" for k, v in s["reasons"].items()) for g, m, s in sg))
    return "\n".join(lines)


def plot_recall(summary: dict, out_path: str | Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    groups = list(summary)
    methods = list(dict.fromkeys(m for g in groups for m in summary[g]))
    fig, (ax_r, ax_f) = plt.subplots(1, 2, figsize=(13, 4.8), dpi=110,
                                     gridspec_kw={"width_ratios": [3, 2]})
    width = 0.8 / max(1, len(methods))
    solvable = [g for g in groups if not g.startswith(NO_SOLUTION)]
    panels = ((ax_r, solvable, "verified_recall",
               "recall %: bars claimed and right, ticks right (RMSE)"),
              (ax_f, groups, "false_claims", "false claims (count)"))
    for ax, keys, value, label in panels:
        x = np.arange(len(keys))
        for k, m in enumerate(methods):
            stats = [summary[g].get(m, {}) for g in keys]
            pos = x + (k - (len(methods) - 1) / 2) * width
            if value == "verified_recall":
                ax.bar(pos, [100 * s.get(value, np.nan) for s in stats], width, label=m)
                ax.scatter(pos, [100 * s.get("recall", np.nan) for s in stats], marker="_",
                           s=120, c="black", zorder=3)
            else:
                ax.bar(pos, [s.get(value, np.nan) for s in stats], width, label=m)
        ax.set_xticks(x, [g.replace("_", "\n") for g in keys], fontsize=8)
        ax.set_ylabel(label, fontsize=9)
        ax.grid(axis="y", alpha=0.3)
    ax_r.set_ylim(0, 105)
    handles, labels = ax_r.get_legend_handles_labels()
    fig.legend(handles, labels, loc="upper center", ncol=len(methods), fontsize=8)
    fig.tight_layout(rect=(0, 0, 1, 0.93))
    Path(out_path).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out_path)
    plt.close(fig)
