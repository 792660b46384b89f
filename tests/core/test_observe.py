"""Incremental observation along a trajectory."""
import numpy as np
import pytest

from sgreg_core.simulation.observe import SensorConfig, first_seen, make_trajectory, observe_sequence, reverse_trajectory
from sgreg_core.simulation.synth import SynthConfig, generate_scene
from sgreg_core.types import InstanceMap


def test_first_seen_range_and_fov():
    pts = np.array([[2, 0, 1], [5, 0, 1], [0, 2, 1], [-2, 0, 1], [1.5, 1.4, 0]], dtype=np.float32)
    m = InstanceMap(points=pts, instance=np.ones(5, np.int32), labels={1: "x"})
    t = first_seen(m, np.array([0.0, 1.0]), np.array([[0, 0, 0], [0, 0, np.pi / 2]]), SensorConfig())
    # ahead -> 0; too far -> never; left -> once turned; behind -> never; at 43 deg -> 0
    np.testing.assert_array_equal(t, [0.0, np.inf, 1.0, np.inf, 0.0])
    T = np.tile(np.eye(4), (2, 1, 1))
    T[1, :2, :2] = [[0, -1], [1, 0]]
    np.testing.assert_array_equal(first_seen(m, np.array([0.0, 1.0]), T), t)


@pytest.fixture(scope="module")
def scene():
    return generate_scene(2, SynthConfig(rooms=2))


def test_trajectory_and_growing_maps(scene):
    rng = np.random.default_rng(0)
    times, poses = make_trajectory(scene, rng)
    assert len(times) > 10 and np.all(np.diff(times) > 0)
    step = np.linalg.norm(np.diff(poses[:, :2], axis=0), axis=1)
    assert step.max() < 0.2                              # 0.5 m/s at 5 Hz
    lo, hi = scene.points[:, :2].min(0), scene.points[:, :2].max(0)
    assert np.all(poses[:, :2] > lo) and np.all(poses[:, :2] < hi)
    seq = observe_sequence(scene, times, poses)
    assert len(seq) == int(np.ceil(times[-1]))
    sizes = [len(m.points) for _, m in seq]
    assert sizes == sorted(sizes) and sizes[0] < sizes[-1] <= len(scene.points)
    counts = [len(m.labels) for _, m in seq]
    assert counts[0] < counts[-1]
    # an instance first appears partially, then grows
    last = seq[-1][1]
    first_ids = set(seq[0][1].labels)
    grew = [k for k in first_ids if (seq[0][1].instance == k).sum() < (last.instance == k).sum()]
    assert grew


def test_reverse_trajectory(scene):
    times, poses = make_trajectory(scene, np.random.default_rng(1))
    rt, rp = reverse_trajectory(times, poses)
    np.testing.assert_allclose(rp[0, :2], poses[-1, :2])
    np.testing.assert_allclose(np.cos(rp[0, 2]), -np.cos(poses[-1, 2]), atol=1e-9)
    a, b = first_seen(scene, times, poses), first_seen(scene, rt, rp)
    assert not np.array_equal(a, b)


def test_trajectory_seeded(scene):
    a = make_trajectory(scene, np.random.default_rng(5))[1]
    b = make_trajectory(scene, np.random.default_rng(5))[1]
    np.testing.assert_array_equal(a, b)


def test_a_start_off_the_walkable_floor_is_refused_not_moved():
    """Two rooms split by a wall with one closed door: walks keep to the larger room, and a
    start asked for in the other is refused with the nearest walkable point, not quietly
    moved there."""
    from sgreg_core.simulation.observe import TrajectoryConfig, walkable_share

    rng = np.random.default_rng(0)
    floor = np.c_[rng.uniform(0, 8, 40000), rng.uniform(0, 4, 40000), np.zeros(40000)]
    z = np.linspace(0.0, 2.0, 21)
    wall_y = np.linspace(0, 4, 81)
    wall = np.array([(5.0, y, h) for y in wall_y for h in z])        # x = 5: the closed door too
    outer = np.array([(x, y, h) for x in np.linspace(0, 8, 161) for y in (0.0, 4.0) for h in z]
                     + [(x, y, h) for x in (0.0, 8.0) for y in wall_y for h in z])
    pts = np.vstack([floor, wall, outer]).astype(np.float32)
    m = InstanceMap(points=pts, instance=np.ones(len(pts), np.int32), labels={1: "x"})
    cfg = TrajectoryConfig(clearance=0.15)
    assert 0.55 < walkable_share(m, cfg) < 0.7          # the 5 m room of 5 + 3 m
    times, poses = make_trajectory(m, rng, TrajectoryConfig(clearance=0.15, start=(2.0, 2.0)))
    assert np.all(poses[:, 0] < 5.0)
    with pytest.raises(ValueError, match=r"start \(6.5, 2\) lies 1\.\d m from the walkable floor.*nearest walkable point is \(4\.\d\d, "):
        make_trajectory(m, rng, TrajectoryConfig(clearance=0.15, start=(6.5, 2.0)))
    with pytest.raises(ValueError, match="waypoints must be at least 2"):
        make_trajectory(m, rng, TrajectoryConfig(waypoints=1))
