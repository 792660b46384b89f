"""Synthetic scene generator: deterministic, realistic statistics, fast, noise hook."""
import time
from collections import Counter

import numpy as np
import pytest

from sgreg_core.maps.instance_map import validate_instance_map
from sgreg_core.simulation.noise import NoiseConfig
from sgreg_core.maps.scene_graph import build_scene_graph
from sgreg_core.simulation.synth import KINDS, SynthConfig, generate_scene


def test_deterministic_from_seed():
    a, b, c = generate_scene(3), generate_scene(3), generate_scene(4)
    np.testing.assert_array_equal(a.points, b.points)
    np.testing.assert_array_equal(a.instance, b.instance)
    assert a.labels == b.labels
    assert len(a.points) != len(c.points) or not np.array_equal(a.points, c.points)


@pytest.mark.parametrize("kind, rooms", [("apartment", 1), ("apartment", 3), ("office", 2)])
def test_scene_statistics(kind, rooms):
    t0 = time.perf_counter()
    m = generate_scene(rooms * 7 + len(kind), SynthConfig(kind=kind, rooms=rooms))
    assert time.perf_counter() - t0 < 4.0
    m = validate_instance_map(m)
    assert m.colors is not None and m.colors.shape == (len(m.points), 3)
    labels = Counter(m.labels.values())
    assert labels["floor"] == rooms and labels["wall"] >= 4 * rooms
    assert 15 * rooms <= len(m.labels) <= 120 * rooms
    ext = m.points.max(0) - m.points.min(0)
    assert 2.3 < ext[2] < 3.2 and ext[:2].min() > 2.5
    # ScanNet-like density: 40k-200k points a room
    assert 30_000 * rooms < len(m.points) < 250_000 * rooms
    # repeated identical objects exist (chairs, monitors, ...): same label and extents, apart
    g = build_scene_graph(m)
    obj = np.flatnonzero(~g.structural)
    same = [(i, j) for i in obj for j in obj if i < j and g.labels[i] == g.labels[j]
            and np.abs(g.extents[i] - g.extents[j]).max() < 0.04 and np.linalg.norm(g.centers[i] - g.centers[j]) > 0.3]
    assert len(same) >= 1


def test_vocabulary_and_shapes_beyond_boxes():
    assert len(KINDS) >= 40
    rng = np.random.default_rng(0)
    chair = KINDS["chair"].builder(0.45, 0.5, 0.9, rng)
    assert len(chair.rects) > 20          # legs, seat, back
    assert KINDS["plant"].builder(0.5, 0.5, 1.0, rng).ells and KINDS["lamp"].builder(0.3, 0.3, 0.5, rng).cyls


def test_floor_and_wall_hidden_behind_solid_furniture():
    from sgreg_core.simulation.synth.scene import _hide_occluded
    pts = np.array([[0.0, 0.0, 0.0], [0.9, 0.0, 0.0], [0.0, 0.55, 1.0], [0.0, 0.55, 2.5], [0.1, 0.1, 0.5]])
    tags = np.array([0, 0, 1, 1, 2])
    structural = np.array([True, True, False])
    # a 1.0 x 1.0 x 2.0 cabinet at the origin rotated by 90 deg: the object's own point stays
    keep = _hide_occluded(pts, tags, structural, [(0.0, 0.0, np.pi / 2, 1.0, 1.0, 2.0)])
    assert keep.tolist() == [False, True, True, True, True]
    keep = _hide_occluded(pts, np.array([0, 0, 0, 0, 2]), structural, [(0.0, 0.0, 0.0, 1.0, 1.1, 2.0)])
    assert keep.tolist() == [False, True, False, True, True]


def test_noise_applied():
    clean = generate_scene(5)
    noisy = generate_scene(5, SynthConfig(noise=NoiseConfig(overseg=1.0)))
    assert len(noisy.labels) > 1.5 * len(clean.labels)


def test_bad_config():
    with pytest.raises(ValueError):
        generate_scene(0, SynthConfig(kind="castle"))
    with pytest.raises(ValueError):
        generate_scene(0, SynthConfig(rooms=0))
    # `sgreg synth --rooms 100000` would fill the memory for minutes before any message
    from sgreg_core.simulation.synth.scene import MAX_ROOMS
    with pytest.raises(ValueError, match=rf"rooms must lie in \[1, {MAX_ROOMS}\]"):
        generate_scene(0, SynthConfig(kind="building", rooms=MAX_ROOMS + 1))


def test_a_building_floor_has_runs_of_identical_rooms():
    from sgreg_core.maps.scene_graph import build_scene_graph
    from sgreg_core.simulation.synth.layout import building

    # the layout: a corridor, then rooms in runs of three that share one template
    rooms, templates = building(14, np.random.default_rng(5), run=3)
    assert len(rooms) == 15 and rooms[0].rtype == "corridor" and templates[0] == -1
    assert templates[1:4] == [templates[1]] * 3 and templates[4] != templates[1]
    # generate_scene draws that layout first from the same seed
    scene = generate_scene(5, SynthConfig(kind="building", rooms=14))
    graph = build_scene_graph(scene)
    assert graph.num_nodes >= 300 and int((~graph.structural).sum()) >= 250

    def content(room):
        inside = ((graph.centers[:, 0] > room.x0) & (graph.centers[:, 0] < room.x1)
                  & (graph.centers[:, 1] > room.y0) & (graph.centers[:, 1] < room.y1) & ~graph.structural)
        offsets = graph.centers[inside, :2] - [room.x0, room.y0]
        order = np.lexsort((offsets[:, 1], offsets[:, 0], np.array(graph.labels)[inside]))
        return np.array(graph.labels)[inside][order], offsets[order]

    (la, oa), (lb, ob), (lc, oc) = content(rooms[1]), content(rooms[2]), content(rooms[4])
    assert len(la) >= 5 and list(la) == list(lb), "rooms of one run hold other objects"
    assert np.abs(oa - ob).max() < 0.15, "rooms of one run hold them elsewhere"      # point sampling only
    assert list(la) != list(lc) or np.abs(oa - oc).max() > 0.5, "rooms of other runs are copies too"


def test_an_office_of_more_rooms_than_room_types():
    # six office room types: the seventh room and on start the list over, by size
    scene = generate_scene(0, SynthConfig(kind="office", rooms=8, density=60.0))
    assert Counter(scene.labels.values())["floor"] == 8
