"""The replay picture (like the paper's Fig. 12): per query frame success, RTE, and the traffic
between agents over time."""
from __future__ import annotations

import numpy as np


def plot_replay(score, timeline, out_path, title: str = "") -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(3, 1, figsize=(9, 8), sharex=True)
    frames = score.frames
    agents = sorted({(f.agent, f.peer) for f in frames})
    for agent, peer in agents:
        fs = [f for f in frames if (f.agent, f.peer) == (agent, peer)]
        t = np.array([f.t for f in fs])
        ok = np.array([f.verified and f.success for f in fs])
        axes[0].scatter(t, np.full(t.size, f"{agent}->{peer}"), c=np.where(ok, "tab:green", "tab:red"),
                        marker="s", s=18)
        rte = np.array([f.rte if f.verified else np.nan for f in fs])
        axes[1].plot(t, rte, "o-", ms=3, label=f"T_{agent}^{peer} (verified)")
    axes[0].set_ylabel("success")
    axes[0].set_title(title + f"  (success rate {score.success_rate:.0%}, wrong verified {score.wrong_verified})")
    axes[1].axhline(0.5, color="gray", ls="--", lw=1)
    axes[1].set_yscale("symlog", linthresh=0.1)
    axes[1].set_ylabel("RTE [m]")
    axes[1].legend(fontsize=8)
    if timeline:
        tl = np.array([(t, b) for t, _, b in timeline])
        bins = np.arange(0, tl[:, 0].max() + 1.0, 1.0)
        for kind in ("coarse", "dense", "dense_request"):
            sel = np.array([topic.endswith("/" + kind) for _, topic, _ in timeline])
            if sel.any():
                h, _ = np.histogram(tl[sel, 0], bins=bins, weights=tl[sel, 1] / 1e3)
                axes[2].step(bins[:-1], h, where="post", label=kind)
        axes[2].legend(fontsize=8)
    axes[2].set_ylabel("kB per second")
    axes[2].set_xlabel("time since the bag started [s]")
    fig.tight_layout()
    fig.savefig(out_path, dpi=110)
    plt.close(fig)


def plot_suite(summary: dict, out_path) -> None:
    """A replay suite at a glance: per bag, its registrable frames by outcome (verified and
    right, then the ones not verified by cause: replay_suite.missed, then wrong verified) with
    the share the link rules could reach with the bag's estimates (replay_suite.out_of_reach), the
    reliability of the stated confidence, and time to first success per bag."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    bags = summary["bags"]
    names = list(bags)
    fig, axes = plt.subplots(1, 3, figsize=(16, max(4.5, 0.17 * len(names) + 1.5)),
                             gridspec_kw={"width_ratios": [2.2, 1.3, 1.3]})
    y = np.arange(len(names))
    from ..bench.replay_suite import MISSED_LABELS

    # shares of each bag's registrable frames, left to right: what trust cost is next to success
    causes = ("right_held", "right_refused", "wrong_estimate")
    parts = [("verified, right", "tab:green"),
             *zip((MISSED_LABELS[c] for c in causes), ("yellowgreen", "orange", "lightgray")),
             ("wrong, verified", "tab:red")]
    counts = np.zeros((len(names), len(parts)))
    for i, n in enumerate(names):
        b, miss = bags[n], bags[n].get("missed") or {}
        reg = b["registrable_frames"]
        ok = round((b["success_rate_registrable"] or 0.0) * reg)
        not_verified = [sum(miss.get(c, {}).values()) for c in causes]
        counts[i] = ok, *not_verified, max(reg - ok - sum(not_verified), 0)
    shares = 100 * counts / np.maximum(counts.sum(axis=1, keepdims=True), 1)
    left = np.zeros(len(names))
    for k, (label, color) in enumerate(parts):
        axes[0].barh(y, shares[:, k], left=left, color=color, label=label)
        left += shares[:, k]
    reach = [(i, 100 * (1 - bags[n]["out_of_reach"] / bags[n]["registrable_frames"]))
             for i, n in enumerate(names) if bags[n].get("out_of_reach") is not None and bags[n]["registrable_frames"]]
    if reach:
        axes[0].scatter([x for _, x in reach], [y[i] for i, _ in reach], marker="|", s=60, color="black",
                        zorder=3, clip_on=False, label="within reach of the link rules")
    wrong = np.array([bags[n]["wrong_verified"] for n in names])
    for i in np.flatnonzero(wrong):
        axes[0].text(2, y[i], f"{wrong[i]} wrong verified", va="center", fontsize=7, color="white")
    # a bag whose maps never share 3 objects has nothing to register: no bar, and no "never"
    registrable = np.array([bags[n]["registrable_frames"] or 0 for n in names])
    for i in np.flatnonzero(registrable == 0):
        axes[0].text(1, y[i], "no registrable frame", va="center", fontsize=6)
    axes[0].legend(loc="lower center", bbox_to_anchor=(0.5, 1.0), ncol=3, fontsize=7, frameon=False)
    axes[0].set_yticks(y, names, fontsize=6)
    axes[0].invert_yaxis()
    axes[0].axvline(85, color="gray", ls="--", lw=1)
    axes[0].set_xlim(0, 100)
    axes[0].set_xlabel("registrable frames [%]")
    overall = summary["rows"]["all"]
    reg = overall["registrable_frames"]
    bound = "" if overall.get("out_of_reach") is None or not reg else \
        f" ({reg - overall['out_of_reach']} within reach of the link rules)"
    axes[0].set_title(f"suite {summary['suite']}: {100 * (overall['success_rate_registrable'] or 0):.1f} % "
                      f"of {reg} frames{bound}, {overall['wrong_verified']} wrong verified",
                      fontsize=9, pad=30)

    rel = summary.get("reliability")
    if rel:
        pts = [(b["confidence"], b["correct"], b["n"]) for b in rel["bins"] if b["n"]]
        if pts:
            c, o, n = (np.array(v, np.float64) for v in zip(*pts))
            axes[1].scatter(c, o, s=10 + 60 * n / n.max(), color="tab:blue", zorder=3)
            axes[1].plot(c, o, color="tab:blue", lw=1)
        axes[1].plot([0, 1], [0, 1], color="gray", ls="--", lw=1)
        axes[1].set_xlim(0, 1)
        axes[1].set_ylim(0, 1)
        axes[1].set_xlabel("stated confidence")
        axes[1].set_ylabel("observed share of correct estimates")
        axes[1].set_title(f"reliability (ECE {rel['ece']:.3f}, {rel['n']} estimates)", fontsize=9)

    t = np.array([np.nan if bags[n]["median_time_to_success_s"] is None
                  else bags[n]["median_time_to_success_s"] for n in names])
    axes[2].barh(y, np.nan_to_num(t), color="tab:purple")
    for i in np.flatnonzero(~np.isfinite(t) & (registrable > 0)):
        axes[2].text(0.1, y[i], "never", va="center", fontsize=6)
    axes[2].set_yticks(y, [])
    axes[2].invert_yaxis()
    axes[2].axvline(5, color="gray", ls="--", lw=1)
    axes[2].set_xlabel("time from registrable (ground truth) to first success [s]")
    fig.tight_layout()
    fig.savefig(out_path, dpi=110)
    plt.close(fig)
