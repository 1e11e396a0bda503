import numpy as np
from scipy.spatial.transform import Rotation

from idsplat_ns.data.geometry import (
    interpolate_poses, invert_pose, make_pose, quat_to_rotmat, rot_z, rotmat_to_quat, slerp_quat, transform_points,
)


def test_quaternion_conversions_match_scipy():
    rng = np.random.default_rng(0)
    q = rng.normal(size=(200, 4))
    q[:3] = [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 0, 1]]  # identity and 180-degree turns
    R = quat_to_rotmat(q)
    ref = Rotation.from_quat(q[:, [1, 2, 3, 0]]).as_matrix()  # scipy is xyzw
    np.testing.assert_allclose(R, ref, atol=1e-12)
    back = rotmat_to_quat(R)
    qn = q / np.linalg.norm(q, axis=1, keepdims=True)
    qn *= np.sign(qn[:, :1] + 1e-300)
    np.testing.assert_allclose(np.abs(np.sum(back * qn, 1)), 1.0, atol=1e-10)
    np.testing.assert_allclose(quat_to_rotmat(back), R, atol=1e-12)


def test_invert_and_transform():
    rng = np.random.default_rng(1)
    T = make_pose(Rotation.random(random_state=2).as_matrix(), rng.normal(size=3) * 1e4)
    np.testing.assert_allclose(invert_pose(T) @ T, np.eye(4), atol=1e-9)
    p = rng.normal(size=(5, 3))
    np.testing.assert_allclose(transform_points(invert_pose(T), transform_points(T, p)), p, atol=1e-9)


def test_rot_z_is_counter_clockwise():
    np.testing.assert_allclose(rot_z(np.pi / 2) @ [1, 0, 0], [0, 1, 0], atol=1e-12)


def test_slerp_matches_scipy_and_interpolate_poses():
    r0, r1 = Rotation.from_euler("z", 10, degrees=True), Rotation.from_euler("xyz", [20, -30, 80], degrees=True)
    q0, q1 = r0.as_quat()[[3, 0, 1, 2]], r1.as_quat()[[3, 0, 1, 2]]
    from scipy.spatial.transform import Slerp

    ref = Slerp([0, 1], Rotation.concatenate([r0, r1]))([0.25, 0.7]).as_matrix()
    got = quat_to_rotmat(slerp_quat(np.stack([q0, q0]), np.stack([q1, q1]), np.array([0.25, 0.7])))
    np.testing.assert_allclose(got, ref, atol=1e-10)
    poses = make_pose(np.stack([r0.as_matrix(), r1.as_matrix()]), np.array([[0, 0, 0], [10, 0, 0.0]]))
    mid = interpolate_poses(np.array([0.0, 2.0]), poses, np.array([0.5, -1.0, 3.0]))
    np.testing.assert_allclose(mid[0, :3, 3], [2.5, 0, 0])
    np.testing.assert_allclose(mid[1], poses[0], atol=1e-12)  # clamped before the span
    np.testing.assert_allclose(mid[2], poses[1], atol=1e-12)  # clamped after it


def test_wrap_angle_and_yaw_of():
    from idsplat_ns.data.geometry import wrap_angle, yaw_of

    angles = np.array([-7.0, -np.pi, -0.3, 0.0, np.pi - 1e-9, np.pi, 4.0, 12.0])
    wrapped = wrap_angle(angles)
    assert np.all((wrapped >= -np.pi) & (wrapped < np.pi))
    np.testing.assert_allclose(np.sin(wrapped), np.sin(angles), atol=1e-12)
    np.testing.assert_allclose(np.cos(wrapped), np.cos(angles), atol=1e-12)
    # heading of the x axis, against scipy's intrinsic Z-Y-X Euler angles (yaw, pitch, roll)
    rng = np.random.default_rng(0)
    euler = np.c_[rng.uniform(-np.pi, np.pi, 20), rng.uniform(-0.5, 0.5, 20), rng.uniform(-0.5, 0.5, 20)]
    R = Rotation.from_euler("ZYX", euler).as_matrix()
    np.testing.assert_allclose(yaw_of(R), euler[:, 0], atol=1e-12)
    T = np.tile(np.eye(4), (20, 1, 1))
    T[:, :3, :3] = R
    np.testing.assert_allclose(yaw_of(T), euler[:, 0], atol=1e-12)
