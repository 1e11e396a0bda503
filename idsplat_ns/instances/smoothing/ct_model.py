"""Coordinated-turn (CT) motion maths: increments, propagation, factor residuals and their Jacobians.

Pure numpy, float64. Conventions:

* A pose is a 4x4 matrix ``T`` (object canonical frame -> world). Its perturbation is on the right,
  ``T -> T * Exp(xi)`` with ``xi = [omega, rho]`` (rotation first), which is GTSAM's Pose3 chart to
  first order; a rotation ``R -> R * Exp(phi)`` likewise (Rot3).
* The *motion frame* of a state is ``M = T * S`` where ``S`` is the rotation shared by all times
  (no translation): in the motion frame x is forward and z is up.
* One CT step of duration dt with speed v and curvature kappa turns by ``theta = kappa * v * dt``
  about the motion frame's z and moves by ``[sin(theta)/kappa, (1 - cos(theta))/kappa, 0]`` in it.
  Both are written as ``s * f(theta)``, ``s * g(theta)`` with the arc length ``s = v * dt``,
  ``f = sin(x)/x``, ``g = (1 - cos(x))/x``, and series forms near zero, so that kappa -> 0 and
  v -> 0 never divide by zero.
"""

from __future__ import annotations

import math

import numpy as np

from idsplat_ns.data.geometry import invert_pose, make_pose, rot_z, skew, so3_log

# Below this |theta| the series forms are used: their truncation error is O(theta^6) < 1e-18.
SERIES_THRESHOLD = 1e-3


def so3_right_jacobian_inv(w: np.ndarray) -> np.ndarray:  # w: [3] -> [3, 3]
    """``Jr^-1(w)``: maps a right perturbation of ``Exp(w)`` to the change of ``w``."""
    theta2 = float(w @ w)
    theta = math.sqrt(theta2)
    W = skew(w)
    if theta < 1e-4:
        c = 1.0 / 12.0 + theta2 / 720.0
    else:
        c = 1.0 / theta2 - (1.0 + math.cos(theta)) / (2.0 * theta * math.sin(theta))
    return np.eye(3) + 0.5 * W + c * (W @ W)


def _sinc_terms(x: float) -> tuple[float, float, float, float]:
    """``f = sin(x)/x``, ``f'``, ``g = (1 - cos x)/x``, ``g'``; series forms for small ``|x|``."""
    if abs(x) < SERIES_THRESHOLD:
        x2 = x * x
        f = 1.0 - x2 / 6.0 + x2 * x2 / 120.0
        df = -x / 3.0 + x * x2 / 30.0
        g = x / 2.0 - x * x2 / 24.0 + x * x2 * x2 / 720.0
        dg = 0.5 - x2 / 8.0 + x2 * x2 / 144.0
        return f, df, g, dg
    s, c = math.sin(x), math.cos(x)
    f = s / x
    g = (1.0 - c) / x
    df = (x * c - s) / (x * x)
    dg = (x * s - (1.0 - c)) / (x * x)
    return f, df, g, dg


def ct_increment(v: float, kappa: float, dt: float) -> tuple[float, float, float]:
    """``(theta, dx, dy)`` of one CT step: heading change and planar displacement in the motion frame.

    ``dx = sin(theta)/kappa``, ``dy = (1 - cos(theta))/kappa`` with ``theta = kappa v dt``, computed
    without dividing by ``kappa`` (finite for kappa = 0, v = 0, dt = 0).
    """
    theta = kappa * v * dt
    f, _, g, _ = _sinc_terms(theta)
    arc = v * dt
    return theta, arc * f, arc * g


def ct_increment_jacobian(v: float, kappa: float, dt: float) -> np.ndarray:  # -> [3, 2]
    """Derivatives of ``(theta, dx, dy)`` with respect to ``(v, kappa)``."""
    theta = kappa * v * dt
    f, df, g, dg = _sinc_terms(theta)
    arc = v * dt
    dtheta_dv, dtheta_dk = kappa * dt, v * dt
    return np.array(
        [
            [dtheta_dv, dtheta_dk],
            [dt * f + arc * df * dtheta_dv, arc * df * dtheta_dk],
            [dt * g + arc * dg * dtheta_dv, arc * dg * dtheta_dk],
        ]
    )


def ct_delta_pose(v: float, kappa: float, dt: float) -> np.ndarray:  # -> [4, 4]
    """The CT step as a 4x4 transform in the motion frame (``dt`` may be negative: backwards)."""
    theta, dx, dy = ct_increment(v, kappa, dt)
    delta = np.eye(4)
    delta[:3, :3] = rot_z(theta)
    delta[:3, 3] = (dx, dy, 0.0)
    return delta


def shared_rotation_pose(shared: np.ndarray) -> np.ndarray:  # shared: [3, 3] -> [4, 4]
    """The shared rotation as a 4x4 transform without translation."""
    return make_pose(shared, np.zeros(3))


def ct_propagate(
    pose: np.ndarray,  # [4, 4] state pose T (canonical -> world)
    shared: np.ndarray,  # [3, 3] shared rotation S
    v: float,
    kappa: float,
    dt: float,
) -> np.ndarray:  # [4, 4]
    """Pose ``dt`` seconds after the state ``pose``: ``T' = T S Delta(v, kappa, dt) S^-1``."""
    S = shared_rotation_pose(shared)
    return pose @ S @ ct_delta_pose(v, kappa, dt) @ invert_pose(S)


