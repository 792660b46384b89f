"""Label text encoding: the bundled MiniLM (loaded once, offline) and the label cache."""
import os

import numpy as np
import pytest

from sgreg_core.net.text import TEXT_DIM, TextEncoder, normalize_label


class CountingEmbed:
    def __init__(self):
        self.calls: list[list[str]] = []

    def __call__(self, labels):
        self.calls.append(list(labels))
        rng = np.random.default_rng(len(self.calls))
        return rng.normal(size=(len(labels), TEXT_DIM)).astype(np.float32)


@pytest.fixture(scope="module")
def minilm():
    encoder = TextEncoder()
    encoder.encode(["chair"])  # loads the model once for the module
    return encoder


def test_a_labels_embedding_does_not_depend_on_the_labels_missed_with_it(minilm):
    """The cache embeds whatever it misses at once: a label must come out the same whether it
    was missed alone or with longer labels (training and the nodes read each other's caches)."""
    embed = minilm._embed_fn
    alone = embed(["office chair"])[0]
    together = embed(["a very long label of a piece of furniture seen in a hall", "office chair"])[1]
    assert np.array_equal(alone, together)


def test_minilm_embeddings_are_semantic_unit_vectors(minilm):
    emb = minilm.encode(["sofa", "couch", "ceiling", "Sofa ", "sofa"])
    assert emb.shape == (5, TEXT_DIM) and emb.dtype == np.float32
    np.testing.assert_allclose(np.linalg.norm(emb, axis=1), 1.0, atol=1e-5)
    assert np.array_equal(emb[0], emb[3]) and np.array_equal(emb[0], emb[4])
    assert emb[0] @ emb[1] > emb[0] @ emb[2] + 0.2
    assert os.environ["HF_HUB_OFFLINE"] == "1" and os.environ["TRANSFORMERS_OFFLINE"] == "1"
    assert minilm.encode([]).shape == (0, TEXT_DIM)


def test_each_label_is_embedded_once():
    embed = CountingEmbed()
    encoder = TextEncoder(embed_fn=embed, name="counting")
    a = encoder.encode(["chair", "table", "chair"])
    b = encoder.encode(["table", "lamp", " CHAIR"])
    assert embed.calls == [["chair", "table"], ["lamp"]]
    assert np.array_equal(a[0], b[2]) and np.array_equal(a[1], b[0])


def test_disk_cache_round_trip_and_name_check(tmp_path):
    path = tmp_path / "cache" / "labels.npz"
    first = TextEncoder(cache_path=path, embed_fn=CountingEmbed(), name="counting")
    emb = first.encode(["door", "window"])
    assert path.exists()

    def fail(labels):
        raise AssertionError(f"cache miss for {labels}")

    again = TextEncoder(cache_path=path, embed_fn=fail, name="counting")
    assert np.array_equal(again.encode(["window", "door"]), emb[::-1])
    assert again.cached_labels == ["door", "window"]
    other = TextEncoder(cache_path=path, embed_fn=CountingEmbed(), name="another-model")
    assert other.cached_labels == []


def test_wrong_embedding_size_is_an_error():
    encoder = TextEncoder(embed_fn=lambda labels: np.zeros((len(labels), 3)), name="bad")
    with pytest.raises(ValueError, match="shape"):
        encoder.encode(["chair"])


def test_normalize_label():
    assert normalize_label("  Office   Chair\n") == "office chair"


def test_shipped_table_is_minilm_and_spares_loading_it(minilm, tmp_path, monkeypatch):
    """The shipped vocabulary table holds what MiniLM gives, and an encoder with it never loads
    MiniLM for those labels; a new label lands in the user cache, read back by the next one."""
    from sgreg_cli.commands.text_table import vocabulary
    from sgreg_core.net.text import SHIPPED_TABLE, user_cache_path

    vocab = vocabulary()
    monkeypatch.setenv("SGREG_CACHE_DIR", str(tmp_path))
    encoder = TextEncoder(cache_path=user_cache_path(), table=SHIPPED_TABLE)
    assert set(vocab) <= set(encoder.cached_labels)
    sample = vocab[::17]
    np.testing.assert_allclose(encoder.encode(sample), minilm.encode(sample), atol=1e-5)
    assert not encoder.loaded_model
    encoder.encode(["a label nobody uses"])
    assert encoder.loaded_model
    again = TextEncoder(cache_path=user_cache_path(), table=SHIPPED_TABLE, embed_fn=None)
    assert "a label nobody uses" in again.cached_labels
    again.encode(["a label nobody uses", "chair"])
    assert not again.loaded_model


def test_table_written_and_unwritable_cache_is_a_warning(tmp_path):
    table = tmp_path / "table.npz"
    TextEncoder(embed_fn=CountingEmbed(), name="counting").write_table(table, ["Door", "window", "door"])
    enc = TextEncoder(table=table, name="counting", embed_fn=CountingEmbed())
    assert enc.cached_labels == ["door", "window"]
    blocked = tmp_path / "file"
    blocked.write_text("not a folder")
    enc = TextEncoder(cache_path=blocked / "cache.npz", embed_fn=CountingEmbed(), name="counting")
    with pytest.warns(UserWarning, match="not written"):
        enc.encode(["lamp"])
    assert enc.encode(["lamp"]).shape == (1, TEXT_DIM)


@pytest.mark.parametrize("damage", ["truncated", "empty", "wrong_width"])
def test_damaged_disk_cache_is_a_warning_and_rebuilt(tmp_path, damage):
    """A cache cut short by a crash, emptied, or written with other embeddings must cost a
    rebuild, never every encode() of the node (np.load raises BadZipFile / EOFError there)."""
    path = tmp_path / "labels.npz"
    TextEncoder(cache_path=path, embed_fn=CountingEmbed(), name="counting").encode(["door", "window"])
    if damage == "truncated":
        path.write_bytes(path.read_bytes()[:40])
    elif damage == "empty":
        path.write_bytes(b"")
    else:
        np.savez(path, model=np.array("counting"), labels=np.array(["door"]),
                 embeddings=np.zeros((1, 3), np.float32))
    with pytest.warns(UserWarning, match="ignored"):
        enc = TextEncoder(cache_path=path, embed_fn=CountingEmbed(), name="counting")
    assert enc.cached_labels == []
    assert enc.encode(["door"]).shape == (1, TEXT_DIM)
