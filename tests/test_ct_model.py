"""CT motion maths: closed forms, series forms at the extremes, propagation, and the analytic
Jacobians of the factor residuals against central finite differences in GTSAM's own charts."""

from __future__ import annotations

import math

import gtsam
import numpy as np
import pytest

from idsplat_ns.instances.smoothing import factors as F
from idsplat_ns.instances.smoothing.config import SmoothingConfig
from idsplat_ns.data.geometry import rot_z, so3_exp, so3_log
from idsplat_ns.instances.smoothing.ct_model import (
    ct_delta_pose,
    ct_increment,
    ct_increment_jacobian,
    ct_propagate,
    ground_height_residual,
    motion_residual,
    roll_pitch,
    so3_right_jacobian_inv,
    tilt_residual,
)


def _random_pose(rng: np.random.Generator, scale: float = 5.0) -> np.ndarray:
    pose = np.eye(4)
    pose[:3, :3] = so3_exp(rng.normal(size=3))
    pose[:3, 3] = rng.normal(size=3) * scale
    return pose


@pytest.mark.parametrize(
    "v,kappa,dt",
    [(10.0, 0.05, 0.1), (3.0, -0.2, 0.5), (15.0, 0.3, 1.0), (-4.0, 0.1, 0.1), (8.0, 2.0, 0.4)],
)
def test_increment_matches_closed_form(v: float, kappa: float, dt: float) -> None:
    theta, dx, dy = ct_increment(v, kappa, dt)
    assert theta == pytest.approx(kappa * v * dt, rel=1e-15)
    assert dx == pytest.approx(math.sin(theta) / kappa, rel=1e-12)
    assert dy == pytest.approx((1.0 - math.cos(theta)) / kappa, rel=1e-12)


def test_increment_series_continuous_across_threshold_and_exact_at_zero() -> None:
    # theta just below and above the series threshold (1e-3): both branches agree to ~1e-15 relative.
    v, dt = 10.0, 0.1
    for theta in [0.999e-3, 1.001e-3, -0.999e-3, -1.001e-3]:
        kappa = theta / (v * dt)
        _, dx, dy = ct_increment(v, kappa, dt)
        assert dx == pytest.approx(math.sin(theta) / kappa, rel=1e-13)
        assert dy == pytest.approx((1.0 - math.cos(theta)) / kappa, rel=1e-9)  # 1 - cos loses digits; series does not
    # kappa = 0: straight line of length v dt, no NaN.
    assert ct_increment(v, 0.0, dt) == (0.0, pytest.approx(1.0), 0.0)
    # kappa -> 0: dy -> kappa (v dt)^2 / 2 exactly (series), where 1 - cos would give 0.
    _, _, dy = ct_increment(v, 1e-12, dt)
    assert dy == pytest.approx(0.5e-12, rel=1e-9)
    # v = 0 and dt = 0: no motion at all.
    assert ct_increment(0.0, 0.3, dt) == (0.0, 0.0, 0.0)
    assert ct_increment(v, 0.3, 0.0) == (0.0, 0.0, 0.0)


