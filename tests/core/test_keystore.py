"""The fleet keystore (runtime/auth.py): what `sgreg keys init` writes and what an agent signs with."""
import shutil

import pytest

from sgreg_core.runtime.auth import Keystore, KeystoreError, init_keystore


def test_an_agent_signs_with_the_key_its_peers_know(tmp_path):
    init_keystore(tmp_path, ["a", "b"])
    kid, _ = Keystore(tmp_path).signer("a")
    assert Keystore(tmp_path).owners[kid] == "a"


def test_a_private_key_that_does_not_match_its_public_key_is_said_at_start(tmp_path):
    """Else every peer would refuse the agent's messages as unknown_key, silently."""
    init_keystore(tmp_path, ["a", "b"])
    shutil.copy(tmp_path / "private" / "b.key", tmp_path / "private" / "a.key")
    with pytest.raises(KeystoreError, match="does not match"):
        Keystore(tmp_path).signer("a")


@pytest.mark.parametrize("names", [["a", "no good"], ["a", "a"]])
def test_a_bad_list_of_names_writes_no_key(tmp_path, names):
    with pytest.raises(KeystoreError):
        init_keystore(tmp_path / "keys", names)
    assert not (tmp_path / "keys").exists()
