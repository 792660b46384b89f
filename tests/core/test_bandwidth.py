"""The bandwidth meter behind `sgreg bw` and the replay's traffic figures (bench/bandwidth.py)."""
from sgreg_core.bench.bandwidth import BandwidthMeter


def test_a_live_window_counts_only_its_own_messages_and_a_quiet_topic_reads_zero():
    meter = BandwidthMeter(window_s=2.0)
    for t in (0.0, 0.5, 1.0, 1.5):
        meter.add("/a/sgreg/coarse", t, 1000)
    (row,) = meter.report(now=1.5)
    assert row.messages == 4 and row.bytes_per_s == 2000.0 and row.total_bytes == 4000
    (row,) = meter.report(now=3.1)        # only the message at 1.5 s is still in the window
    assert row.messages == 1 and row.bytes_per_s == 500.0
    (row,) = meter.report(now=10.0)       # the topic went quiet: 0, its total kept
    assert row.messages == 0 and row.bytes_per_s == 0.0 and row.total_bytes == 4000


def test_a_bag_is_reported_over_its_own_span():
    meter = BandwidthMeter()
    for t in (0.0, 1.0, 2.0):
        meter.add("/b/sgreg/dense", t, 300)
    (row,) = meter.report()
    assert row.messages == 3 and row.bytes_per_s == 450.0 and (row.min_bytes, row.max_bytes) == (300, 300)


def test_a_topic_watched_for_less_than_a_window_divides_by_the_time_watched():
    """`ros2 topic bw` divides by the time its samples span, not by a window not yet full:
    10 messages of 1000 B in the first second of a 10 s window are 10 kB/s, not 1 kB/s."""
    meter = BandwidthMeter(window_s=10.0)
    meter.watch("/a/sgreg/coarse", 100.0)
    for i in range(10):
        meter.add("/a/sgreg/coarse", 100.05 + 0.1 * i, 1000)
    (row,) = meter.report(now=101.0)
    assert row.bytes_per_s == 10_000.0
    (row,) = meter.report(now=115.0)     # a full window on: the window again (and it is empty)
    assert row.messages == 0 and row.bytes_per_s == 0.0


def test_no_rate_where_no_time_has_passed():
    meter = BandwidthMeter()
    meter.add("/b/sgreg/dense", 5.0, 300)
    (row,) = meter.report()              # one message of a bag: no span
    assert row.bytes_per_s is None and row.as_row()[2] == "-"
    (row,) = meter.report(span=0.0)
    assert row.bytes_per_s is None