def test_full_circle_returns_to_start() -> None:
    kappa, v = 0.1, 5.0
    dt = 2.0 * math.pi / (kappa * v)  # one full turn of radius 10 m
    delta = ct_delta_pose(v, kappa, dt)
    np.testing.assert_allclose(delta, np.eye(4), atol=1e-12)
    quarter = ct_delta_pose(v, kappa, dt / 4.0)
    np.testing.assert_allclose(quarter[:3, 3], [10.0, 10.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(quarter[:3, :3], rot_z(math.pi / 2.0), atol=1e-12)


def test_propagation_composes_and_inverts() -> None:
    rng = np.random.default_rng(0)
    pose, shared = _random_pose(rng), so3_exp(rng.normal(size=3))
    v, kappa = 7.0, 0.08
    two_steps = ct_propagate(ct_propagate(pose, shared, v, kappa, 0.3), shared, v, kappa, 0.5)
    np.testing.assert_allclose(two_steps, ct_propagate(pose, shared, v, kappa, 0.8), atol=1e-12)
    np.testing.assert_allclose(ct_propagate(ct_propagate(pose, shared, v, kappa, 0.4), shared, v, kappa, -0.4), pose, atol=1e-12)


def test_increment_jacobian_finite_differences() -> None:
    for v, kappa, dt in [(10.0, 0.05, 0.1), (10.0, 1e-7, 0.1), (0.0, 0.1, 0.1), (3.0, 0.0, 1e-6), (12.0, 0.4, 2.0)]:
        J = ct_increment_jacobian(v, kappa, dt)
        h = 1e-6
        num = np.stack(
            [
                (np.array(ct_increment(v + h, kappa, dt)) - np.array(ct_increment(v - h, kappa, dt))) / (2 * h),
                (np.array(ct_increment(v, kappa + h, dt)) - np.array(ct_increment(v, kappa - h, dt))) / (2 * h),
            ],
            axis=1,
        )
        np.testing.assert_allclose(J, num, atol=1e-7, rtol=1e-6)


def test_so3_log_exp_roundtrip_including_near_pi_and_zero() -> None:
    rng = np.random.default_rng(1)
    for w in [np.zeros(3), np.array([1e-9, 0, 0]), rng.normal(size=3), np.array([0, 0, math.pi - 1e-7]), np.array([math.pi - 1e-4, 0, 0])]:
        R = so3_exp(w)
        np.testing.assert_allclose(so3_log(R), w, atol=1e-8)
        np.testing.assert_allclose(R, gtsam.Rot3.Expmap(w).matrix(), atol=1e-12)


def test_right_jacobian_inverse_matches_gtsam() -> None:
    rng = np.random.default_rng(2)
    for w in [rng.normal(size=3), np.array([1e-6, 2e-6, 0.0]), np.array([0.0, 0.0, 3.0])]:
        # gtsam's LogmapDerivative is Jr^-1 of the rotation vector.
        H = np.zeros((3, 3), order="F")
        gtsam.Rot3.Logmap(gtsam.Rot3.Expmap(w), H)
        np.testing.assert_allclose(so3_right_jacobian_inv(w), H, atol=1e-9)


def _pose_fd(fn, pose: np.ndarray, h: float = 1e-6) -> np.ndarray:
    """Central differences of ``fn(pose)`` in GTSAM's Pose3 chart (``retract``)."""
    cols = []
    p = gtsam.Pose3(pose)
    for k in range(6):
        e = np.zeros(6)
        e[k] = h
        cols.append((fn(p.retract(e).matrix()) - fn(p.retract(-e).matrix())) / (2 * h))
    return np.stack(cols, axis=1)


def _rot_fd(fn, rot: np.ndarray, h: float = 1e-6) -> np.ndarray:
    cols = []
    r = gtsam.Rot3(rot)
    for k in range(3):
        e = np.zeros(3)
        e[k] = h
        cols.append((fn(r.retract(e).matrix()) - fn(r.retract(-e).matrix())) / (2 * h))
    return np.stack(cols, axis=1)


@pytest.mark.parametrize("case", ["generic", "straight", "stopped", "tiny_dt", "far_away"])
def test_motion_residual_jacobians_finite_differences(case: str) -> None:
    rng = np.random.default_rng(3)
    v, kappa, dt, scale = {"generic": (8.0, 0.07, 0.1, 5.0), "straight": (12.0, 0.0, 0.1, 5.0),
                           "stopped": (0.0, 0.02, 0.1, 5.0), "tiny_dt": (9.0, 0.1, 1e-6, 5.0),
                           "far_away": (10.0, 0.05, 0.1, 1e5)}[case]
    shared = so3_exp(rng.normal(size=3))
    pose0 = _random_pose(rng, scale)
    # A state near the prediction with a perturbation, like in a real optimisation.
    pose1 = ct_propagate(pose0, shared, v, kappa, dt) @ gtsam.Pose3.Expmap(rng.normal(size=6) * 0.1).matrix()
    err, H = motion_residual(pose0, pose1, v, kappa, shared, dt)
    assert np.all(np.isfinite(err))
    tol = dict(atol=1e-5 * max(1.0, scale / 1e3), rtol=1e-5)
    np.testing.assert_allclose(H[0], _pose_fd(lambda P: motion_residual(P, pose1, v, kappa, shared, dt, False)[0], pose0), **tol)
    np.testing.assert_allclose(H[1], _pose_fd(lambda P: motion_residual(pose0, P, v, kappa, shared, dt, False)[0], pose1), **tol)
    h = 1e-6
    num_v = (motion_residual(pose0, pose1, v + h, kappa, shared, dt, False)[0] - motion_residual(pose0, pose1, v - h, kappa, shared, dt, False)[0]) / (2 * h)
    num_k = (motion_residual(pose0, pose1, v, kappa + h, shared, dt, False)[0] - motion_residual(pose0, pose1, v, kappa - h, shared, dt, False)[0]) / (2 * h)
    np.testing.assert_allclose(H[2][:, 0], num_v, atol=1e-6)
    np.testing.assert_allclose(H[3][:, 0], num_k, atol=1e-6)
    np.testing.assert_allclose(H[4], _rot_fd(lambda R: motion_residual(pose0, pose1, v, kappa, R, dt, False)[0], shared), **tol)


def test_motion_residual_zero_on_exact_ct_motion() -> None:
    rng = np.random.default_rng(4)
    shared, pose0 = so3_exp(rng.normal(size=3)), _random_pose(rng)
    pose1 = ct_propagate(pose0, shared, 11.0, -0.04, 0.1)
    err, _ = motion_residual(pose0, pose1, 11.0, -0.04, shared, 0.1, jacobians=False)
    np.testing.assert_allclose(err, 0.0, atol=1e-12)


def test_tilt_residual_values_and_jacobians() -> None:
    rng = np.random.default_rng(5)
    shared, pose = so3_exp(rng.normal(size=3) * 0.5), _random_pose(rng)
    err, H = tilt_residual(pose, shared)
    roll, pitch = roll_pitch(pose[:3, :3] @ shared)
    np.testing.assert_allclose(err, [math.cos(pitch) * math.sin(roll), math.sin(pitch)], atol=1e-12)
    np.testing.assert_allclose(H[0], _pose_fd(lambda P: tilt_residual(P, shared, False)[0], pose), atol=1e-7)
    np.testing.assert_allclose(H[1], _rot_fd(lambda R: tilt_residual(pose, R, False)[0], shared), atol=1e-7)
    # A level motion frame (yaw only) has zero tilt.
    level = np.eye(4)
    level[:3, :3] = rot_z(1.2)
    np.testing.assert_allclose(tilt_residual(level, np.eye(3), False)[0], 0.0, atol=1e-15)


def test_custom_factors_linearize_like_their_residuals() -> None:
    """The GTSAM CustomFactor wrappers hand GTSAM the same whitened Jacobians as the maths."""
    rng = np.random.default_rng(6)
    config = SmoothingConfig()
    shared, pose0 = so3_exp(rng.normal(size=3)), _random_pose(rng)
    pose1 = ct_propagate(pose0, shared, 9.0, 0.03, 0.1) @ gtsam.Pose3.Expmap(rng.normal(size=6) * 0.05).matrix()
    values = gtsam.Values()
    values.insert(F.pose_key(0), gtsam.Pose3(pose0))
    values.insert(F.pose_key(1), gtsam.Pose3(pose1))
    values.insert(F.speed_key(0), 9.0)
    values.insert(F.curvature_key(0), 0.03)
    values.insert(F.SHARED_KEY, gtsam.Rot3(shared))
    factor = F.motion_factor(0, 0.1, config)
    err, H = motion_residual(pose0, pose1, 9.0, 0.03, shared, 0.1)
    # Roll/pitch and vertical sigmas apart from the paper's isotropic ones (SmoothingConfig's defaults).
    np.testing.assert_allclose(F.motion_sigmas(config), [0.01, 0.01, 0.1, 0.2, 0.2, 0.02])
    paper = SmoothingConfig(motion_vertical_sigma=None, motion_tilt_sigma=None)
    np.testing.assert_allclose(F.motion_sigmas(paper), [0.1] * 3 + [0.2] * 3)
    whiten = 1.0 / F.motion_sigmas(config)
    assert factor.error(values) == pytest.approx(0.5 * float(np.sum((err * whiten) ** 2)), rel=1e-12)
    A, b = factor.linearize(values).jacobian()
    np.testing.assert_allclose(A, np.hstack(H) * whiten[:, None], atol=1e-9)
    np.testing.assert_allclose(b, -err * whiten, atol=1e-12)


def test_ground_height_residual_values_and_jacobians() -> None:
    """The height change beyond the ground's rise, and its Jacobians against finite differences
    in GTSAM's Pose3 chart; the CustomFactor hands GTSAM the same whitened ones."""
    rng = np.random.default_rng(7)
    pose0, pose1 = _random_pose(rng), _random_pose(rng)
    err, H = ground_height_residual(pose0, pose1, 0.3)
    assert err[0] == pytest.approx(pose1[2, 3] - pose0[2, 3] - 0.3, abs=1e-15)
    np.testing.assert_allclose(H[0], _pose_fd(lambda P: ground_height_residual(P, pose1, 0.3, False)[0], pose0), atol=1e-7)
    np.testing.assert_allclose(H[1], _pose_fd(lambda P: ground_height_residual(pose0, P, 0.3, False)[0], pose1), atol=1e-7)
    values = gtsam.Values()
    values.insert(F.pose_key(3), gtsam.Pose3(pose0))
    values.insert(F.pose_key(4), gtsam.Pose3(pose1))
    factor = F.ground_height_factor(3, 0.3, 0.05)
    A, b = factor.linearize(values).jacobian()
    np.testing.assert_allclose(A, np.hstack(H) / 0.05, atol=1e-9)
    np.testing.assert_allclose(b, -err / 0.05, atol=1e-12)
