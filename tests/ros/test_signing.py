"""Signatures survive the wire: every message kind the nodes sign, with values that float32
fields round (a confidence of 0.1234567891 arrives as 0.12345679), checks on the receiving side
after real CDR serialisation, and a changed field does not."""
import pytest
from rclpy.serialization import deserialize_message, serialize_message
from sgreg_msgs.msg import CoarseGraph, DenseGraph, DenseRequest, RegistrationResult

from sgreg_core.runtime.auth import AuthConfig, init_keystore
from sgreg_ros.signing import MessageAuth


class Quiet:
    def warning(self, text):
        pass


def result() -> RegistrationResult:
    msg = RegistrationResult(agent_id="a", peer_id="b", sequence=7, verified=True, mode="dense",
                             reason="ok", link="confirmed", confidence=0.1234567891,
                             fitness=0.98765432101, ambiguity=1.0 / 3.0, inlier_ratio=0.2)
    msg.transform.transform.translation.x = 1.0 / 3.0      # float64: kept as is
    msg.inlier_node_pairs = [1, 2, 3, 4]
    msg.timing_names, msg.timing_ms = ["total"], [123.456789]
    return msg


@pytest.mark.parametrize("make,tamper", [
    (result, lambda m: setattr(m, "confidence", 0.99)),
    (result, lambda m: setattr(m, "verified", False)),
    (lambda: CoarseGraph(agent_id="a", sequence=3), lambda m: setattr(m, "sequence", 4)),
    (lambda: DenseGraph(agent_id="a", requester="b", request_sequence=2),
     lambda m: setattr(m, "requester", "c")),
    (lambda: DenseRequest(from_agent="a", to_agent="b", sequence=5), lambda m: setattr(m, "sequence", 6)),
])
def test_a_signed_message_checks_after_the_wire_and_a_changed_one_does_not(tmp_path, make, tamper):
    init_keystore(tmp_path, ["a", "b"])
    sender = MessageAuth(AuthConfig(keystore=str(tmp_path)), "a", Quiet())
    msg = make()
    topic = "/a/sgreg/topic"
    sender.sign(msg, topic)
    wire = serialize_message(msg)
    received = deserialize_message(wire, type(msg))
    assert MessageAuth(AuthConfig(keystore=str(tmp_path)), "b", Quiet()).check(received, topic, "a") is None
    changed = deserialize_message(wire, type(msg))
    tamper(changed)
    assert MessageAuth(AuthConfig(keystore=str(tmp_path)), "b", Quiet()).check(changed, topic, "a") \
        == "bad_signature"


def test_a_results_age_is_counted_from_its_signing_and_one_from_before_a_restart_has_none(tmp_path):
    """What the registration node dates a peer's word by (Peers.on_peer_result age_s)."""
    import time

    from sgreg_ros import convert

    init_keystore(tmp_path, ["a", "b"])
    sender = MessageAuth(AuthConfig(keystore=str(tmp_path)), "a", Quiet())
    before_restart = sender.sign(result(), "/a/sgreg/registration").signed_ns
    receiver = MessageAuth(AuthConfig(keystore=str(tmp_path)), "b", Quiet())
    assert receiver.said_s_ago(before_restart) == float("inf")
    msg = result()
    msg.header.frame_id = msg.transform.header.frame_id = "b/map"
    msg.transform.child_frame_id = "a/map"
    msg.transform.transform.rotation.w = 1.0
    sender.sign(msg, "/a/sgreg/registration")
    taken = convert.result_from_msg(deserialize_message(serialize_message(msg), RegistrationResult))
    assert taken.signed_ns == msg.signed_ns and 0.0 <= receiver.said_s_ago(taken.signed_ns) < 1.0
    receiver._started_ns -= 60_000_000_000           # as if it had run for a minute
    assert receiver.said_s_ago(time.time_ns() - 4_000_000_000) == pytest.approx(4.0, abs=0.5)
    assert MessageAuth(AuthConfig(), "b", Quiet()).said_s_ago(0) == 0.0      # nothing is signed
