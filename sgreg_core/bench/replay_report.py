"""The JSON report of one replay (`sgreg replay`, `sgreg bench-replay`): the score of every frame,
registrability and links (bench/replay_score.py), the agents' counters and, for a replay through
real nodes, traffic, node load, played messages and any sign of another fleet on the domain.
The SG-Reg paper's two-agent figures are carried beside ours for scale (other data).
"""
from __future__ import annotations

from .bandwidth import per_agent_rate

PAPER_SUCCESS_RATE = 0.324   # SG-Reg T-RO 2025, two-agent success rate (different data)
PAPER_KB_PER_FRAME = 52.0
# refusals of the fleet's own messages that an honest replay never earns (a corrupted bag
# message is the agent's own input, counted elsewhere): any of them means a bug
FLEET_REFUSALS = ("unsigned", "bad_signature", "unknown_key", "key_not_agents", "stale_message",
                  "replayed", "agent_mismatch", "rejected_weights", "bad_feature_size", "bad_nodes",
                  "bad_level", "invalid_values", "bad_points")


def foreign_warning(foreign: dict) -> str:
    """What a replay says when another fleet shared its ROS_DOMAIN_ID (ReplayRun.foreign)."""
    seen = ", ".join(f"{n} {why}" for why, n in sorted(foreign.items()))
    return (f"another fleet shares this ROS_DOMAIN_ID ({seen}): its results were left out of the "
            "score, but its maps may have reached these nodes; replay again on a free ROS_DOMAIN_ID")


def replay_report(bag, score, run_=None, config: dict | None = None, settle_s: float = 22.0,
                  merge: dict | None = None, counters: dict | None = None) -> dict:
    """The JSON report of one replay: the score (every frame, registrability, links), the merged
    frame (bench/merge_score.py), each agent's counters (refusals, requests, confirmations: run_'s
    from real nodes, else `counters` from the offline replay) and, from a replay through real
    nodes (run_), traffic (per agent, during the bag and once the maps are static), node load,
    played messages and any sign of another fleet on the same DDS domain."""
    counters = run_.counters if run_ is not None else (counters or {})
    report = {
        "bag": str(bag),
        "query_frames": score.query_frames,
        "success_rate": score.success_rate,
        "success_rate_any": score.success_rate_any,
        "paper_success_rate": PAPER_SUCCESS_RATE,
        "registrable_frames": score.registrable_frames,
        "success_rate_registrable": score.success_rate_registrable,
        "wrong_verified": score.wrong_verified,
        "verified": score.verified,
        "first_success_s": score.first_success_s,
        "links": score.links,
        "median_rte_verified_m": score.median_rte_verified,
        "median_rre_verified_deg": score.median_rre_verified,
        "kb_per_query_frame": None,
        "paper_kb_per_query_frame": PAPER_KB_PER_FRAME,
        "coarse_latency_ms": score.coarse_latency_ms,
        "dense_latency_ms": score.dense_latency_ms,
        "merge": merge,
        "counters": counters,
        "config": config or {},
        "frames": score.to_dict()["frames"],
    }
    if run_ is not None:
        cross_bytes = sum(run_.bytes_per_topic.values())
        quiet = (run_.bag_end_s + settle_s, run_.duration_s)
        report.update({
            "kb_per_query_frame": cross_bytes / 1e3 / score.query_frames if score.query_frames else None,
            "bytes_per_topic": run_.bytes_per_topic,
            "bandwidth": [vars(b) for b in run_.bandwidth],
            "nodes": run_.processes,
            "messages_played": run_.played,
            "corrupted_messages": [{"topic": t, "index": i, "error": e} for t, i, e in run_.corrupted],
            "duration_s": run_.duration_s,
            "events": [{"t": t, "what": w} for t, w in run_.events],
            "refused_from_fleet": {a: {k: v for k, v in c.items() if k in FLEET_REFUSALS and v}
                                   for a, c in counters.items()},
            # another fleet on the domain: results left out, other publishers of the maps
            "foreign": run_.foreign,
            # the link once the maps stopped changing (after the bag and settle_s more)
            "after_bag": {"window_s": max(quiet[1] - quiet[0], 0.0),
                          "bytes_per_s": per_agent_rate(run_.timeline, *quiet) if quiet[1] > quiet[0] else {}},
            # what each agent sends on its sgreg topics while the maps grow
            "during_bag": {"window_s": run_.bag_end_s,
                           "bytes_per_s": per_agent_rate(run_.timeline, 0.0, run_.bag_end_s)
                           if run_.bag_end_s > 0 else {}},
        })
    return report
