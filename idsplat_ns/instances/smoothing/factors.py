"""GTSAM factors of the CT smoother: CT motion and roll/pitch priors as ``gtsam.CustomFactor``
(residuals and analytic Jacobians from :mod:`ct_model`), the rest GTSAM's own factors."""

from __future__ import annotations

import math

import gtsam
import numpy as np
from gtsam.symbol_shorthand import K, S, V, X

from idsplat_ns.instances.smoothing.config import SmoothingConfig
from idsplat_ns.instances.smoothing.ct_model import ground_height_residual, motion_residual, tilt_residual

SHARED_KEY = S(0)
"""Key of the rotation shared by all times (Rot3)."""


def pose_key(i: int) -> int:
    """Key of the pose (Pose3) at step ``i``."""
    return X(i)


def speed_key(i: int) -> int:
    """Key of the speed (double) at step ``i``."""
    return V(i)


def curvature_key(i: int) -> int:
    """Key of the curvature (double) at step ``i``."""
    return K(i)


def measurement_covariance(
    config: SmoothingConfig,
    translation_covariance: np.ndarray | None = None,  # [3, 3] in the measurement's own (canonical) frame
) -> np.ndarray:  # -> [6, 6] over ``[rot x3, trans x3]``
    """Covariance of a pose measurement in GTSAM's Pose3 tangent (rotation, then translation in
    the measured pose's frame): the configured sigmas, or the given translation block."""
    cov = np.diag([config.measurement_rot_sigma**2] * 3 + [config.measurement_trans_sigma**2] * 3)
    if translation_covariance is not None:
        cov[3:, 3:] = translation_covariance
    return cov


def measurement_noise(
    config: SmoothingConfig,
    robust: bool = True,
    translation_covariance: np.ndarray | None = None,  # [3, 3]
) -> gtsam.noiseModel.Base:
    """Pose noise ``[rot x3, trans x3]`` of the measurement factors (diagonal unless a translation
    covariance is given), Huber-robust if asked."""
    if translation_covariance is None:
        sigmas = np.array([config.measurement_rot_sigma] * 3 + [config.measurement_trans_sigma] * 3)
        gaussian = gtsam.noiseModel.Diagonal.Sigmas(sigmas)
    else:
        gaussian = gtsam.noiseModel.Gaussian.Covariance(measurement_covariance(config, translation_covariance))
    if not robust:
        return gaussian
    return gtsam.noiseModel.Robust.Create(gtsam.noiseModel.mEstimator.Huber.Create(config.huber_threshold), gaussian)


def measurement_factor(
    i: int,
    measured: np.ndarray,  # [4, 4]
    config: SmoothingConfig,
    translation_covariance: np.ndarray | None = None,  # [3, 3]
) -> gtsam.PriorFactorPose3:
    """Absolute pose measurement at step ``i`` (Huber loss)."""
    return gtsam.PriorFactorPose3(pose_key(i), gtsam.Pose3(measured), measurement_noise(config, True, translation_covariance))


def whitened_measurement_error(
    measured: np.ndarray,  # [4, 4]
    estimate: gtsam.Pose3,
    config: SmoothingConfig,
    translation_covariance: np.ndarray | None = None,  # [3, 3]
) -> float:
    """Mahalanobis norm of ``Local(measured, estimate)`` under the measurement's Gaussian noise
    (no robust loss)."""
    local = gtsam.Pose3(measured).localCoordinates(estimate)
    cov = measurement_covariance(config, translation_covariance)
    return float(np.sqrt(local @ np.linalg.solve(cov, local)))


def motion_sigmas(config: SmoothingConfig) -> np.ndarray:  # -> [6] over [roll, pitch, yaw, x, y, z] of the motion frame
    """Sigmas of the CT motion residual; the tilt and vertical ones where configured apart."""
    tilt = config.motion_rot_sigma if config.motion_tilt_sigma is None else config.motion_tilt_sigma
    vertical = config.motion_trans_sigma if config.motion_vertical_sigma is None else config.motion_vertical_sigma
    return np.array([tilt, tilt, config.motion_rot_sigma, config.motion_trans_sigma, config.motion_trans_sigma, vertical])


def motion_factor(i: int, dt: float, config: SmoothingConfig) -> gtsam.CustomFactor:
    """CT motion factor between the states at steps ``i`` and ``i + 1``, ``dt`` seconds apart."""
    noise = gtsam.noiseModel.Diagonal.Sigmas(motion_sigmas(config))
    keys = [pose_key(i), pose_key(i + 1), speed_key(i), curvature_key(i), SHARED_KEY]

    def error(this: gtsam.CustomFactor, values: gtsam.Values, jac: gtsam.JacobianVector | None) -> np.ndarray:
        err, H = motion_residual(
            values.atPose3(keys[0]).matrix(),
            values.atPose3(keys[1]).matrix(),
            values.atDouble(keys[2]),
            values.atDouble(keys[3]),
            values.atRot3(keys[4]).matrix(),
            dt,
            jacobians=jac is not None,
        )
        if jac is not None:
            for j, h in enumerate(H):
                jac[j] = h
        return err

    return gtsam.CustomFactor(noise, keys, error)


