"""scripts/choose_verdict.py's logistic fit, which the verdict's shipped confidence weights
come from (docs/VERDICT.md)."""
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "scripts"))
from choose_verdict import fit_logistic, parse_fixed  # noqa: E402


def _samples(w_true, n=20000, seed=0):
    rng = np.random.default_rng(seed)
    X = np.column_stack([np.ones(n), rng.normal(size=(n, len(w_true) - 1))])
    y = (rng.random(n) < 1 / (1 + np.exp(-X @ w_true))).astype(float)
    return X, y


def test_the_fit_recovers_the_weights_that_made_the_labels():
    w_true = np.array([-1.0, 2.0, -0.5])
    X, y = _samples(w_true)
    np.testing.assert_allclose(fit_logistic(X, y), w_true, atol=0.1)


def test_a_fixed_weight_is_held_and_the_others_fitted_around_it():
    w_true = np.array([-1.0, 2.0, -0.5])
    X, y = _samples(w_true)
    w = fit_logistic(X, y, fixed={2: -0.5})
    assert w[2] == -0.5
    np.testing.assert_allclose(w, w_true, atol=0.1)
    # held far from what the data say, it stays there
    assert fit_logistic(X, y, fixed={1: 0.0})[1] == 0.0


def test_fixed_weights_are_named_as_the_confidence_names_them():
    assert parse_fixed(["ambiguity=-2.353", "bias=-13"]) == {4: -2.353, 0: -13.0}
    for bad in (["amb=-1"], ["ambiguity"], ["ambiguity="]):
        with pytest.raises(SystemExit, match="NAME=VALUE"):
            parse_fixed(bad)
