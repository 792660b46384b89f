"""Field combinations the decoders refuse instead of reading one way: clouds whose fields repeat
or overlap, instance ids that repeat, stamps past a second's nanoseconds, results whose rotation
is not a unit quaternion or whose frames name another link, and messages too big to be what
they claim, refused before they are decoded."""
import numpy as np
import pytest
from rclpy.serialization import serialize_message

from sgreg_ros import convert
from sgreg_ros.pointcloud import PointField

from . import samples


def refusals():
    said = []
    return said, lambda counter, why: said.append((counter, why)) or why


def fields(msg, **change):
    """The cloud's fields with (name -> (offset, count)) changed, or a field added (name_2)."""
    out = []
    for f in msg.points.fields:
        offset, count = change.get(f.name, (f.offset, f.count))
        out.append(PointField(name=f.name, offset=offset, datatype=f.datatype, count=count))
    if "x_again" in change:
        out.append(PointField(name="x", offset=change["x_again"][0], datatype=PointField.FLOAT32, count=1))
    return out


@pytest.mark.parametrize("change", [
    {"y": (2, 1)},             # y overlaps x: distinct offsets, the same bytes
    {"z": (8, 2)},             # a field of two values: which one is z?
    {"x_again": (12, 1)},      # x twice: which one is meant?
])
def test_point_clouds_with_repeated_or_overlapping_fields_are_refused(change):
    msg = samples.instance_map(np.random.default_rng(0))
    msg.points.point_step = 20
    msg.points.row_step = 20 * msg.points.width
    msg.points.data = bytes(20 * msg.points.width)
    sent = fields(msg)
    msg.points.fields = fields(msg, **change)
    with pytest.raises(convert.ConversionError, match="points: PointCloud2"):
        convert.instance_map_from_msg(msg)
    msg.points.fields = sent               # the same bytes with the fields as sent: taken
    assert len(convert.instance_map_from_msg(msg).points) == msg.points.width


def test_instance_ids_that_repeat_are_refused():
    msg = samples.instance_map(np.random.default_rng(1))
    ids = list(msg.instance_ids)
    msg.instance_ids = [ids[0], *ids[:-1]]
    with pytest.raises(convert.ConversionError, match=f"instance ids repeat: \\[{ids[0]}\\]"):
        convert.instance_map_from_msg(msg)


def test_a_stamp_past_a_seconds_nanoseconds_is_refused():
    rng = np.random.default_rng(2)
    imap = samples.instance_map(rng)
    imap.header.stamp.nanosec = 1_000_000_000
    said, refuse = refusals()
    taken = []
    why = convert.take_instance_map(serialize_message(imap), lambda *a: taken.append(a), refuse, "a")
    assert not taken and said[0][0] == "bad_instance_map" and "nanosec 1000000000" in why
    result = samples.registration_result(rng)
    result.header.stamp.nanosec = 4_000_000_000
    with pytest.raises(convert.ConversionError, match="nanosec"):
        convert.result_from_msg(result)


def test_results_with_a_rotation_that_is_not_unit_or_frames_of_another_link_are_refused():
    rng = np.random.default_rng(3)
    assert convert.result_from_msg(samples.registration_result(rng)).peer == "b"
    scaled = samples.registration_result(rng)
    scaled.transform.transform.rotation.w *= 3.0      # once normalised away, a guess at the rotation
    with pytest.raises(convert.ConversionError, match="not a unit quaternion"):
        convert.result_from_msg(scaled)
    for frame in ("header", "transform.header", "child"):
        other = samples.registration_result(rng)
        if frame == "header":
            other.header.frame_id = "c/map"
        elif frame == "transform.header":
            other.transform.header.frame_id = "c/map"
        else:
            other.transform.child_frame_id = "c/map"
        with pytest.raises(convert.ConversionError, match="is 'c/map', not"):
            convert.result_from_msg(other)
    unset = samples.registration_result(rng)            # frames left empty: taken
    unset.header.frame_id = unset.transform.header.frame_id = unset.transform.child_frame_id = ""
    assert convert.result_from_msg(unset).agent == "a"


def test_messages_too_big_for_what_they_hold_are_refused_before_decoding():
    rng = np.random.default_rng(4)
    raw = serialize_message(samples.instance_map(rng, n_points=1000))
    said, refuse = refusals()
    taken = []
    # room for the map's 1000 points: taken as far as the checks go
    convert.take_instance_map(raw, lambda *a: taken.append(a), refuse, "a", max_points=1000)
    assert taken and not said
    # a front end's padded layout (32 bytes a point, as PCL's PointXYZL) is no bigger a map
    wide = samples.instance_map(rng, n_points=1000)
    wide.points.point_step, wide.points.row_step = 32, 32 * 1000
    wide.points.data = bytes(32 * 1000)
    convert.take_instance_map(serialize_message(wide), lambda *a: taken.append(a), refuse, "a", max_points=1000)
    assert len(taken) == 2 and not said
    taken.pop()
    too_many = (convert.MAP_OVERHEAD_BYTES + 1000 * convert.MAX_POINT_BYTES) // 16 + 1000
    big = serialize_message(samples.instance_map(rng, n_points=too_many))
    convert.take_instance_map(big, lambda *a: taken.append(a), refuse, "a", max_points=1000)
    assert len(taken) == 1 and said[0][0] == "oversized_message" and "max_points_in_map=1000" in said[0][1]
    # a request naming every node of a graph of max_nodes fits; one naming more does not
    request = samples.dense_request(rng)
    request.node_ids = list(range(2000))
    assert len(serialize_message(request)) <= convert.max_request_bytes(2000)
    request.node_ids = list(range(2000 + convert.REQUEST_OVERHEAD_BYTES))
    assert len(serialize_message(request)) > convert.max_request_bytes(2000)
