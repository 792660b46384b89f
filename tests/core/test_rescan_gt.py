"""One reader of rescan_gt.json for training, bench-register and make-bag: the same entries are
used by all three, and a malformed file is refused by all three instead of skipped by some."""
import json

import numpy as np
import pytest

from sgreg_core.rescan_gt import (RescanGTError, accepted_directions, load_rescan_gt,
                                  transform_between)

RIGID = [[0.0, -1.0, 0.0, 1.0], [1.0, 0.0, 0.0, 2.0], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]]


def _write(tmp_path, pairs) -> str:
    path = tmp_path / "rescan_gt.json"
    path.write_text(json.dumps({"pairs": pairs}))
    return str(path)


def test_accepted_pairs_between_known_scans_are_the_only_ones_used(tmp_path):
    pairs = load_rescan_gt(_write(tmp_path, [
        {"src": "b", "ref": "a", "accepted": True, "T_src_to_ref": RIGID},
        {"src": "c", "ref": "a", "accepted": False, "reasons": ["low overlap"]},
        {"src": "x", "ref": "a", "accepted": True, "T_src_to_ref": RIGID},   # x is not a scan here
    ]))
    one_way = accepted_directions(pairs, {"a", "b", "c"})
    assert [(s, r) for s, r, _ in one_way] == [("b", "a")]
    both = accepted_directions(pairs, {"a", "b", "c"}, both_ways=True)
    assert [(s, r) for s, r, _ in both] == [("b", "a"), ("a", "b")]
    np.testing.assert_allclose(both[1][2] @ both[0][2], np.eye(4), atol=1e-12)
    np.testing.assert_allclose(transform_between(pairs, "a", "b"), RIGID)     # b into a's frame
    with pytest.raises(RescanGTError, match="rejects a x c: low overlap$"):
        transform_between(pairs, "a", "c")
    with pytest.raises(RescanGTError, match="has no entry for a x d$"):
        transform_between(pairs, "a", "d")


@pytest.mark.parametrize("entry, why", [
    ({"src": "b", "ref": "a", "accepted": "no", "T_src_to_ref": RIGID}, "'accepted' of a x b must be true or false"),
    ({"src": "b", "ref": "a", "accepted": 1, "T_src_to_ref": RIGID}, "'accepted' of a x b must be true or false"),
    ({"src": "b", "ref": "a", "accepted": True, "T_src_to_ref": (2 * np.eye(4)).tolist()}, "not a 4x4 rigid"),
    ({"src": "b", "ref": None, "accepted": True, "T_src_to_ref": RIGID}, "src and ref must be scan names"),
])
def test_a_malformed_entry_anywhere_in_the_file_is_refused(tmp_path, entry, why):
    """Even an entry for scans nobody asked about: a file with one wrong entry is not trusted."""
    path = _write(tmp_path, [{"src": "d", "ref": "c", "accepted": True, "T_src_to_ref": RIGID}, entry])
    with pytest.raises(RescanGTError, match=why):
        load_rescan_gt(path)


def test_bench_register_and_training_refuse_a_malformed_file_instead_of_skipping_it(tmp_path):
    """Before one reader, both skipped an entry whose 'accepted' was "no" (one case or pair
    fewer, without a word) while make-bag refused it."""
    from sgreg_core.bench.cases import CaseConfig, _rescan_cases
    from sgreg_core.net.dataset import DataConfig, PairSource

    path = _write(tmp_path, [{"src": "b", "ref": "a", "accepted": "no", "T_src_to_ref": RIGID}])
    with pytest.raises(RescanGTError, match="must be true or false, got 'no'"):
        _rescan_cases(CaseConfig(rescan_gt=path), {"a", "b"})
    source = PairSource.__new__(PairSource)     # only the reader, without scans to load
    source.cfg = DataConfig(rescan_gt=path)
    with pytest.raises(RescanGTError, match="must be true or false, got 'no'"):
        source._rescan_list({"a", "b"})


def test_a_different_room_pair_of_a_training_room_never_takes_the_held_out_room():
    """The different-room poses of training rooms are negatives of threshold fits
    (scripts/choose_geometric.py): the held-out room must not be their other room."""
    from sgreg_core.bench.cases import CaseConfig, _other_rooms_of

    scans = ["p_scene0000_00", "p_scene0000_01", "p_scene0001_00", "p_scene0005_00", "p_scene0005_01"]
    cfg = CaseConfig(rooms=("scene0000", "scene0001"), held_out_rooms=("scene0005",))
    assert _other_rooms_of(cfg, "p_scene0000_01", scans) == ["p_scene0001_00"]
    held = CaseConfig(rooms=("scene0005",), held_out_rooms=("scene0005",))
    assert _other_rooms_of(held, "p_scene0005_00", scans) == scans[:3]      # any other room
    asked = CaseConfig(rooms=("scene0000",), other_rooms=("scene0005",))
    assert _other_rooms_of(asked, "p_scene0000_00", scans) == scans[3:]     # named on purpose


def test_the_room_of_a_capture_is_one_rule_for_splits_cases_and_suites():
    from sgreg_core.rescan_gt import room_of

    assert room_of("scannet-picwoon_scene0005_01") == room_of("/x/p_scene0005_00") == "scene0005"
    assert room_of("lab_01") == room_of("lab_02") == "lab"       # two captures of one room
    assert room_of("myroom") == "myroom" and room_of("_01") == "_01"
