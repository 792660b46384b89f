"""The clock an agent's intervals run on (request intervals and timeouts, quiet_after_s,
peer_timeout_s, the diagnostics' map timeout).

A node feeds it its ROS time on every reading. Under use_sim_time that is the bag's /clock, so
a bag played at another rate, or paused, keeps the link's timing as recorded: a paused bag must
not expire its peers nor time out their requests. Without sim time it is the steady clock (the
system clock can jump). Either way it never goes back: a bag played again restarts its clock,
and intervals measured across that would freeze until the new run caught up with the old one.

Public API:
    RunClock.read(sim_active, ros_ns, steady_s) -> seconds since the clock started
"""
from __future__ import annotations


class RunClock:
    """Seconds that advance with the source of the moment (ROS time while sim time is active,
    else the steady clock), counting only forward steps. ROS time 0 means no /clock yet (rclpy
    reads 0 until the first message): it holds the clock, and the first real reading only
    sets where counting starts, so the jump from 0 to the bag's epoch is not a 50-year wait."""

    def __init__(self) -> None:
        self.seconds = 0.0
        self._source: bool | None = None     # sim_active at the last reading
        self._last: float | None = None      # the source's reading then

    def read(self, sim_active: bool, ros_ns: int, steady_s: float) -> float:
        t = (ros_ns * 1e-9 if ros_ns > 0 else None) if sim_active else steady_s
        if sim_active != self._source:       # a new source: its first reading is a base only
            self._source, self._last = sim_active, None
        if t is not None:
            if self._last is not None:
                self.seconds += max(0.0, t - self._last)
            self._last = t
        return self.seconds
