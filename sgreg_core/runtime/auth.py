"""Who may speak for an agent: every coarse graph, dense request and dense graph is signed with
its sender's Ed25519 key (PyNaCl), over the topic it is published on and the message's bytes
(with the signature left empty), so a process without that key can neither forge nor move a
message to another topic. DDS-Security (SROS2) is the transport-level answer on full ROS
installs; the Fast DDS of the wheels is built without it, hence this.

A fleet keystore is a folder:
    private/<agent>.key   hex Ed25519 seed of an agent this machine runs (mode 0600)
    public/<agent>.pub    hex public key of every agent of the fleet
`sgreg keys init/add/list` manage it. A key's id is the first 16 hex digits of the sha256 of its
public key; a message names the key that signed it, and the receiver checks that the key
belongs to the agent the message claims to come from."""
from __future__ import annotations

import hashlib
import os
import re
from dataclasses import dataclass
from pathlib import Path

from ..config import param


class KeystoreError(ValueError):
    """A keystore that cannot be read or written; the message says why in one line."""


@dataclass
class AuthConfig:
    """keystore: the fleet keystore folder; empty: run unauthenticated (said loudly, once).
    max_age_s: a signed message whose signing time is further than this from the receiver's
    clock is refused as stale (robots' clocks are assumed synchronised to well within it)."""

    keystore: str = param("", "fleet keystore folder (sgreg keys init); empty: unauthenticated")
    max_age_s: float = param(30.0, "signed messages older or newer than this are refused as stale",
                             1.0, 3600.0)


def key_id(public: bytes) -> str:
    return hashlib.sha256(public).hexdigest()[:16]


class Keystore:
    """The public keys of a fleet and the private keys of the agents run here."""

    def __init__(self, root: str | Path):
        from nacl.signing import SigningKey, VerifyKey

        self.root = Path(root)
        if not (self.root / "public").is_dir():
            raise KeystoreError(f"{self.root} is not a keystore (no public/ folder; see sgreg keys init)")
        self.owners: dict[str, str] = {}           # key id -> agent
        self._verify: dict[str, VerifyKey] = {}
        self._sign: dict[str, SigningKey] = {}
        path = self.root
        try:
            # as ssh's StrictModes: whoever may write a public key may speak for its agent
            for path in (self.root, self.root / "public", self.root / "private",
                         *sorted((self.root / "public").glob("*.pub"))):
                if path.exists() and path.stat().st_mode & 0o022:
                    mode = path.stat().st_mode & 0o777
                    raise KeystoreError(f"keystore {self.root}: {path} can be written by other "
                                        f"users (mode {mode:o}); chmod go-w {path}")
            for path in sorted((self.root / "public").glob("*.pub")):
                vk = VerifyKey(bytes.fromhex(path.read_text().strip()))
                kid = key_id(bytes(vk))
                if kid in self.owners:   # either agent could sign as the other
                    raise KeystoreError(f"keystore {self.root}: public/{self.owners[kid]}.pub and "
                                        f"public/{path.name} hold the same key")
                self.owners[kid], self._verify[kid] = path.stem, vk
            for path in sorted((self.root / "private").glob("*.key")):
                mode = path.stat().st_mode & 0o777
                if mode & 0o077:    # as ssh does: a key others can read may already speak for the agent
                    raise KeystoreError(f"keystore {self.root}: private/{path.name} can be read by other "
                                        f"users (mode {mode:o}); chmod 600 {path}")
                self._sign[path.stem] = SigningKey(bytes.fromhex(path.read_text().strip()))
        except KeystoreError:
            raise
        except (OSError, ValueError) as exc:
            # the file it failed on, so that the fix is one line
            where = "" if path == self.root else f"{path.relative_to(self.root)}: "
            raise KeystoreError(f"keystore {self.root}: {where}{exc}") from None

    def signer(self, agent: str) -> tuple[str, object]:
        """(key id, signing key) of an agent run here; KeystoreError when its key is missing."""
        sk = self._sign.get(agent)
        if sk is None:
            raise KeystoreError(f"keystore {self.root} holds no private key of agent '{agent}'")
        kid = key_id(bytes(sk.verify_key))
        if self.owners.get(kid) != agent:    # every peer would refuse its messages as unknown_key
            raise KeystoreError(f"keystore {self.root}: private/{agent}.key does not match "
                                f"public/{agent}.pub")
        return kid, sk

    def check(self, kid: str, claimed_agent: str, payload: bytes, signature: bytes) -> str | None:
        """None when `signature` is kid's over payload and kid belongs to claimed_agent, else the
        refusal counter: unsigned, unknown_key, key_not_agents or bad_signature."""
        from nacl.exceptions import BadSignatureError

        if not kid or not signature:
            return "unsigned"
        vk = self._verify.get(kid)
        if vk is None:
            return "unknown_key"
        if self.owners[kid] != claimed_agent:
            return "key_not_agents"
        try:
            vk.verify(payload, bytes(signature))
        except (BadSignatureError, ValueError):
            return "bad_signature"
        return None


