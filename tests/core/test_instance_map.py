"""Instance map directory I/O: round trip and one clear error per kind of malformed input."""
import json

import numpy as np
import pytest

from sgreg_core.maps.instance_map import (InstanceMapError, labelled_mask, read_instance_map, select_points,
                                     write_instance_map)
from sgreg_core.types import InstanceMap


def _map(n=100, seed=0):
    rng = np.random.default_rng(seed)
    inst = rng.integers(0, 4, n).astype(np.int32)
    return InstanceMap(points=rng.normal(size=(n, 3)).astype(np.float32), instance=inst,
                       labels={1: "chair", 2: "table", 3: "wall"}, scores={1: 0.5, 2: 1.0, 3: 0.9},
                       colors=rng.integers(0, 255, (n, 3)).astype(np.uint8))


def test_round_trip(tmp_path):
    m = _map()
    write_instance_map(m, tmp_path / "m")
    r = read_instance_map(tmp_path / "m")
    assert r.points.dtype == np.float32 and r.instance.dtype == np.int32
    np.testing.assert_array_equal(r.points, m.points)
    np.testing.assert_array_equal(r.instance, m.instance)
    np.testing.assert_array_equal(r.colors, m.colors)
    assert r.labels == m.labels and r.scores == m.scores


def test_colors_and_score_optional(tmp_path):
    m = _map()
    m.colors = None
    write_instance_map(m, tmp_path / "m")
    entries = json.loads((tmp_path / "m/instances.json").read_text())
    (tmp_path / "m/instances.json").write_text(json.dumps([{"id": e["id"], "label": e["label"]} for e in entries]))
    r = read_instance_map(tmp_path / "m")
    assert r.colors is None and r.scores == {1: 1.0, 2: 1.0, 3: 1.0}


def test_ids_missing_from_json_are_unlabelled(tmp_path):
    m = _map()
    m.labels = {1: "chair"}
    write_instance_map(m, tmp_path / "m")
    r = read_instance_map(tmp_path / "m")
    np.testing.assert_array_equal(labelled_mask(r), m.instance == 1)


def _corrupt(tmp_path, fn):
    write_instance_map(_map(), tmp_path / "m")
    fn(tmp_path / "m")
    with pytest.raises(InstanceMapError) as err:
        read_instance_map(tmp_path / "m")
    msg = str(err.value)
    assert "\n" not in msg and str(tmp_path / "m") in msg
    return msg


def _as_npz(path):
    """An .npz archive under an .npy name (np.load opens it whatever it is called)."""
    with open(path, "wb") as f:
        np.savez(f, np.zeros((100, 3), np.float32))


@pytest.mark.parametrize("fn, needle", [
    (lambda d: (d / "points.npy").unlink(), "points.npy: missing file"),
    (lambda d: (d / "instances.json").unlink(), "instances.json: missing file"),
    (lambda d: np.save(d / "points.npy", np.zeros((100, 3), np.int32)), "dtype int32"),
    (lambda d: np.save(d / "points.npy", np.zeros((100, 2), np.float32)), "shape"),
    (lambda d: np.save(d / "instance.npy", np.zeros(99, np.int32)), "instance.npy"),
    (lambda d: np.save(d / "instance.npy", np.zeros(100, np.float32)), "dtype float32"),
    (lambda d: np.save(d / "colors.npy", np.zeros((100, 3), np.float32)), "colors.npy"),
    (lambda d: (d / "instances.json").write_text("[{"), "malformed JSON"),
    (lambda d: (d / "instances.json").write_text('{"id": 1}'), "expected a list"),
    (lambda d: (d / "instances.json").write_text('[{"id": "a", "label": "x"}]'), "non-integer id"),
    (lambda d: (d / "instances.json").write_text('[{"id": 1, "label": ""}]'), "label"),
    (lambda d: (d / "instances.json").write_text('[{"id": 1, "label": "a"}, {"id": 1, "label": "b"}]'), "twice"),
    (lambda d: (d / "instances.json").write_text('[{"id": 9, "label": "a"}]'), "no labelled point"),
    (lambda d: np.save(d / "points.npy", np.zeros((0, 3), np.float32)), "instance.npy"),
    (lambda d: (d / "points.npy").write_bytes(b"garbage"), "not a readable"),
    (lambda d: _as_npz(d / "points.npy"), "an .npz archive"),
    (lambda d: (d / "instances.json").write_text('[{"id": 9223372036854775808, "label": "a"}]'), "beyond int32"),
    (lambda d: (d / "instances.json").write_text('[{"id": 1, "label": "a", "score": 1' + "0" * 400 + '}]'),
     "non-numeric score"),
    (lambda d: (d / "instances.json").write_text("[" * 100000 + "]" * 100000), "nested too deep"),
])
def test_malformed_inputs(tmp_path, fn, needle):
    assert needle in _corrupt(tmp_path, fn)


def test_nan_points_and_empty_map(tmp_path):
    def nan(d):
        p = np.load(d / "points.npy")
        p[3, 1] = np.nan
        p[5, 0] = np.inf
        np.save(d / "points.npy", p)
    assert "2 points are NaN or infinite" in _corrupt(tmp_path / "a", nan)

    def empty(d):
        np.save(d / "points.npy", np.zeros((0, 3), np.float32))
        np.save(d / "instance.npy", np.zeros(0, np.int32))
        (d / "colors.npy").unlink()
    assert "empty map" in _corrupt(tmp_path / "b", empty)


def test_not_a_directory(tmp_path):
    with pytest.raises(InstanceMapError, match="not a directory"):
        read_instance_map(tmp_path / "nope")


def test_select_points_drops_vanished_labels():
    m = _map()
    s = select_points(m, m.instance != 2)
    assert 2 not in s.labels and set(s.labels) == {1, 3} and len(s.points) == (m.instance != 2).sum()
