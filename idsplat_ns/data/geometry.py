"""Rigid-transform helpers on float64 numpy arrays (host-side geometry, see DESIGN.md).

Quaternions are (w, x, y, z), scalar first, as in PandaSet's ``heading`` and gsplat's ``quats``.
"""

from __future__ import annotations

import math

import numpy as np

# Below this rotation angle the SO(3) exponential and logarithm use their series forms.
SO3_SMALL_ANGLE = 1e-6


def quat_to_rotmat(q: np.ndarray) -> np.ndarray:
    """Unit-normalise and convert quaternions to rotation matrices.

    q: [..., 4] wxyz. Returns [..., 3, 3]. A zero quaternion raises (it is not a rotation).
    """
    q = np.asarray(q, dtype=np.float64)
    norm = np.linalg.norm(q, axis=-1, keepdims=True)
    if np.any(norm < 1e-12):
        raise ValueError("quaternion of zero norm is not a rotation")
    w, x, y, z = np.moveaxis(q / norm, -1, 0)
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
            np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
            np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
        ],
        -2,
    )


def rotmat_to_quat(R: np.ndarray) -> np.ndarray:
    """Rotation matrices [..., 3, 3] to unit quaternions [..., 4] wxyz with w >= 0.

    Uses the largest-diagonal branch (Shepperd) so that it stays accurate near 180 degrees.
    """
    R = np.asarray(R, dtype=np.float64)
    batch = R.shape[:-2]
    m = R.reshape(-1, 3, 3)
    out = np.empty((m.shape[0], 4))
    tr = np.trace(m, axis1=1, axis2=2)
    diag = np.stack([tr, m[:, 0, 0], m[:, 1, 1], m[:, 2, 2]], 1)
    branch = np.argmax(diag, 1)
    for b in range(4):
        s = branch == b
        if not np.any(s):
            continue
        r = m[s]
        if b == 0:
            t = np.sqrt(1.0 + tr[s]) * 2
            q = np.stack([0.25 * t, (r[:, 2, 1] - r[:, 1, 2]) / t, (r[:, 0, 2] - r[:, 2, 0]) / t, (r[:, 1, 0] - r[:, 0, 1]) / t], 1)
        elif b == 1:
            t = np.sqrt(1.0 + r[:, 0, 0] - r[:, 1, 1] - r[:, 2, 2]) * 2
            q = np.stack([(r[:, 2, 1] - r[:, 1, 2]) / t, 0.25 * t, (r[:, 0, 1] + r[:, 1, 0]) / t, (r[:, 0, 2] + r[:, 2, 0]) / t], 1)
        elif b == 2:
            t = np.sqrt(1.0 + r[:, 1, 1] - r[:, 0, 0] - r[:, 2, 2]) * 2
            q = np.stack([(r[:, 0, 2] - r[:, 2, 0]) / t, (r[:, 0, 1] + r[:, 1, 0]) / t, 0.25 * t, (r[:, 1, 2] + r[:, 2, 1]) / t], 1)
        else:
            t = np.sqrt(1.0 + r[:, 2, 2] - r[:, 0, 0] - r[:, 1, 1]) * 2
            q = np.stack([(r[:, 1, 0] - r[:, 0, 1]) / t, (r[:, 0, 2] + r[:, 2, 0]) / t, (r[:, 1, 2] + r[:, 2, 1]) / t, 0.25 * t], 1)
        out[s] = q
    out *= np.where(out[:, :1] < 0, -1.0, 1.0)
    out /= np.linalg.norm(out, axis=1, keepdims=True)
    return out.reshape(*batch, 4)


