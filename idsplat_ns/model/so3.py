"""SO(3) maths on torch tensors: differentiable, batched, stable at zero angle and near pi.

Each function is a few fixed linear maps and element-wise operations, so that a call costs a
dozen operators whatever its batch shape: on a GPU a training step is bound by the host
launching operators, and these run several times a step (trajectory interpolation, the
composition of instance Gaussians, camera corrections). ``tests/test_so3.py`` compares them with
the entry-by-entry formulas and with SciPy.
"""

from __future__ import annotations

import functools

import torch
from torch import Tensor

# Below this angle (radians) exp/log use their Taylor series (gradients stay finite).
SMALL_ANGLE = 1e-4

# [w]x flattened row-major, as a linear map of w = (x, y, z): rows of _HAT are x, y, z.
_HAT = (
    (0, 0, 0, 0, 0, -1, 0, 1, 0),
    (0, 0, 1, 0, 0, 0, -1, 0, 0),
    (0, -1, 0, 1, 0, 0, 0, 0, 0),
)

# 4 q q^T (q = wxyz, flattened row-major) as an affine map of R's entries r00, r01, ..., r22:
# 4w^2 = 1 + r00 + r11 + r22, 4wx = r21 - r12, 4xy = r01 + r10, and so on (the classic
# identities behind Shepperd's method).
_R = {f"r{i}{j}": 3 * i + j for i in range(3) for j in range(3)}
_OUTER_TERMS = {
    (0, 0): "+r00 +r11 +r22", (1, 1): "+r00 -r11 -r22", (2, 2): "-r00 +r11 -r22", (3, 3): "-r00 -r11 +r22",
    (0, 1): "+r21 -r12", (0, 2): "+r02 -r20", (0, 3): "+r10 -r01",
    (1, 2): "+r01 +r10", (1, 3): "+r02 +r20", (2, 3): "+r12 +r21",
}  # fmt: skip


# The maps are made once per dtype and device (no host-to-device copy a call), outside inference
# mode so that a first call under it cannot give autograd a tensor it refuses to save.
@functools.lru_cache(maxsize=None)
@torch.inference_mode(False)
def constant(values: tuple, dtype: torch.dtype, device: torch.device) -> Tensor:
    """A constant tensor of nested tuples, made once per dtype and device."""
    return torch.tensor(values, dtype=dtype, device=device)


def _outer_map(dtype: torch.dtype, device: torch.device) -> tuple[Tensor, Tensor]:  # -> [9, 16], [16]
    return constant(_OUTER_LINEAR, dtype, device), constant(_OUTER_CONST, dtype, device)


def _outer_tables() -> tuple[tuple, tuple]:
    linear = [[0.0] * 16 for _ in range(9)]
    const = [0.0] * 16
    for (a, b), terms in _OUTER_TERMS.items():
        for cell in {4 * a + b, 4 * b + a}:
            const[cell] = 1.0 if a == b else 0.0
            for term in terms.split():
                linear[_R[term[1:]]][cell] = 1.0 if term[0] == "+" else -1.0
    return tuple(map(tuple, linear)), tuple(const)


_OUTER_LINEAR, _OUTER_CONST = _outer_tables()


def hat(w: Tensor) -> Tensor:  # w: [..., 3] -> [..., 3, 3]
    """Cross-product matrices ``[w]x`` with ``[w]x @ u == cross(w, u)``."""
    return (w @ constant(_HAT, w.dtype, w.device)).unflatten(-1, (3, 3))


def so3_exp(w: Tensor) -> Tensor:  # w: [..., 3] -> [..., 3, 3]
    """Rodrigues' formula; the series form below ``SMALL_ANGLE`` keeps the gradient at 0 exact."""
    theta2 = (w * w).sum(-1)
    small = theta2 < SMALL_ANGLE**2
    # Double-where: the unused branch must not see theta = 0 (its gradient would be NaN).
    theta2_safe = torch.where(small, torch.ones_like(theta2), theta2)
    theta = torch.sqrt(theta2_safe)
    a = torch.where(small, 1.0 - theta2 / 6.0, torch.sin(theta) / theta)
    b = torch.where(small, 0.5 - theta2 / 24.0, (1.0 - torch.cos(theta)) / theta2_safe)
    W = hat(w)
    eye = torch.eye(3, dtype=w.dtype, device=w.device)
    return eye + a[..., None, None] * W + b[..., None, None] * (W @ W)


def rotmat_to_quat(R: Tensor) -> Tensor:  # R: [..., 3, 3] -> [..., 4] wxyz, w >= 0
    """Unit quaternions of rotation matrices (Shepperd's method, differentiable).

    ``4 q q^T`` is an affine function of R; its row with the largest diagonal entry, divided by
    twice that entry's square root, is q. That entry is at least 1 for a rotation, so neither the
    square root nor the division comes near zero, and rows not selected get no gradient.
    """
    linear, const = _outer_map(R.dtype, R.device)
    outer = (R.flatten(-2) @ linear + const).unflatten(-1, (4, 4))  # [..., 4, 4] = 4 q q^T
    diag = outer.diagonal(dim1=-2, dim2=-1)  # [..., 4]
    branch = diag.argmax(-1, keepdim=True)  # [..., 1]
    row = torch.gather(outer, -2, branch[..., None].expand(*branch.shape, 4)).squeeze(-2)  # [..., 4]
    q = row / (2.0 * torch.sqrt(torch.gather(diag, -1, branch).clamp_min(1e-12)))
    return q * torch.where(q[..., :1] < 0, -1.0, 1.0)  # canonical sign: w >= 0


def so3_log(R: Tensor) -> Tensor:  # R: [..., 3, 3] -> [..., 3]
    """Rotation vectors of rotation matrices, through the quaternion (stable at 0 and near pi)."""
    q = rotmat_to_quat(R)
    w, v = q[..., 0], q[..., 1:]
    n2 = (v * v).sum(-1)
    small = n2 < SMALL_ANGLE**2
    n = torch.sqrt(torch.where(small, torch.ones_like(n2), n2))
    # Double-where: at exactly pi, w = 0 and the unused series branch's 1/w would make the
    # gradient NaN (0 * inf); near 0, where the series is used, w is about 1.
    w_safe = torch.where(small, w, torch.ones_like(w))
    # angle = 2 atan2(|v|, w); factor = angle / |v|, series 2/w (1 - |v|^2 / (3 w^2)) near 0.
    factor = torch.where(small, 2.0 / w_safe * (1.0 - n2 / (3.0 * w_safe * w_safe)), 2.0 * torch.atan2(n, w) / n)
    return factor[..., None] * v
