"""Benchmarks: sgreg against its peers on the same pairs (`sgreg bench-register`) and live
two-agent replays (`sgreg replay`, `sgreg bench-replay`).

Modules: cases (the registration pairs with ground truth), baselines (the peer methods),
register_bench (runs every method on every case and scores it), register_report (summaries,
tables, the recall chart); replay_score (scores one replay against its ground truth),
replay_suite (suite files and the bags they make), offline_replay (the nodes' cores on a
virtual clock), replay_report (suite tables and plots), bandwidth (traffic per topic)."""
