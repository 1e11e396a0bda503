"""Which tile compositor a rasterizer call uses: the compiled loops
(:mod:`idsplat_ns.render.compiled_composite`, numba, CPU) or torch tensor ops
(:mod:`idsplat_ns.render.tile_composite`, any device).

numba is imported only when the compiled loops run, so CUDA runs (gsplat for cameras, the torch
compositor for lidar) never load it.
"""

from __future__ import annotations

import functools
import importlib.util
import warnings

import torch
from torch import Tensor

from ..errors import IDSplatError

COMPOSITORS = ("auto", "compiled", "torch")


@functools.lru_cache(maxsize=1)
def numba_installed() -> bool:
    """Whether numba can be imported. The package requires it; an environment assembled without
    it (a ``pip --target`` install of the GPU benches) gets the torch compositor and one warning."""
    found = importlib.util.find_spec("numba") is not None
    if not found:
        warnings.warn("idsplat_ns: numba is not installed; CPU rasterization uses the slower torch compositor "
                      "(pip install numba)")  # fmt: skip
    return found


def use_compiled_compositor(compositor: str, feats: Tensor) -> bool:
    """Whether ``compositor`` (one of :data:`COMPOSITORS`) means the compiled loops for ``feats``:
    ``"auto"`` takes them for float CPU tensors, ``"compiled"`` insists on them."""
    if compositor not in COMPOSITORS:
        raise IDSplatError(f"compositor={compositor!r}: use one of {', '.join(COMPOSITORS)}")
    usable = feats.device.type == "cpu" and feats.dtype in (torch.float32, torch.float64)
    if compositor == "compiled" and not usable:
        raise IDSplatError(
            f"compositor='compiled' runs on float32/float64 CPU tensors, not {feats.dtype} on {feats.device}; "
            "use compositor='torch' or 'auto'"
        )
    if compositor == "compiled" and not numba_installed():
        raise IDSplatError("compositor='compiled' needs numba: pip install numba, or use compositor='torch'")
    return compositor != "torch" and usable and numba_installed()
