"""AsyncCL-v0: the MRCLAM Dataset 6 loader (skipped when the dataset is not present)."""

from __future__ import annotations

import numpy as np
import pytest

from mrcomm_env.asynccl.mrclam import default_path, load_mrclam

pytestmark = pytest.mark.skipif(default_path() is None, reason="MRCLAM Dataset 6 absent (CI has it)")


def test_robot_to_robot_measurements_agree_with_motion_capture():
    d = load_mrclam(duration=300.0)
    truth, s, a, b, z = d["truth"], d["meas_step"], d["meas_a"], d["meas_b"], d["meas_z"]
    assert truth.shape[1:] == (5, 3) and len(s) > 100
    assert np.all(a != b) and np.all(np.diff(s) >= 0)
    diff = truth[s, b, :2] - truth[s, a, :2]
    rng = np.hypot(diff[:, 0], diff[:, 1])
    bearing = np.arctan2(diff[:, 1], diff[:, 0]) - truth[s, a, 2]
    err = (z[:, 1] - bearing + np.pi) % (2 * np.pi) - np.pi
    assert np.median(np.abs(z[:, 0] - rng)) < 0.2  # the paper's sensor model: a few percent of d
    assert np.median(np.abs(err)) < 0.05


def test_odometry_dead_reckoning_follows_ground_truth_over_a_few_seconds():
    d = load_mrclam(duration=120.0)
    truth, odo, dt = d["truth"], d["odometry"], d["dt"]
    x = truth[0].copy()
    for k in range(40):  # 2 s of unicycle integration, eq. (1)
        v, w = odo[k, :, 0], odo[k, :, 1]
        x = np.column_stack([x[:, 0] + v * np.cos(x[:, 2]) * dt, x[:, 1] + v * np.sin(x[:, 2]) * dt, x[:, 2] + w * dt])
    assert np.max(np.hypot(*(x[:, :2] - truth[40, :, :2]).T)) < 0.3
