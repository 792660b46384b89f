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
