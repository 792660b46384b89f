"""What changed between two `sgreg bench-replay` runs of one suite (`sgreg bench-diff`).

A change of settings, weights or code is judged bag by bag: the suite's total can stay level
while one bag gains what another loses, and one wrong verified frame anywhere breaks the rule
of issue 11. Totals are taken over the bags both runs replayed, so a run of `--only` some bags
compares with the same bags of a full run.

Public API:
    load_run(folder) -> dict                 a bench-replay output folder's results.json
    compare(before, after) -> Comparison     two such results
    BagOutcome, Comparison
"""
from __future__ import annotations

import json
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

# context entries that say what was run: a difference in one of them is what is compared
CONTEXT_KEYS = ("backend", "weights_id", "model_config", "source", "params", "overrides")


@dataclass(frozen=True)
class BagOutcome:
    """verified: registrable frames verified (and right); wrong: wrong verified frames (any);
    merged_wrong_s: seconds the merged frame (/tf) held a wrong link or misplaced an agent."""

    verified: int
    registrable: int
    wrong: int
    merged_wrong_s: float = 0.0

    @property
    def broke_rule(self) -> bool:
        """Something wrong was published as good: a verified frame, or the merged frame."""
        return self.wrong > 0 or self.merged_wrong_s > 0


@dataclass
class Comparison:
    """changed: bag -> (before, after) for the bags both ran whose outcome differs; only_before /
    only_after: bags one run has and the other lacks (left out of the totals); totals: the sums
    over the bags both ran; missed: (category, reason) -> registrable frames not verified;
    context: what was run (CONTEXT_KEYS) where the two differ -> (before, after); within_reach:
    the registrable frames the link rules could reach with each run's estimates, over the bags
    both ran (replay_suite.out_of_reach; None for a run that does not report it); new_wrong: the
    bags that published something wrong (BagOutcome.broke_rule) and did not before."""

    common: int
    changed: dict[str, tuple[BagOutcome, BagOutcome]]
    only_before: list[str]
    only_after: list[str]
    totals: tuple[BagOutcome, BagOutcome]
    bags_with_wrong: tuple[int, int]     # bags that broke the rule (BagOutcome.broke_rule)
    missed: tuple[Counter, Counter]
    context: dict[str, tuple] = field(default_factory=dict)
    within_reach: tuple[int | None, int | None] = (None, None)

    @property
    def new_wrong(self) -> list[str]:
        """Bags that broke the rule after and did not before."""
        return [name for name, (b, a) in self.changed.items() if a.broke_rule and not b.broke_rule]


def load_run(folder: str | Path) -> dict:
    """results.json of a bench-replay output folder (or the file itself); ValueError naming what
    is missing."""
    path = Path(folder)
    if path.is_dir():
        path = path / "results.json"
    if not path.is_file():
        raise ValueError(f"{folder}: no bench-replay results.json there")
    try:
        run = json.loads(path.read_text())
    except (OSError, ValueError) as exc:
        raise ValueError(f"{path}: not readable JSON ({exc})") from None
    if not isinstance(run, dict) or not isinstance(run.get("bags"), dict):
        raise ValueError(f"{path}: not a bench-replay result (no per-bag summaries)")
    return run


def _outcome(row: dict) -> BagOutcome:
    registrable = int(row.get("registrable_frames") or 0)
    rate = row.get("success_rate_registrable")
    verified = int(round((rate or 0.0) * registrable))
    return BagOutcome(verified, registrable, int(row.get("wrong_verified") or 0),
                      float(row.get("merged_wrong_s") or 0.0))


def _missed(rows: list[dict]) -> Counter:
    out: Counter = Counter()
    for row in rows:
        for category, reasons in (row.get("missed") or {}).items():
            for reason, n in reasons.items():
                out[(category, reason)] += n
    return out


def _within_reach(rows: list[dict]) -> int | None:
    if any(row.get("out_of_reach") is None for row in rows):
        return None
    return sum(int(row.get("registrable_frames") or 0) - int(row["out_of_reach"]) for row in rows)


def _sum(outcomes: list[BagOutcome]) -> BagOutcome:
    return BagOutcome(sum(o.verified for o in outcomes), sum(o.registrable for o in outcomes),
                      sum(o.wrong for o in outcomes), sum(o.merged_wrong_s for o in outcomes))


def compare(before: dict, after: dict) -> Comparison:
    if before.get("suite") != after.get("suite"):
        raise ValueError(f"runs of two suites ({before.get('suite')!r}, {after.get('suite')!r}): "
                         "nothing to compare bag by bag")
    b_bags, a_bags = before["bags"], after["bags"]
    common = sorted(set(b_bags) & set(a_bags))
    if not common:
        raise ValueError("the two runs share no bag")
    pairs = {name: (_outcome(b_bags[name]), _outcome(a_bags[name])) for name in common}
    b_ctx, a_ctx = before.get("context") or {}, after.get("context") or {}
    return Comparison(
        common=len(common),
        changed={name: pair for name, pair in pairs.items() if pair[0] != pair[1]},
        only_before=sorted(set(b_bags) - set(a_bags)),
        only_after=sorted(set(a_bags) - set(b_bags)),
        totals=(_sum([p[0] for p in pairs.values()]), _sum([p[1] for p in pairs.values()])),
        bags_with_wrong=(sum(p[0].broke_rule for p in pairs.values()),
                         sum(p[1].broke_rule for p in pairs.values())),
        missed=(_missed([b_bags[n] for n in common]), _missed([a_bags[n] for n in common])),
        context={k: (b_ctx.get(k), a_ctx.get(k)) for k in CONTEXT_KEYS if b_ctx.get(k) != a_ctx.get(k)},
        within_reach=(_within_reach([b_bags[n] for n in common]), _within_reach([a_bags[n] for n in common])))
