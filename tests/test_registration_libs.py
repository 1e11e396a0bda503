"""Registration's library parts against independent references: open3d normals against a brute-force
PCA, the numpy point-to-plane ICP where open3d's solver is unguarded, and the numpy RANSAC against
open3d's on the same correspondences."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from idsplat_ns._compat.libusb import ensure_loadable
from idsplat_ns.data.geometry import make_pose
from idsplat_ns.instances.registration import (
    RegistrationConfig,
    estimate_normals,
    icp_point_to_plane,
    register,
    surface_normals,
)


def _car(rng: np.random.Generator, n: int, noise: float = 0.01) -> np.ndarray:  # -> [n, 3] on a car-sized box
    half = np.array([2.25, 0.9, 0.75])
    pts = rng.uniform(-1, 1, (n, 3)) * half
    face = rng.integers(0, 3, n)
    pts[np.arange(n), face] = np.sign(pts[np.arange(n), face]) * half[face]
    return pts + [20.0, -5.0, 0.8] + rng.normal(scale=noise, size=pts.shape)


def _brute_force_pca(points: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:  # -> [N, 3] desc, [N, 3, 3] rows
    """Eigen-decomposition of each point's k-nearest-neighbour covariance, neighbours by a full sort."""
    d = np.linalg.norm(points[:, None] - points[None], axis=-1)
    idx = np.argsort(d, axis=1, kind="stable")[:, : min(k, len(points))]
    nb = points[idx] - points[idx].mean(1, keepdims=True)
    eig, axes = np.linalg.eigh(np.einsum("nki,nkj->nij", nb, nb) / nb.shape[1])
    return eig[:, ::-1], np.swapaxes(axes[:, :, ::-1], 1, 2)


def _clouds() -> dict[str, np.ndarray]:
    rng = np.random.default_rng(0)
    return {
        "car": _car(rng, 600),
        "far car": _car(rng, 400, 0.002) + [8000.0, -6000.0, 30.0],  # open3d's one-pass covariance needs centring
        "noisy plane": np.c_[rng.uniform(-2, 2, 300), rng.normal(0, 0.005, 300), rng.uniform(0, 1.5, 300)],
        "blob": rng.normal(size=(200, 3)),
        "fewer than k": rng.normal(size=(7, 3)),
        "duplicated": np.repeat(rng.normal(size=(40, 3)), 3, 0),
    }


@pytest.mark.parametrize("name", list(_clouds()))
def test_normals_match_a_brute_force_pca(name):
    points = _clouds()[name]
    eig, axes = _brute_force_pca(points, 12)
    # Where the two smallest eigenvalues (nearly) coincide the normal is any vector of a plane.
    defined = (eig[:, 1] - eig[:, 2]) > 1e-6 * np.maximum(eig[:, 0], 1e-300)
    assert defined.mean() > 0.9
    dot = np.abs(np.sum(estimate_normals(points) * axes[:, 2], 1))
    np.testing.assert_allclose(dot[defined], 1.0, atol=1e-6)
    # The surface test: the same points have a normal, along the same axis.
    ours = surface_normals(points)
    surface = (eig[:, 1] > 0.05 * np.maximum(eig[:, 0], 1e-12)) & (eig[:, 2] <= 0.3 * eig[:, 1])
    np.testing.assert_array_equal(np.any(ours != 0, 1), surface)
    np.testing.assert_allclose(np.abs(np.sum(ours * axes[:, 2], 1))[surface & defined], 1.0, atol=1e-6)


def test_a_line_has_no_surface_normal():
    line = np.outer(np.linspace(0, 5, 30), [1.0, 0.0, 0.0]) + [3.0, 2.0, 1.0]
    assert np.all(surface_normals(line) == 0.0)
    n = estimate_normals(line)  # any unit vector across the line
    np.testing.assert_allclose(np.linalg.norm(n, axis=1), 1.0, atol=1e-9)
    np.testing.assert_allclose(n[:, 0], 0.0, atol=1e-6)