def tilt_factor(i: int, config: SmoothingConfig) -> gtsam.CustomFactor:
    """Roll/pitch prior on the motion frame of step ``i`` (zero mean)."""
    noise = gtsam.noiseModel.Isotropic.Sigma(2, config.roll_pitch_sigma)
    keys = [pose_key(i), SHARED_KEY]

    def error(this: gtsam.CustomFactor, values: gtsam.Values, jac: gtsam.JacobianVector | None) -> np.ndarray:
        err, H = tilt_residual(values.atPose3(keys[0]).matrix(), values.atRot3(keys[1]).matrix(), jacobians=jac is not None)
        if jac is not None:
            jac[0] = H[0]
            jac[1] = H[1]
        return err

    return gtsam.CustomFactor(noise, keys, error)


def ground_height_factor(i: int, ground_rise: float, sigma: float) -> gtsam.CustomFactor:
    """The vehicle's height at step ``i + 1`` minus that at step ``i`` equals the rise of the
    ground under it (``ground_rise`` metres) within ``sigma`` metres: it stays on the road."""
    noise = gtsam.noiseModel.Isotropic.Sigma(1, sigma)
    keys = [pose_key(i), pose_key(i + 1)]

    def error(this: gtsam.CustomFactor, values: gtsam.Values, jac: gtsam.JacobianVector | None) -> np.ndarray:
        err, H = ground_height_residual(values.atPose3(keys[0]).matrix(), values.atPose3(keys[1]).matrix(),
                                        ground_rise, jacobians=jac is not None)
        if jac is not None:
            jac[0] = H[0]
            jac[1] = H[1]
        return err

    return gtsam.CustomFactor(noise, keys, error)


def random_walk_sigma(rate: float, dt: float, config: SmoothingConfig) -> float:
    """``sqrt(rate * dt)`` with ``dt`` floored at ``config.min_noise_dt``."""
    return math.sqrt(rate * max(dt, config.min_noise_dt))


def speed_walk_factor(i: int, dt: float, config: SmoothingConfig) -> gtsam.BetweenFactorDouble:
    """Random walk ``v[i+1] - v[i] ~ N(0, speed_walk_rate * dt)``."""
    noise = gtsam.noiseModel.Isotropic.Sigma(1, random_walk_sigma(config.speed_walk_rate, dt, config))
    return gtsam.BetweenFactorDouble(speed_key(i), speed_key(i + 1), 0.0, noise)


def curvature_walk_factor(i: int, dt: float, config: SmoothingConfig) -> gtsam.BetweenFactorDouble:
    """Random walk ``k[i+1] - k[i] ~ N(0, curvature_walk_rate * dt)``."""
    noise = gtsam.noiseModel.Isotropic.Sigma(1, random_walk_sigma(config.curvature_walk_rate, dt, config))
    return gtsam.BetweenFactorDouble(curvature_key(i), curvature_key(i + 1), 0.0, noise)


def curvature_prior_factor(i: int, config: SmoothingConfig) -> gtsam.PriorFactorDouble:
    """Zero-mean curvature prior at step ``i``."""
    return gtsam.PriorFactorDouble(curvature_key(i), 0.0, gtsam.noiseModel.Isotropic.Sigma(1, config.curvature_sigma))


def weak_speed_prior_factor(speed: float, config: SmoothingConfig) -> gtsam.PriorFactorDouble:
    """Weak prior on the first speed (only matters when the measurements leave it free)."""
    return gtsam.PriorFactorDouble(speed_key(0), speed, gtsam.noiseModel.Isotropic.Sigma(1, config.weak_speed_sigma))


def weak_shared_rotation_prior_factor(shared: np.ndarray, config: SmoothingConfig) -> gtsam.PriorFactorRot3:  # shared: [3, 3]
    """Weak prior on the shared rotation (only matters when the motion leaves it free)."""
    return gtsam.PriorFactorRot3(
        SHARED_KEY, gtsam.Rot3(shared), gtsam.noiseModel.Isotropic.Sigma(3, config.weak_shared_rotation_sigma)
    )


def heading_prior_factor(heading_yaw: float, config: SmoothingConfig) -> gtsam.PriorFactorRot3:
    """Prior that the shared rotation's x axis (the direction of travel in the canonical frame)
    points at ``heading_yaw`` [rad] about the canonical z axis; its tilt is left to the other
    factors (the prior's roll and pitch sigmas are ``weak_shared_rotation_sigma``)."""
    assert config.heading_prior_sigma is not None
    weak = config.weak_shared_rotation_sigma
    sigmas = np.array([weak, weak, config.heading_prior_sigma])
    target = gtsam.Rot3.Yaw(heading_yaw)
    return gtsam.PriorFactorRot3(SHARED_KEY, target, gtsam.noiseModel.Diagonal.Sigmas(sigmas))
