"""Per-topic bandwidth statistics, as `ros2 topic bw` reports them: mean bytes per second over a
window and message size mean / min / max. Fed with (time, size) samples from live topics or a
bag; knows nothing of ROS."""
from __future__ import annotations

from collections import defaultdict, deque
from dataclasses import dataclass


@dataclass
class TopicBandwidth:
    """bytes_per_s: None where no time has passed to divide by (one message in a bag)."""

    topic: str
    messages: int
    bytes_per_s: float | None
    mean_bytes: float
    min_bytes: int
    max_bytes: int
    total_bytes: int

    def as_row(self) -> list[str]:
        rate = "-" if self.bytes_per_s is None else human_bytes(self.bytes_per_s) + "/s"
        return [self.topic, str(self.messages), rate,
                human_bytes(self.mean_bytes), human_bytes(self.min_bytes),
                human_bytes(self.max_bytes), human_bytes(self.total_bytes)]


HEADER = ["topic", "msgs", "mean rate", "mean size", "min", "max", "total"]


def human_bytes(n: float) -> str:
    for unit, scale in (("MB", 1e6), ("kB", 1e3)):
        if n >= scale:
            return f"{n / scale:.2f} {unit}"
    return f"{n:.0f} B"


def per_agent_rate(timeline, start: float, end: float) -> dict[str, float]:
    """Bytes per second each agent sent between start and end, from (t, "/<agent>/...", bytes)
    samples: the link an agent keeps busy, whatever the topic."""
    span = max(end - start, 1e-9)
    out: dict[str, float] = {}
    for t, topic, size in timeline:
        agent = topic.split("/")[1]
        out[agent] = out.get(agent, 0.0) + (size / span if start <= t <= end else 0.0)
    return dict(sorted(out.items()))


class BandwidthMeter:
    """window_s: samples older than this are forgotten (None: keep all, for bags and totals)."""

    def __init__(self, window_s: float | None = None):
        self.window_s = window_s
        self.samples: dict[str, deque] = defaultdict(deque)
        self.totals: dict[str, int] = defaultdict(int)
        self.counts: dict[str, int] = defaultdict(int)
        self.since: dict[str, float] = {}     # topic -> when it was first watched (live)

    def watch(self, topic: str, t: float) -> None:
        """The topic is listened to from t on: until a whole window has passed, its rate divides
        by the time since then, not by the window (which would read low at first)."""
        self.since.setdefault(topic, t)

    def add(self, topic: str, t: float, size: int) -> None:
        q = self.samples[topic]
        q.append((t, size))
        self.totals[topic] += size
        self.counts[topic] += 1
        self._forget_before(q, t)

    def _forget_before(self, q: deque, now: float) -> None:
        """Drop the samples of `q` that the window, ending at `now`, has left behind."""
        if self.window_s is not None:
            while q and q[0][0] < now - self.window_s:
                q.popleft()

    def report(self, now: float | None = None, span: float | None = None) -> list[TopicBandwidth]:
        """One row per topic. The rate divides the window's bytes by `span` (seconds) if given,
        else by the window length (live; the time since the topic was watched while that is
        shorter) or the time between first and last sample (bags); no rate (None) where that
        time is 0. Live (`now` and a window), samples older than the window are dropped first:
        a topic that went quiet reads 0 once its last message has left the window."""
        rows = []
        for topic in sorted(self.samples):
            q = self.samples[topic]
            if now is not None:
                self._forget_before(q, now)
            if not q:
                if self.totals[topic]:
                    rows.append(TopicBandwidth(topic, 0, 0.0, 0.0, 0, 0, self.totals[topic]))
                continue
            sizes = [s for _, s in q]
            if span is not None:
                duration = span
            elif self.window_s is None:
                duration = q[-1][0] - q[0][0]
            elif now is not None and topic in self.since:
                duration = min(self.window_s, now - self.since[topic])
            else:
                duration = self.window_s
            rate = sum(sizes) / duration if duration > 0 else None
            rows.append(TopicBandwidth(topic, len(sizes), rate, sum(sizes) / len(sizes),
                                       min(sizes), max(sizes), self.totals[topic]))
        return rows


def format_table(header: list[str], rows: list[list[str]]) -> str:
    """A plain text table with aligned columns."""
    widths = [max(len(str(r[i])) for r in [header] + rows) for i in range(len(header))]
    lines = ["  ".join(str(c).ljust(w) for c, w in zip(header, widths))]
    lines.append("  ".join("-" * w for w in widths))
    lines += ["  ".join(str(c).ljust(w) for c, w in zip(r, widths)) for r in rows]
    return "\n".join(lines)