def sign(signing_key, payload: bytes) -> bytes:
    return bytes(signing_key.sign(payload).signature)


# ---- managing a keystore (sgreg keys) ------------------------------------------------------
def init_keystore(root: str | Path, agents: list[str]) -> list[tuple[str, str]]:
    """Create (or extend) a keystore with a new key pair for each agent; [(agent, key id)]."""
    from nacl.signing import SigningKey

    root = Path(root)
    for agent in agents:     # every name checked before anything is written
        _check_name(agent)
        if (root / "private" / f"{agent}.key").exists() or (root / "public" / f"{agent}.pub").exists():
            raise KeystoreError(f"{root} already holds a key of agent '{agent}'")
    if len(set(agents)) != len(agents):
        raise KeystoreError(f"agent names repeat: {agents}")
    (root / "private").mkdir(parents=True, exist_ok=True)
    (root / "public").mkdir(parents=True, exist_ok=True)
    os.chmod(root / "private", 0o700)
    made = []
    for agent in agents:
        sk = SigningKey.generate()
        private = root / "private" / f"{agent}.key"
        # created 0600, never readable by others for a moment (umask can only narrow it)
        with os.fdopen(os.open(private, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600), "w") as f:
            f.write(bytes(sk).hex() + "\n")
        (root / "public" / f"{agent}.pub").write_text(bytes(sk.verify_key).hex() + "\n")
        made.append((agent, key_id(bytes(sk.verify_key))))
    return made


def add_public_key(root: str | Path, agent: str, public_hex: str) -> str:
    """Add a peer's public key (hex, as `sgreg keys list` prints it); returns its key id."""
    from nacl.signing import VerifyKey

    _check_name(agent)
    try:
        vk = VerifyKey(bytes.fromhex(public_hex.strip()))
    except ValueError as exc:
        raise KeystoreError(f"not an Ed25519 public key: {exc}") from None
    public = Path(root) / "public"
    held = {path.stem: path.read_text().strip() for path in sorted(public.glob("*.pub"))}
    given = bytes(vk).hex()
    if held.get(agent, given) != given:
        # a new key for a known agent would lock out the old one's messages (and break that
        # agent if its private key is here): replacing a key is a deliberate act
        raise KeystoreError(f"{root} already holds another public key of agent '{agent}' "
                            f"(remove {public / (agent + '.pub')} to replace it)")
    others = [a for a, h in held.items() if h == given and a != agent]
    if others:    # one key for two agents: either could sign as the other
        raise KeystoreError(f"that key is agent '{others[0]}'s in {root}")
    public.mkdir(parents=True, exist_ok=True)
    (public / f"{agent}.pub").write_text(given + "\n")
    return key_id(bytes(vk))


def list_keys(root: str | Path) -> list[dict]:
    ks = Keystore(root)
    return [{"agent": agent, "key_id": kid, "private_here": agent in ks._sign,
             "public": bytes(ks._verify[kid]).hex()} for kid, agent in sorted(ks.owners.items(), key=lambda x: x[1])]


AGENT_ID = re.compile(r"[A-Za-z][A-Za-z0-9_]*")


def is_agent_id(name: str) -> bool:
    """Whether `name` can be an agent id: one token of a ROS name (a letter, then letters,
    digits and single underscores), since it starts every topic of the agent."""
    return bool(AGENT_ID.fullmatch(name)) and "__" not in name


def _check_name(agent: str) -> None:
    if not is_agent_id(agent):
        raise KeystoreError(f"agent id {agent!r} must be a letter, then letters, digits and single '_' "
                            "(a ROS name token)")
