"""Benchmarks that compare sgreg with its peers on the same pairs (`sgreg bench-register`).

Modules: cases (the registration pairs with ground truth), register_bench (runs every method
on every case and scores it), report (summaries, tables, the recall chart)."""