def test_icp_corrects_an_exact_plane_only_along_its_normal():
    """A flat wall 5 cm off along its normal: the offset is the only observable motion, so ICP must
    move the source 5 cm along y and nothing else (open3d's registration_icp solves the singular
    normal equations by LDLT and slid the wall tens of centimetres along itself)."""
    rng = np.random.default_rng(1)
    wall = lambda n: np.c_[rng.uniform(-2, 2, n), np.zeros(n), rng.uniform(0, 1.5, n)] + [20.0, -5.0, 0.0]
    src, tgt = wall(600), wall(300) + [0.0, 0.05, 0.0]
    T = icp_point_to_plane(np.eye(4), src, tgt, iterations=10, max_distance=0.3)
    np.testing.assert_allclose(T[:3, :3], np.eye(3), atol=1e-9)
    np.testing.assert_allclose(T[:3, 3], [0.0, 0.05, 0.0], atol=1e-9)


def test_icp_keeps_the_pose_with_fewer_than_six_pairs():
    rng = np.random.default_rng(2)
    src = _car(rng, 60, 0.0)
    turn = Rotation.from_rotvec([0.0, 0.0, 0.01]).as_matrix()  # about the car, 3 cm off
    start = make_pose(turn, src.mean(0) - turn @ src.mean(0) + [0.03, 0.0, 0.0])
    # Twelve target points, five of them near the source: five pairs cannot fix six degrees of
    # freedom (open3d's registration_icp solves them anyway and moves the car).
    tgt = np.concatenate([src[:5] + rng.normal(scale=0.01, size=(5, 3)), src[5:12] + [0.0, 0.0, 5.0]])
    moved = src @ start[:3, :3].T + start[:3, 3]
    assert np.sum(np.linalg.norm(tgt[:, None] - moved[None], axis=-1).min(1) < 0.3) == 5
    np.testing.assert_array_equal(icp_point_to_plane(start, src, tgt, 10, 0.3), start)


def test_ransac_agrees_with_open3d_on_the_same_correspondences():
    """The paper's RANSAC (no tilt limit, no back-face test, no ICP) and open3d's
    registration_ransac_based_on_correspondence on noisy correspondences, half of them wrong: both
    find every true inlier and a pose within a few centimetres."""
    ensure_loadable()
    import open3d as o3d

    reg = o3d.pipelines.registration
    cfg = RegistrationConfig(max_tilt=None, back_face_tolerance=None, icp_iterations=0, rescore_top_k=1, refine_iterations=0)
    rng = np.random.default_rng(3)
    for trial in range(6):
        truth = make_pose(Rotation.from_rotvec([0.0, 0.0, rng.uniform(-np.pi, np.pi)]).as_matrix(), rng.normal(size=3) * [3, 3, 0.05])
        cs = _car(rng, 150, 0.0)
        ct = cs @ truth[:3, :3].T + truth[:3, 3] + rng.normal(scale=0.01, size=cs.shape)
        bad = rng.random(len(cs)) < 0.5
        ct[bad] = ct[rng.permutation(np.flatnonzero(bad))] + rng.normal(scale=0.5, size=(bad.sum(), 3))
        feat = rng.normal(size=(len(cs), 16))
        ours = register(cs, feat, ct, feat, replace(cfg, seed=trial)).transform
        o3d.utility.random.seed(trial)
        pairs = o3d.utility.Vector2iVector(np.repeat(np.arange(len(cs), dtype=np.int32)[:, None], 2, 1))
        theirs = np.asarray(reg.registration_ransac_based_on_correspondence(
            o3d.geometry.PointCloud(o3d.utility.Vector3dVector(cs)), o3d.geometry.PointCloud(o3d.utility.Vector3dVector(ct)),
            pairs, cfg.inlier_distance, reg.TransformationEstimationPointToPoint(False), 3, [],
            reg.RANSACConvergenceCriteria(cfg.max_iterations, cfg.confidence)).transformation)
        inliers = [int(np.sum(np.linalg.norm(cs @ T[:3, :3].T + T[:3, 3] - ct, axis=1) < cfg.inlier_distance))
                   for T in (ours, theirs, truth)]
        assert abs(inliers[0] - inliers[2]) <= 1 and abs(inliers[1] - inliers[2]) <= 1, inliers
        for T in (ours, theirs):
            assert np.linalg.norm(cs @ (T[:3, :3] - truth[:3, :3]).T + (T[:3, 3] - truth[:3, 3]), axis=1).mean() < 0.05
