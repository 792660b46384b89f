"""A node's diagnostics level (no ROS): OK, WARN for the period an input was refused, ERROR
without a model or without a map for map_timeout_s."""
from sgreg_core.runtime.health import ERROR, OK, WARN, Health, HealthConfig


def test_levels():
    h = Health(HealthConfig(map_timeout_s=10.0), started_at=0.0)
    assert h.status(1.0, refused=0, last_map_at=None)[0] == OK          # starting, within the timeout
    level, message = h.status(11.0, refused=0, last_map_at=None)
    assert level == ERROR and "no instance map yet" in message
    assert h.status(12.0, refused=0, last_map_at=11.5)[0] == OK
    level, message = h.status(13.0, refused=2, last_map_at=12.5)
    assert level == WARN and message.startswith("2 input(s) refused")
    assert h.status(14.0, refused=2, last_map_at=13.5)[0] == OK         # no new refusal: OK again
    level, message = h.status(30.0, refused=2, last_map_at=13.5)
    assert level == ERROR and "no new instance map for 16 s" in message
    assert h.status(31.0, refused=2, last_map_at=30.5, problem="no model: x") == (ERROR, "no model: x")
