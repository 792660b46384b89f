"""Signing the node's outgoing sgreg messages and checking incoming ones (sgreg_core.runtime.auth):
the signature covers the topic and every field of the message but `signature`, in a canonical
encoding. Not the CDR bytes: CDR leaves its alignment padding uninitialised, so the same message
serialises to different bytes."""
from __future__ import annotations

import array
import struct
import time

from sgreg_core.runtime.auth import AuthConfig, Keystore, KeystoreError, sign

from .params import ParameterError

UNAUTHENTICATED = ("running UNAUTHENTICATED (no keystore parameter): any process on this DDS "
                   "domain can speak for any agent. Make a fleet keystore with `sgreg keys init` "
                   "and pass -p keystore:=DIR (docs/SECURITY.md)")


class MessageAuth:
    """sign(msg, topic) before publishing; check(msg, topic, agent) -> None or a refusal counter:
    unsigned, stale_message, unknown_key, key_not_agents, bad_signature, or replayed (signed
    no later than the last message of that key taken on that topic). Without a keystore both are no-ops and
    the node says so once, loudly. agent None: check only (a listener that signs nothing; it
    needs a keystore, and no logger)."""

    def __init__(self, cfg: AuthConfig, agent: str | None, logger):
        self.cfg = cfg
        self.keystore, self._key = None, None
        self._newest: dict[tuple, int] = {}   # (topic, key) -> signing time of the last message taken
        self._started_ns = time.time_ns()
        if not cfg.keystore:
            logger.warning(UNAUTHENTICATED)
            return
        try:
            self.keystore = Keystore(cfg.keystore)
            if agent is not None:
                self.key_id, self._key = self.keystore.signer(agent)
        except KeystoreError as exc:
            raise ParameterError(f"parameter 'keystore': {exc}") from None

    @staticmethod
    def _payload(msg, topic: str) -> bytes:
        parts = [topic.encode(), b"\0"]
        _canonical(msg, parts, skip="signature")
        return b"".join(parts)

    def sign(self, msg, topic: str):
        if self.keystore is not None:
            if self._key is None:
                raise RuntimeError("MessageAuth made to check only (agent None) cannot sign")
            msg.key_id, msg.signed_ns, msg.signature = self.key_id, time.time_ns(), b""
            msg.signature = sign(self._key, self._payload(msg, topic))
        return msg

    def said_s_ago(self, signed_ns: int) -> float:
        """How long ago a checked message was signed (0 without a keystore, where nothing is
        signed); inf when it was signed before this node started: a message captured before a
        restart, whose replay the record of the newest one seen (lost with it) cannot catch."""
        if self.keystore is None:
            return 0.0
        if signed_ns < self._started_ns:
            return float("inf")
        return max(time.time_ns() - signed_ns, 0) / 1e9

    def check(self, msg, topic: str, agent: str) -> str | None:
        """Why a message on `topic` that claims to come from `agent` is refused, or None."""
        if self.keystore is None:
            return None
        if not msg.key_id or not len(msg.signature):
            return "unsigned"
        if abs(time.time_ns() - msg.signed_ns) > self.cfg.max_age_s * 1e9:
            return "stale_message"
        signature, msg.signature = bytes(msg.signature), b""
        try:
            refused = self.keystore.check(msg.key_id, agent, self._payload(msg, topic), signature)
        finally:
            msg.signature = signature
        if refused:
            return refused
        # a sender signs in time order: an older signing time is a captured message played again
        if msg.signed_ns <= self._newest.get((topic, msg.key_id), 0):
            return "replayed"
        self._newest[topic, msg.key_id] = msg.signed_ns
        return None


def _canonical(value, out: list, skip: str = "", kind: str = "") -> None:
    """Append an unambiguous encoding of a ROS message (fields in declaration order, each
    length-prefixed) to `out`. A float32 field is encoded as float32: the sender holds the
    Python double it set, the receiver what survived the wire."""
    if hasattr(value, "get_fields_and_field_types"):
        for name, field_type in value.get_fields_and_field_types().items():
            if name != skip:
                _canonical(getattr(value, name), out, kind=field_type)
    elif isinstance(value, float) and kind == "float":
        out.append(struct.pack("<cf", b"f", value))
    elif isinstance(value, str):
        data = value.encode()
        out += [struct.pack("<cQ", b"s", len(data)), data]
    elif isinstance(value, (bytes, bytearray, memoryview, array.array)) or hasattr(value, "tobytes"):
        data = value.tobytes() if hasattr(value, "tobytes") else bytes(value)
        out += [struct.pack("<cQ", b"b", len(data)), data]
    elif isinstance(value, (list, tuple)):
        out.append(struct.pack("<cQ", b"l", len(value)))
        for item in value:
            _canonical(item, out)
    elif isinstance(value, bool):
        out.append(b"t" if value else b"f")
    elif isinstance(value, int):
        out += [b"i", str(value).encode(), b";"]
    elif isinstance(value, float):
        out.append(struct.pack("<cd", b"d", value))
    else:
        raise TypeError(f"cannot sign a field of type {type(value).__name__}")
