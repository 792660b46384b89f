"""The clock the runtime's intervals run on (runtime/clock.py): the bag's clock under sim time,
the steady clock otherwise, never going back."""
from sgreg_core.runtime.clock import RunClock

S = 1_000_000_000   # ns per second
EPOCH = 1_700_000_000 * S


def test_sim_time_advances_with_the_bag_and_holds_while_it_is_paused():
    c = RunClock()
    assert c.read(True, 0, 5.0) == 0.0                 # no /clock yet
    assert c.read(True, EPOCH, 6.0) == 0.0             # the first reading is where counting starts
    assert c.read(True, EPOCH + 2 * S, 7.0) == 2.0     # 2 s of bag in 1 s of wall: rate 2
    assert c.read(True, EPOCH + 2 * S, 60.0) == 2.0    # paused for a minute
    assert c.read(True, EPOCH + 3 * S, 61.0) == 3.0


def test_a_bag_played_again_does_not_turn_the_clock_back():
    c = RunClock()
    c.read(True, EPOCH, 0.0)
    c.read(True, EPOCH + 10 * S, 10.0)
    assert c.read(True, EPOCH, 11.0) == 10.0           # the bag starts over
    assert c.read(True, EPOCH + S, 12.0) == 11.0       # and counts on from there


def test_without_sim_time_it_is_the_steady_clock_and_a_switch_is_seamless():
    c = RunClock()
    assert c.read(False, EPOCH, 100.0) == 0.0
    assert c.read(False, 0, 103.5) == 3.5              # ROS time is not read
    assert c.read(True, EPOCH, 104.0) == 3.5           # use_sim_time set: a base, no jump
    assert c.read(True, EPOCH + S, 104.0) == 4.5
    assert c.read(False, 0, 500.0) == 4.5              # and back: a base again
    assert c.read(False, 0, 501.0) == 5.5
