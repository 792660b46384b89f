"""Metrics on hand-computed cases."""
import math

import numpy as np

from sgreg_core.geometry import transform_points, yaw_transform
from sgreg_core.metrics import (inlier_ratio, node_match_scores, registration_rmse, registration_success, rre, rte,
                                two_agent_success)


def test_yaw_transform_and_transform_points():
    T = yaw_transform(np.pi / 2, (1.0, 2.0, 3.0))
    np.testing.assert_allclose(transform_points(T, np.array([[1.0, 0.0, 0.0]])), [[1.0, 3.0, 3.0]], atol=1e-12)


def test_rre_rte():
    assert math.isclose(rre(yaw_transform(np.radians(10)), np.eye(4)), 10.0, rel_tol=1e-9)
    assert math.isclose(rre(yaw_transform(np.radians(170)), yaw_transform(np.radians(-170))), 20.0, rel_tol=1e-9)
    assert math.isclose(rte(yaw_transform(0, (3, 4, 0)), np.eye(4)), 5.0)


def test_rmse_and_registration_recall():
    src = np.array([[1.0, 0, 0], [-1.0, 0, 0]])
    T_est = yaw_transform(0, (0.1, 0, 0))
    assert math.isclose(registration_rmse(src, T_est, np.eye(4)), 0.1)
    assert registration_success(src, T_est, np.eye(4))
    # rotating by 90 deg moves each point by sqrt(2): RMSE sqrt(2)
    assert math.isclose(registration_rmse(src, yaw_transform(np.pi / 2), np.eye(4)), math.sqrt(2))
    assert not registration_success(src, yaw_transform(np.pi / 2), np.eye(4))


def test_two_agent_success():
    assert two_agent_success(yaw_transform(np.radians(4), (0.3, 0.3, 0)), np.eye(4))
    assert not two_agent_success(yaw_transform(np.radians(6)), np.eye(4))
    assert not two_agent_success(yaw_transform(0, (0.4, 0.4, 0)), np.eye(4))  # 0.566 m


def test_inlier_ratio():
    T = yaw_transform(0, (1, 0, 0))
    src = np.zeros((4, 3))
    ref = np.array([[1.0, 0, 0], [1.05, 0, 0], [1.2, 0, 0], [5, 0, 0]])
    assert inlier_ratio(src, ref, T) == 0.5
    assert inlier_ratio(np.zeros((0, 3)), np.zeros((0, 3)), T) == 0.0


def test_node_match_scores():
    gt = np.array([[1, 10], [2, 20], [3, 30], [4, 40]])
    iou = np.array([0.9, 0.5, 0.31, 0.2])          # the last one is below 0.3: not a gt match
    pred = np.array([[1, 10], [2, 30], [4, 40], [3, 30]])
    s = node_match_scores(pred, gt, iou)
    assert (s.true_positives, s.predicted, s.ground_truth) == (2, 4, 3)
    assert math.isclose(s.precision, 0.5) and math.isclose(s.recall, 2 / 3)
    empty = node_match_scores(np.zeros((0, 2)), gt, iou)
    assert math.isnan(empty.precision) and empty.recall == 0.0