def make_pose(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Stack rotations [..., 3, 3] and translations [..., 3] into 4x4 poses [..., 4, 4]."""
    R = np.asarray(R, dtype=np.float64)
    t = np.asarray(t, dtype=np.float64)
    T = np.zeros(R.shape[:-2] + (4, 4))
    T[..., :3, :3] = R
    T[..., :3, 3] = t
    T[..., 3, 3] = 1.0
    return T


def invert_pose(T: np.ndarray) -> np.ndarray:
    """Invert rigid transforms [..., 4, 4] exactly (R^T, -R^T t), not by general matrix inversion."""
    T = np.asarray(T, dtype=np.float64)
    Rt = np.swapaxes(T[..., :3, :3], -1, -2)
    return make_pose(Rt, -np.einsum("...ij,...j->...i", Rt, T[..., :3, 3]))


def transform_points(T: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Apply one rigid transform T [4, 4] to points [N, 3]."""
    return np.asarray(points, dtype=np.float64) @ T[:3, :3].T + T[:3, 3]


def wrap_angle(angle: np.ndarray | float) -> np.ndarray:
    """Angles (rad) wrapped to [-pi, pi)."""
    return (np.asarray(angle, dtype=np.float64) + np.pi) % (2 * np.pi) - np.pi


def yaw_of(poses: np.ndarray) -> np.ndarray:  # [..., 4, 4] or [..., 3, 3] -> [...]
    """Heading (rad) of the x axis about +z: ``atan2(R[1, 0], R[0, 0])``."""
    return np.arctan2(poses[..., 1, 0], poses[..., 0, 0])


def rot_z(yaw: np.ndarray | float) -> np.ndarray:
    """Rotations about +z by ``yaw`` radians, counter-clockwise: [..., 3, 3]."""
    yaw = np.asarray(yaw, dtype=np.float64)
    c, s = np.cos(yaw), np.sin(yaw)
    zero, one = np.zeros_like(yaw), np.ones_like(yaw)
    return np.stack([np.stack([c, -s, zero], -1), np.stack([s, c, zero], -1), np.stack([zero, zero, one], -1)], -2)


def slerp_quat(q0: np.ndarray, q1: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Spherical interpolation between unit quaternions q0, q1 [..., 4] with weights w [...] in [0, 1]."""
    q0 = q0 / np.linalg.norm(q0, axis=-1, keepdims=True)
    q1 = q1 / np.linalg.norm(q1, axis=-1, keepdims=True)
    dot = np.sum(q0 * q1, -1)
    q1 = np.where(dot[..., None] < 0, -q1, q1)  # shortest path
    dot = np.abs(dot).clip(-1.0, 1.0)
    theta = np.arccos(dot)
    sin_t = np.sin(theta)
    small = sin_t < 1e-8
    safe = np.where(small, 1.0, sin_t)
    a = np.where(small, 1.0 - w, np.sin((1.0 - w) * theta) / safe)
    b = np.where(small, w, np.sin(w * theta) / safe)
    q = a[..., None] * q0 + b[..., None] * q1
    return q / np.linalg.norm(q, axis=-1, keepdims=True)


def interpolate_poses(times: np.ndarray, poses: np.ndarray, query: np.ndarray, extrapolate: bool = False) -> np.ndarray:
    """Interpolate poses [T, 4, 4] known at increasing ``times`` [T] at ``query`` [M] times.

    Translation is linear and rotation is slerped between the bracketing samples. Outside the
    span, queries are clamped to the end poses (a sensor pose is always defined) or, with
    ``extrapolate``, continued at the end segments' constant velocity (the slerp formula
    extrapolates for weights outside [0, 1]). Returns [M, 4, 4].
    """
    times = np.asarray(times, dtype=np.float64)
    query = np.asarray(query, dtype=np.float64)
    if len(times) == 1:
        return np.repeat(poses[:1], len(query), 0)
    idx = np.clip(np.searchsorted(times, query, side="right") - 1, 0, len(times) - 2)
    span = times[idx + 1] - times[idx]
    w = (query - times[idx]) / np.where(span > 0, span, 1.0)
    if not extrapolate:
        w = np.clip(w, 0.0, 1.0)
    q = rotmat_to_quat(poses[:, :3, :3])
    R = quat_to_rotmat(slerp_quat(q[idx], q[idx + 1], w))
    t = (1 - w)[:, None] * poses[idx, :3, 3] + w[:, None] * poses[idx + 1, :3, 3]
    return make_pose(R, t)


def skew(w: np.ndarray) -> np.ndarray:  # w: [3] -> [3, 3]
    """The cross-product matrix ``[w]x`` with ``[w]x @ u == cross(w, u)``."""
    return np.array([[0.0, -w[2], w[1]], [w[2], 0.0, -w[0]], [-w[1], w[0], 0.0]])


def so3_exp(w: np.ndarray) -> np.ndarray:  # w: [3] -> [3, 3]
    """Rodrigues' formula, exact near zero through the series of its coefficients."""
    theta2 = float(w @ w)
    theta = math.sqrt(theta2)
    if theta < SO3_SMALL_ANGLE:
        a = 1.0 - theta2 / 6.0
        b = 0.5 - theta2 / 24.0
    else:
        a = math.sin(theta) / theta
        b = (1.0 - math.cos(theta)) / theta2
    W = skew(w)
    return np.eye(3) + a * W + b * (W @ W)


def so3_log(R: np.ndarray) -> np.ndarray:  # R: [3, 3] -> [3]
    """Rotation vector of ``R``; stable at zero and at pi."""
    cos_theta = min(1.0, max(-1.0, 0.5 * (np.trace(R) - 1.0)))
    v = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])  # = 2 sin(theta) axis
    sin_theta = 0.5 * float(np.linalg.norm(v))
    theta = math.atan2(sin_theta, cos_theta)
    if theta < SO3_SMALL_ANGLE:
        return 0.5 * v * (1.0 + theta * theta / 6.0)
    if math.pi - theta < 1e-3:
        # Near pi the antisymmetric part vanishes: take the axis from the symmetric part.
        B = 0.5 * (R + R.T) - cos_theta * np.eye(3)  # = (1 - cos) axis axis^T
        k = int(np.argmax(np.diag(B)))
        axis = B[:, k] / math.sqrt(max(B[k, k], 1e-300))
        if axis @ v < 0.0:
            axis = -axis
        return theta * axis / np.linalg.norm(axis)
    return v * (theta / (2.0 * sin_theta))
