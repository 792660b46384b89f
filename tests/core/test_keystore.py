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


@pytest.mark.parametrize("names", [["é"], ["1a"], ["a__b"], ["_a"]])
def test_names_the_nodes_would_refuse_get_no_key(tmp_path, names):
    with pytest.raises(KeystoreError, match="ROS name token"):
        init_keystore(tmp_path / "keys", names)


def test_a_known_agents_key_is_never_replaced_or_shared(tmp_path):
    """`keys add` over an agent's own key broke that agent (its private key no longer matched),
    and one key under two names let either sign as the other."""
    from sgreg_core.runtime.auth import add_public_key, list_keys

    init_keystore(tmp_path, ["a", "b"])
    keys = {k["agent"]: k["public"] for k in list_keys(tmp_path)}
    with pytest.raises(KeystoreError, match="another public key of agent 'a'"):
        add_public_key(tmp_path, "a", keys["b"])
    with pytest.raises(KeystoreError, match="agent 'b's"):
        add_public_key(tmp_path, "c", keys["b"])
    assert add_public_key(tmp_path, "a", keys["a"])        # the same key again: nothing changes
    Keystore(tmp_path).signer("a")
    assert {k["agent"] for k in list_keys(tmp_path)} == {"a", "b"}
    # a peer's key that `add` stored is not replaced by `init` either
    other = tmp_path / "other"
    init_keystore(other, ["peer"])
    peer = list_keys(other)[0]["public"]
    add_public_key(tmp_path, "peer", peer)
    with pytest.raises(KeystoreError, match="already holds a key of agent 'peer'"):
        init_keystore(tmp_path, ["peer"])
    assert {k["agent"]: k["public"] for k in list_keys(tmp_path)}["peer"] == peer


def test_one_public_key_under_two_names_is_refused_at_load(tmp_path):
    """A hand-copied public/ where c.pub is b's key: b's messages would be refused as another
    agent's and b's key could speak as c. `keys add` refuses this; loading must too."""
    init_keystore(tmp_path, ["a", "b"])
    shutil.copy(tmp_path / "public" / "b.pub", tmp_path / "public" / "c.pub")
    with pytest.raises(KeystoreError, match="same key"):
        Keystore(tmp_path)


def test_a_private_key_other_users_can_read_is_refused_at_load(tmp_path):
    """As ssh refuses such a key: whoever else can read it may already sign as the agent."""
    import os

    init_keystore(tmp_path, ["a", "b"])
    Keystore(tmp_path).signer("a")
    os.chmod(tmp_path / "private" / "b.key", 0o644)
    with pytest.raises(KeystoreError, match=r"private/b.key can be read by other users \(mode 644\); chmod 600") as err:
        Keystore(tmp_path)
    assert str(err.value).count("keystore") == 1      # said once, not wrapped again


@pytest.mark.parametrize("where", ["public/b.pub", "public", "private", "."])
def test_a_keystore_other_users_can_write_to_is_refused_at_load(tmp_path, where):
    """As ssh's StrictModes: whoever may replace public/b.pub may sign as b."""
    import os

    init_keystore(tmp_path, ["a", "b"])
    path = tmp_path / where
    os.chmod(path, path.stat().st_mode | 0o002)
    with pytest.raises(KeystoreError, match=r"can be written by other users .*chmod go-w"):
        Keystore(tmp_path)


def test_the_keys_command_refuses_arguments_it_would_ignore(tmp_path, capsys):
    from sgreg_cli.main import main

    assert main(["keys", "init", str(tmp_path / "k"), "--agents", "a", "b"]) == 0
    capsys.readouterr()
    for argv, words in ((["list", str(tmp_path / "k"), "extra"], "list takes only DIR; got also extra"),
                        (["list", str(tmp_path / "k"), "--agents", "c"], "list takes only DIR; got also --agents"),
                        (["init", str(tmp_path / "k2"), "c", "--agents", "c"], "init takes only DIR and --agents")):
        assert main(["keys", *argv]) == 2, argv
        assert words in capsys.readouterr().err
    assert not (tmp_path / "k2").exists()
    assert main(["keys", "list", str(tmp_path / "k")]) == 0


def test_a_key_file_that_is_not_hex_is_named(tmp_path):
    init_keystore(tmp_path / "k", ["a", "b"])
    (tmp_path / "k" / "public" / "b.pub").write_text("not hex")
    with pytest.raises(KeystoreError, match=r"public/b\.pub: non-hexadecimal"):
        Keystore(tmp_path / "k")
