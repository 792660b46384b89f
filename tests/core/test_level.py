"""Levelling (maps/level.py): each map's gravity from its own surfaces, and the pipeline's
registration of tilted maps back in their own frames."""
import numpy as np
import pytest

from sgreg_core.geometry import invert_transform, transform_points
from sgreg_core.maps.level import LevelConfig, estimate_level, level_map, rotation_between
from sgreg_core.simulation.noise import tilt_rotation
from sgreg_core.simulation.synth import SynthConfig, generate_scene


def angle(a, b) -> float:
    return float(np.degrees(np.arccos(np.clip(np.dot(a, b), -1.0, 1.0))))


@pytest.fixture(scope="module")
def scene():
    return generate_scene(4, SynthConfig(rooms=2))


@pytest.mark.parametrize("deg,axis", [(0.7, 10.0), (2.0, 130.0), (6.0, 250.0)])
def test_gravity_of_a_tilted_map_is_found(scene, deg, axis):
    T = tilt_rotation(deg, axis)
    lev = estimate_level(scene.transformed(T).points)
    true_up = T[:3, :3] @ [0.0, 0.0, 1.0]
    assert lev.ok and angle(lev.up, true_up) < 0.15
    assert abs(lev.tilt_deg - deg) < 0.15
    # the levelled map is upright again: its up is z
    assert angle(lev.R @ true_up, [0.0, 0.0, 1.0]) < 0.15


def test_level_map_levels_and_says_so(scene):
    imap, lev = level_map(scene.transformed(tilt_rotation(1.5, 40.0)))
    assert lev.ok and abs(lev.tilt_deg - 1.5) < 0.15
    assert abs(estimate_level(imap.points).tilt_deg) < 0.15
    same, off = level_map(scene, LevelConfig(enabled=False))
    assert same is scene and off.reason == "disabled" and np.allclose(off.R, np.eye(3))


def test_what_cannot_be_levelled_is_left_as_it_is(scene):
    few = estimate_level(scene.points[:50])
    assert not few.ok and "too few points" in few.reason and np.allclose(few.R, np.eye(3))
    steep = estimate_level(scene.transformed(tilt_rotation(30.0, 0.0)).points,
                           LevelConfig(max_tilt_deg=20.0))
    assert not steep.ok and np.allclose(steep.R, np.eye(3)) and "max_tilt_deg" in steep.reason
    # a map of one tilted plane only (no walls, no floor) gives no gravity it cannot support
    rng = np.random.default_rng(0)
    junk = rng.uniform(-3, 3, (5000, 3))
    assert not estimate_level(junk).ok


def test_points_that_are_not_points_are_refused_with_the_reason():
    for bad in (np.zeros((100, 2)), np.zeros(3), np.zeros((10, 4))):
        lev = estimate_level(bad)
        assert not lev.ok and "shape (N, 3)" in lev.reason and np.allclose(lev.R, np.eye(3))


@pytest.mark.parametrize("bad", [{"cones_deg": ()}, {"cones_deg": (35.0, 0.0)}, {"voxel": 0.0},
                                 {"neighbours": 2}, {"max_planarity": 0.5},
                                 {"min_tilt_deg": 3.0, "max_tilt_deg": 2.0},
                                 {"min_points": 9000}])
def test_level_config_refuses_what_would_report_any_map_level(bad):
    """With no cone at all, up stayed z and every map was reported level, however tilted."""
    with pytest.raises(ValueError, match="level"):
        LevelConfig(**bad)


def test_rotation_between():
    rng = np.random.default_rng(1)
    for _ in range(5):
        a, b = rng.normal(size=3), rng.normal(size=3)
        a, b = a / np.linalg.norm(a), b / np.linalg.norm(b)
        R = rotation_between(a, b)
        assert np.allclose(R @ a, b, atol=1e-9) and np.isclose(np.linalg.det(R), 1.0)
    z = np.array([0.0, 0.0, 1.0])
    assert np.allclose(rotation_between(z, -z) @ z, -z)


def test_register_tilted_maps_gives_a_full_pose_between_the_maps(scene):
    """Two views, each tilted its own way: the pipeline levels both, registers them upright,
    and returns the 6-DoF T between the maps as given, with the tilts in its JSON."""
    from sgreg_core.net.model import load_model
    from sgreg_core.pipeline import PipelineConfig, build_graphs, register_graphs
    from sgreg_core.simulation.pairs import PairConfig, make_pair

    pair = make_pair(scene, PairConfig(overlap=0.7), np.random.default_rng(3))
    S, R = tilt_rotation(1.8, 20.0), tilt_rotation(1.2, 200.0)
    src, ref = pair.src.transformed(S), pair.ref.transformed(R)
    T_gt = R @ pair.T_src_ref @ invert_transform(S)
    cfg, timings = PipelineConfig(), {}
    reg = register_graphs(load_model(), *build_graphs(src, ref, cfg, timings), cfg, timings)
    assert reg.success, reg.reason
    pts = src.points[::10].astype(np.float64)
    err = np.linalg.norm(transform_points(reg.T, pts) - transform_points(T_gt, pts), axis=1)
    assert np.sqrt(np.mean(err ** 2)) < 0.05
    out = reg.to_json()
    assert abs(out["tilt_deg"]["src"] - 1.8) < 0.2 and abs(out["tilt_deg"]["ref"] - 1.2) < 0.2
    # the pose between the levelled frames is 4-DoF up to the levelling error
    assert angle(reg.T_levelled[:3, :3] @ [0, 0, 1.0], [0, 0, 1.0]) < 0.3
    assert "level" in reg.timing_ms
