"""Which tile compositor a rasterizer call uses: the compiled loops
(:mod:`idsplat_ns.render.compiled_composite`, numba, CPU), Triton kernels
(:mod:`idsplat_ns.render.triton_composite`, CUDA) or torch tensor ops
(:mod:`idsplat_ns.render.tile_composite`, any device).

numba and Triton are imported only when their kernels run, so CUDA runs never load numba and
CPU runs never load Triton.
"""

from __future__ import annotations

import functools
import importlib.util
import os
import warnings

import torch
from torch import Tensor

from ..errors import IDSplatError

COMPOSITORS = ("auto", "compiled", "torch", "triton")


@functools.lru_cache(maxsize=1)
def numba_installed() -> bool:
    """Whether numba can be imported. The package requires it; an environment assembled without
    it (a ``pip --target`` install of the GPU benches) gets the torch compositor and one warning."""
    found = importlib.util.find_spec("numba") is not None
    if not found:
        warnings.warn("idsplat_ns: numba is not installed; CPU rasterization uses the slower torch compositor "
                      "(pip install numba)")  # fmt: skip
    return found


@functools.lru_cache(maxsize=1)
def triton_installed() -> bool:
    """Whether Triton can be imported (it comes with CUDA builds of torch)."""
    return importlib.util.find_spec("triton") is not None


def _triton_usable(feats: Tensor) -> bool:
    """Triton's kernels take float32 features on CUDA, or on the CPU under its interpreter."""
    interpreted = os.environ.get("TRITON_INTERPRET", "0") not in ("", "0")
    return feats.dtype == torch.float32 and (feats.device.type == "cuda" or (interpreted and feats.device.type == "cpu"))


def choose_compositor(compositor: str, feats: Tensor) -> str:
    """``"compiled"``, ``"triton"`` or ``"torch"``: what ``compositor`` (one of :data:`COMPOSITORS`)
    means for ``feats``. ``"auto"`` takes the compiled loops for float CPU tensors, Triton for
    float32 CUDA tensors, else torch; a named one that cannot run is one line naming the option."""
    if compositor not in COMPOSITORS:
        raise IDSplatError(f"compositor={compositor!r}: use one of {', '.join(COMPOSITORS)}")
    compiled_ok = feats.device.type == "cpu" and feats.dtype in (torch.float32, torch.float64)
    if compositor == "compiled":
        if not compiled_ok:
            raise IDSplatError(
                f"compositor='compiled' runs on float32/float64 CPU tensors, not {feats.dtype} on {feats.device}; "
                "use compositor='torch' or 'auto'"
            )
        if not numba_installed():
            raise IDSplatError("compositor='compiled' needs numba: pip install numba, or use compositor='torch'")
        return "compiled"
    if compositor == "triton":
        if not triton_installed():
            raise IDSplatError("compositor='triton' needs Triton (it comes with CUDA builds of torch); use compositor='torch'")
        if not _triton_usable(feats):
            raise IDSplatError(
                f"compositor='triton' runs on float32 CUDA tensors (CPU only under TRITON_INTERPRET=1), not "
                f"{feats.dtype} on {feats.device}; use compositor='torch' or 'auto'"
            )
        return "triton"
    if compositor == "auto":
        if compiled_ok and numba_installed():
            return "compiled"
        if feats.device.type == "cuda" and feats.dtype == torch.float32 and triton_installed():
            return "triton"
    return "torch"


def use_compiled_compositor(compositor: str, feats: Tensor) -> bool:
    """Whether ``compositor`` means the compiled loops for ``feats`` (see :func:`choose_compositor`)."""
    return choose_compositor(compositor, feats) == "compiled"
