"""Node features survive the wire encodings; malformed payloads are refused, not misread."""
import numpy as np
import pytest

from sgreg_core.runtime.wire import FLOAT16, FLOAT32, INT8, WireError, pack_features, unpack_features


@pytest.mark.parametrize("encoding,tol", [(FLOAT32, 0.0), (FLOAT16, 1e-3), (INT8, 1 / 254)])
def test_round_trip_within_encoding_precision(encoding, tol):
    x = np.random.default_rng(0).normal(size=(37, 64)).astype(np.float32)
    payload, scales = pack_features(x, encoding)
    y = unpack_features(payload, 37, 64, encoding, scales)
    assert y.shape == x.shape and y.dtype == np.float32
    # error relative to each node's largest component
    err = np.abs(y - x).max(axis=1) / np.abs(x).max(axis=1)
    assert err.max() <= tol + 1e-7


def test_sizes_in_bytes():
    x = np.ones((10, 32), np.float32)
    assert len(pack_features(x, FLOAT32)[0]) == 1280
    assert len(pack_features(x, FLOAT16)[0]) == 640
    assert len(pack_features(x, INT8)[0]) == 320


def test_zero_node_survives_int8():
    x = np.zeros((2, 8), np.float32)
    payload, scales = pack_features(x, INT8)
    assert np.array_equal(unpack_features(payload, 2, 8, INT8, scales), x)


@pytest.mark.parametrize("n,dim,encoding,scales", [
    (10, 33, FLOAT32, None),      # wrong dim
    (11, 32, FLOAT32, None),      # wrong count
    (10, 32, INT8, np.ones(3)),   # wrong number of scales
    (10, 32, 7, None),            # unknown encoding
])
def test_mismatched_payload_is_refused(n, dim, encoding, scales):
    payload, _ = pack_features(np.ones((10, 32), np.float32), FLOAT32 if encoding != INT8 else INT8)
    with pytest.raises(WireError):
        unpack_features(payload, n, dim, encoding, scales)


def test_nan_features_are_refused():
    """By the receiver, whatever a (forged or broken) sender packed."""
    x = np.ones((3, 4), np.float32)
    x[1, 2] = np.nan
    with pytest.raises(WireError, match="NaN"):
        unpack_features(x.astype("<f4").tobytes(), 3, 4, FLOAT32)


@pytest.mark.parametrize("encoding", [FLOAT32, FLOAT16, INT8])
def test_features_no_receiver_would_take_are_refused_by_the_sender(encoding):
    """Non-finite features (and, as float16, ones beyond its range, which become inf) would be
    refused by every peer without the sender knowing: the sender says why instead. int8 would
    even turn NaN into 0, features the receiver takes."""
    bad = np.array([[0.5, np.nan, 1.0]], np.float32)
    with pytest.raises(WireError, match="NaN or inf"):
        pack_features(bad, encoding)
    big = np.array([[7e4, 1.0, 0.0]], np.float32)
    if encoding == FLOAT16:
        with pytest.raises(WireError, match="beyond float16"):
            pack_features(big, encoding)
    else:
        payload, scales = pack_features(big, encoding)
        assert np.isfinite(unpack_features(payload, 1, 3, encoding, scales)).all()
