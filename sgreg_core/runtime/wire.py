"""Node features on the wire: float32, float16, or int8 with one scale per node.

int8 keeps each node's largest magnitude at 127, so the relative error per node is at most
1/254 of its largest component: enough for matching (cosine similarities move by < 1e-2) at a
quarter of float32's bytes.
"""
from __future__ import annotations

import numpy as np

FLOAT32, FLOAT16, INT8 = 0, 1, 2  # the FEATURE_* constants of sgreg_msgs/CoarseGraph
ENCODINGS = {"float32": FLOAT32, "float16": FLOAT16, "int8": INT8}
# what agents send unless told otherwise (the node's feature_encoding), and so what offline
# replays and the scaling bench assume: half float32's bytes, matching unchanged
DEFAULT_ENCODING = "float16"


class WireError(ValueError):
    """Packed features that do not decode to (n, dim)."""


def pack_features(x: np.ndarray, encoding: int) -> tuple[bytes, np.ndarray]:
    """(n, d) features -> (payload bytes, per-node scales; empty unless INT8)."""
    x = np.asarray(x, dtype=np.float32)
    if x.ndim != 2:
        raise WireError(f"features must be (n, d), got shape {x.shape}")
    # every receiver refuses non-finite features: the sender is the one to say why
    if not np.isfinite(x).all():
        raise WireError("features hold NaN or inf (the network's output); not sent")
    if encoding == FLOAT32:
        return x.astype("<f4").tobytes(), np.zeros(0, np.float32)
    if encoding == FLOAT16:
        if x.size and np.abs(x).max() > np.finfo(np.float16).max:
            raise WireError(f"features reach {np.abs(x).max():.3g}, beyond float16 (65504): "
                            "send them as float32 or int8")
        return x.astype("<f2").tobytes(), np.zeros(0, np.float32)
    if encoding == INT8:
        scale = np.abs(x).max(axis=1) / 127.0
        scale = np.where(scale > 0, scale, 1.0).astype(np.float32)
        q = np.clip(np.rint(x / scale[:, None]), -127, 127).astype(np.int8)
        return q.tobytes(), scale
    raise WireError(f"unknown feature encoding {encoding}")


def unpack_features(payload: bytes, n: int, dim: int, encoding: int,
                    scales: np.ndarray | None = None) -> np.ndarray:
    """Inverse of pack_features -> (n, dim) float32; raises WireError on any size mismatch."""
    itemsize = {FLOAT32: 4, FLOAT16: 2, INT8: 1}.get(encoding)
    if itemsize is None:
        raise WireError(f"unknown feature encoding {encoding}")
    if len(payload) != n * dim * itemsize:
        raise WireError(f"features are {len(payload)} bytes, expected {n} nodes x {dim} x {itemsize}")
    if encoding == FLOAT32:
        x = np.frombuffer(payload, dtype="<f4")
    elif encoding == FLOAT16:
        x = np.frombuffer(payload, dtype="<f2").astype(np.float32)
    else:
        scales = np.asarray(scales if scales is not None else [], dtype=np.float32)
        if scales.shape != (n,):
            raise WireError(f"int8 features need {n} scales, got {scales.shape[0]}")
        x = np.frombuffer(payload, dtype=np.int8).astype(np.float32).reshape(n, dim) * scales[:, None]
    x = x.reshape(n, dim).astype(np.float32)
    if not np.isfinite(x).all():
        raise WireError("features contain NaN or inf")
    return x
