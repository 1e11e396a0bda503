"""SO(3) maths on torch tensors (idsplat_ns/model/so3.py) against SciPy, NumPy and the
entry-by-entry formulas, values and gradients, at zero angle, near pi and in every branch."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from idsplat_ns.data.geometry import so3_exp as np_so3_exp
from idsplat_ns.model import so3
from idsplat_ns.model.so3 import hat, rotmat_to_quat, so3_exp, so3_log

D = torch.float64


def _reference_quat(R: torch.Tensor) -> torch.Tensor:  # R: [N, 3, 3] -> [N, 4]
    """Shepperd's method written out entry by entry: the slow reference of rotmat_to_quat."""
    r = R
    args = torch.stack([1 + r[:, 0, 0] + r[:, 1, 1] + r[:, 2, 2], 1 + r[:, 0, 0] - r[:, 1, 1] - r[:, 2, 2],
                        1 - r[:, 0, 0] + r[:, 1, 1] - r[:, 2, 2], 1 - r[:, 0, 0] - r[:, 1, 1] + r[:, 2, 2]], -1)
    out = []
    for n in range(R.shape[0]):
        b = int(args[n].argmax())
        s = 2 * torch.sqrt(args[n, b])
        m = r[n]
        pairs = {(0, 1): m[2, 1] - m[1, 2], (0, 2): m[0, 2] - m[2, 0], (0, 3): m[1, 0] - m[0, 1],
                 (1, 2): m[0, 1] + m[1, 0], (1, 3): m[0, 2] + m[2, 0], (2, 3): m[1, 2] + m[2, 1]}
        q = [0.25 * s if j == b else pairs[(min(b, j), max(b, j))] / s for j in range(4)]
        q = torch.stack(q)
        out.append(q if q[0] >= 0 else -q)
    return torch.stack(out)


def _rotation_vectors(n: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    w = rng.normal(size=(n, 3))
    w *= (rng.uniform(0, 3.1, n) / np.linalg.norm(w, axis=1))[:, None]  # angles below pi
    w[:3] *= 1e-7  # the small-angle series
    return w


def test_hat_is_the_cross_product():
    w, u = torch.randn(7, 3, dtype=D), torch.randn(7, 3, dtype=D)
    assert torch.allclose((hat(w) @ u[..., None])[..., 0], torch.linalg.cross(w, u), atol=1e-14)


def test_exp_log_and_quaternions_match_numpy_and_scipy():
    w = _rotation_vectors(60)
    R = so3_exp(torch.from_numpy(w))
    assert np.allclose(R.numpy(), np.stack([np_so3_exp(x) for x in w]), atol=1e-12)
    assert np.allclose(so3_log(R).numpy(), w, atol=1e-10)
    q = rotmat_to_quat(R).numpy()
    ref = Rotation.from_rotvec(w).as_quat()[:, [3, 0, 1, 2]]  # scipy: xyzw
    ref *= np.where(ref[:, :1] < 0, -1.0, 1.0)
    assert np.allclose(q, ref, atol=1e-12) and np.all(q[:, 0] >= 0)


@pytest.mark.parametrize("axis", range(3))
def test_every_branch_near_pi(axis):
    # Half-turns about each axis (and near them) select the x, y and z branches.
    for angle in (np.pi, np.pi - 1e-6, np.pi - 0.3):
        w = np.zeros(3)
        w[axis] = angle
        R = torch.from_numpy(Rotation.from_rotvec(w).as_matrix())[None]
        q = rotmat_to_quat(R)
        assert torch.allclose(q, _reference_quat(R), atol=1e-12)
        assert np.allclose(Rotation.from_quat(q[0, [1, 2, 3, 0]].numpy()).as_matrix(), R[0].numpy(), atol=1e-12)


def test_quaternion_gradients_equal_the_entry_by_entry_formula():
    w = _rotation_vectors(40, seed=3)
    w[5] = [0.0, 0.0, np.pi - 1e-3]
    R = torch.from_numpy(np_stack := np.stack([np_so3_exp(x) for x in w])).requires_grad_(True)
    R_ref = torch.from_numpy(np_stack.copy()).requires_grad_(True)
    weights = torch.randn(40, 4, dtype=D)
    (rotmat_to_quat(R) * weights).sum().backward()
    (_reference_quat(R_ref) * weights).sum().backward()
    assert torch.allclose(R.grad, R_ref.grad, atol=1e-12)


def test_exp_and_log_gradients_are_finite_at_zero_and_pass_gradcheck():
    for w in (torch.zeros(1, 3, dtype=D), torch.tensor([[0.3, -1.1, 0.7]], dtype=D)):
        w.requires_grad_(True)
        assert torch.autograd.gradcheck(so3_exp, (w,))
        R = so3_exp(w.detach())
        if w.abs().sum() > 0:
            assert torch.autograd.gradcheck(so3_log, (R.clone().requires_grad_(True),))
        g = torch.autograd.grad(so3_log(so3_exp(w)).sum(), w)[0]
        assert torch.isfinite(g).all() and torch.allclose(g, torch.ones_like(g), atol=1e-6)


def test_a_first_call_under_inference_mode_leaves_training_gradients_working():
    so3.constant.cache_clear()
    with torch.inference_mode():
        rotmat_to_quat(torch.eye(3, dtype=torch.float32)[None])
        so3_exp(torch.zeros(1, 3, dtype=torch.float32))
    w = torch.full((1, 3), 0.2, requires_grad=True)
    (rotmat_to_quat(so3_exp(w)).sum()).backward()
    assert torch.isfinite(w.grad).all()