def motion_residual(
    pose0: np.ndarray,  # [4, 4] state pose at t
    pose1: np.ndarray,  # [4, 4] state pose at t + dt
    v: float,
    kappa: float,
    shared: np.ndarray,  # [3, 3] shared rotation
    dt: float,
    jacobians: bool = True,
) -> tuple[np.ndarray, list[np.ndarray] | None]:
    """Deviation of the state at ``t + dt`` from the CT prediction made at ``t``.

    With motion frames ``M_i = T_i S``: rotation error ``Log(Rz(theta)^T R_M0^T R_M1)`` and
    translation error ``R_M0^T (p1 - p0) - [dx, dy, 0]`` (expressed in the earlier motion frame).
    Returns the 6-vector ``[rotation; translation]`` and, if asked, its Jacobians with respect to
    ``pose0`` [6, 6], ``pose1`` [6, 6], ``v`` [6, 1], ``kappa`` [6, 1] and ``shared`` [6, 3].
    """
    R0, p0 = pose0[:3, :3], pose0[:3, 3]
    R1, p1 = pose1[:3, :3], pose1[:3, 3]
    S = shared
    theta, dx, dy = ct_increment(v, kappa, dt)
    Rz = rot_z(theta)
    A = S.T @ R0.T @ R1 @ S  # relative rotation between the motion frames
    E = Rz.T @ A
    e_rot = so3_log(E)
    d = p1 - p0
    q = S.T @ (R0.T @ d)  # displacement in the earlier motion frame
    e_trans = q - np.array([dx, dy, 0.0])
    err = np.concatenate([e_rot, e_trans])
    if not jacobians:
        return err, None
    Jinv = so3_right_jacobian_inv(e_rot)
    J_inc = ct_increment_jacobian(v, kappa, dt)  # [3, 2]: (theta, dx, dy) by (v, kappa)
    H0 = np.zeros((6, 6))
    H0[:3, :3] = -Jinv @ A.T @ S.T
    H0[3:, :3] = S.T @ skew(R0.T @ d)
    H0[3:, 3:] = -S.T
    H1 = np.zeros((6, 6))
    H1[:3, :3] = Jinv @ S.T
    H1[3:, 3:] = S.T @ R0.T @ R1
    de_dtheta = np.concatenate([-Jinv @ E.T @ np.array([0.0, 0.0, 1.0]), np.zeros(3)])
    de_dxy = np.zeros((6, 2))  # d err / d (dx, dy)
    de_dxy[3, 0] = -1.0
    de_dxy[4, 1] = -1.0
    H_vk = np.outer(de_dtheta, J_inc[0]) + de_dxy @ J_inc[1:]  # [6, 2]
    HS = np.zeros((6, 3))
    HS[:3, :] = Jinv @ (np.eye(3) - A.T)
    HS[3:, :] = skew(q)
    return err, [H0, H1, H_vk[:, :1].copy(), H_vk[:, 1:].copy(), HS]


def tilt_residual(
    pose: np.ndarray,  # [4, 4] state pose
    shared: np.ndarray,  # [3, 3] shared rotation
    jacobians: bool = True,
) -> tuple[np.ndarray, list[np.ndarray] | None]:
    """Roll/pitch residual of the motion frame ``R_M = R S``: ``[cos(pitch) sin(roll), sin(pitch)]``.

    These are the world up axis' y and -x components in the motion frame (ZYX Euler angles); they
    equal roll and pitch to first order, are smooth everywhere and bounded, so the prior never
    meets the pitch = 90 degree singularity of Euler angles. Jacobians: pose [2, 6], shared [2, 3].
    """
    R_M = pose[:3, :3] @ shared
    up = R_M[2, :]  # world z in motion-frame coordinates
    err = np.array([up[1], -up[0]])
    if not jacobians:
        return err, None
    # Right perturbation R_M -> R_M Exp(delta) changes ``up`` by [up]x delta.
    d_up = skew(up)
    sel = np.array([d_up[1], -d_up[0]])  # [2, 3]
    H_pose = np.zeros((2, 6))
    H_pose[:, :3] = sel @ shared.T  # delta = S^T omega for a perturbation of the pose
    return err, [H_pose, sel.copy()]


def roll_pitch(rotation: np.ndarray) -> tuple[float, float]:  # rotation: [3, 3]
    """ZYX-Euler roll and pitch [rad] of a rotation."""
    up = rotation[2, :]
    return math.atan2(up[1], up[2]), math.asin(max(-1.0, min(1.0, -up[0])))


def ground_height_residual(
    pose0: np.ndarray,  # [4, 4] state pose at step i
    pose1: np.ndarray,  # [4, 4] state pose at step i + 1
    ground_rise: float,  # metres the ground rises from under pose0 to under pose1
    jacobians: bool = True,
) -> tuple[np.ndarray, list[np.ndarray] | None]:
    """How much more the vehicle rises between two steps than the ground under it:
    ``[(p1_z - p0_z) - ground_rise]``. Jacobians (GTSAM's right perturbation, translation moved
    by ``R dv``): pose0 [1, 6] and pose1 [1, 6], over ``[rotation; translation]``."""
    err = np.array([pose1[2, 3] - pose0[2, 3] - ground_rise])
    if not jacobians:
        return err, None
    H0 = np.zeros((1, 6))
    H1 = np.zeros((1, 6))
    H0[0, 3:] = -pose0[2, :3]
    H1[0, 3:] = pose1[2, :3]
    return err, [H0, H1]
