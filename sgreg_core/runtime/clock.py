"""The clock an agent's intervals run on (request intervals and timeouts, quiet_after_s,
peer_timeout_s, the diagnostics' map timeout), and map stamps as integer nanoseconds.

A node feeds it its ROS time on every reading. Under use_sim_time that is the bag's /clock, so
a bag played at another rate, or paused, keeps the link's timing as recorded: a paused bag must
not expire its peers nor time out their requests. Without sim time it is the steady clock (the
system clock can jump). Either way it never goes back: a bag played again restarts its clock,
and intervals measured across that would freeze until the new run caught up with the old one.
A jump forward (a later bag, a seek) is time that passed: peers silent across it are forgotten.

Map stamps travel as integer ns, so that a result carries its map's header stamp exactly
(float seconds of today's epoch resolve 240 ns).

Public API:
    RunClock.read(sim_active, ros_ns, steady_s) -> seconds since the clock started
    stamp_ns(value) -> int   a map stamp, refused (TypeError) unless integer nanoseconds
    seconds_to_ns(t) -> int  a moment in seconds (a virtual clock, a bag's offset) as a stamp
"""
from __future__ import annotations

import numpy as np


def stamp_ns(value) -> int:
    """`value` as a stamp in ns; TypeError for anything but an integer (seconds given as a
    float would stamp every result in 1970)."""
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        raise TypeError(f"map stamps are integer nanoseconds, got {value!r}")
    return int(value)


def seconds_to_ns(t: float) -> int:
    """t seconds as integer ns, to the nearest (only times small enough for float seconds to
    hold ns: offsets and virtual clocks, not today's epoch)."""
    return int(round(t * 1e9))


class RunClock:
    """Seconds that advance with the source of the moment (ROS time while sim time is active,
    else the steady clock), counting only forward steps. ROS time 0 means no /clock yet (rclpy
    reads 0 until the first message): it holds the clock, and the first real reading only
    sets where counting starts, so the jump from 0 to the bag's epoch is not a 50-year wait."""

    def __init__(self) -> None:
        self.seconds = 0.0
        self._source: bool | None = None     # sim_active at the last reading
        self._last = None                    # the source's reading then (ns, or s when steady)

    def read(self, sim_active: bool, ros_ns: int, steady_s: float) -> float:
        t = (int(ros_ns) if ros_ns > 0 else None) if sim_active else steady_s
        if sim_active != self._source:       # a new source: its first reading is a base only
            self._source, self._last = sim_active, None
        if t is not None:
            if self._last is not None and t > self._last:
                step = t - self._last        # ns differences stay exact
                self.seconds += step * 1e-9 if sim_active else step
            self._last = t
        return self.seconds
