"""A node's health for its diagnostics: OK, WARN while inputs are being refused, ERROR while the
node cannot do its job (no model, or no instance map from its own front end for a while).
Levels are the byte values of diagnostic_msgs/DiagnosticStatus."""
from __future__ import annotations

from dataclasses import dataclass

from ..config import param

OK, WARN, ERROR = 0, 1, 2


@dataclass
class HealthConfig:
    """map_timeout_s: without an instance map for this long (since start, or since the last
    one) the node reports ERROR: its front end is silent, so its registrations go stale."""

    map_timeout_s: float = param(30.0, "diagnostics say ERROR after this long without an instance map",
                                 1.0, 3600.0, live=True)


class Health:
    """Feed `status` once per diagnostics period with the node's totals; it compares them with
    the previous call, so a refusal shows as WARN for one period after it happened."""

    def __init__(self, cfg: HealthConfig, started_at: float):
        self.cfg = cfg
        self.started_at = started_at
        self._refused = 0

    def status(self, now: float, refused: int, last_map_at: float | None,
               problem: str | None = None) -> tuple[int, str]:
        """(level, one-line message). refused: inputs refused so far; last_map_at: when the
        front end was last heard from, a map taken or one too small to use yet (None: never);
        problem: why the node cannot work at all."""
        new_refusals, self._refused = refused - self._refused, refused
        if problem:
            return ERROR, problem
        silent = now - (self.started_at if last_map_at is None else last_map_at)
        if silent > self.cfg.map_timeout_s:
            what = "no instance map yet" if last_map_at is None else "no new instance map"
            return ERROR, f"{what} for {silent:.0f} s (map_timeout_s={self.cfg.map_timeout_s:g})"
        if new_refusals > 0:
            return WARN, f"{new_refusals} input(s) refused in the last period (see the counters)"
        return OK, ""
