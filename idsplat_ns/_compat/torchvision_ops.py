"""Make ``import torchvision`` work when its compiled ops cannot load (CPU torch, CUDA-linked wheel).

torchvision registers fake (meta) kernels for ``torchvision::nms`` and ``torchvision::qnms``
unconditionally at import; without its compiled library those operators do not exist and the
import fails. When (and only when) the library cannot be loaded, this defines the two operator
schemas with a pure-torch CPU NMS, so the import succeeds and ``torchvision.ops.nms`` still works.
Every other compiled op stays absent and torchvision reports that itself when it is called.
"""

from __future__ import annotations

import importlib.util
from pathlib import Path

_LIBRARY = None  # keeps the torch.library.Library alive (definitions vanish when it is collected)


def _nms_reference(dets, scores, iou_threshold: float):
    """Greedy NMS in pure torch: dets [N, 4] (x1, y1, x2, y2), scores [N] -> kept indices, best first."""
    import torch

    order = torch.argsort(scores, descending=True)
    boxes = dets[order].to(torch.float64)
    area = (boxes[:, 2] - boxes[:, 0]).clamp(min=0) * (boxes[:, 3] - boxes[:, 1]).clamp(min=0)
    suppressed = torch.zeros(len(order), dtype=torch.bool)
    keep = []
    for i in range(len(order)):
        if suppressed[i]:
            continue
        keep.append(i)
        lt = torch.maximum(boxes[i, :2], boxes[i + 1 :, :2])
        rb = torch.minimum(boxes[i, 2:], boxes[i + 1 :, 2:])
        inter = (rb - lt).clamp(min=0).prod(1)
        iou = inter / (area[i] + area[i + 1 :] - inter).clamp(min=1e-12)
        suppressed[i + 1 :] |= iou > iou_threshold
    return order[torch.tensor(keep, dtype=torch.long)] if keep else order[:0]


def compiled_ops_load() -> bool:
    """Whether torchvision's compiled op library loads against the installed torch."""
    import torch

    spec = importlib.util.find_spec("torchvision")
    if spec is None or spec.origin is None:
        return True  # no torchvision: nothing to guard
    libs = sorted(Path(spec.origin).parent.glob("_C*.so")) + sorted(Path(spec.origin).parent.glob("_C*.pyd"))
    if not libs:
        return False
    try:
        torch.ops.load_library(str(libs[0]))
    except (OSError, RuntimeError):
        return False
    return True


def ensure_importable() -> bool:
    """Define the ops torchvision's import needs if its library cannot load. Returns True if it acted."""
    global _LIBRARY
    if _LIBRARY is not None or compiled_ops_load():
        return False
    import torch

    lib = torch.library.Library("torchvision", "DEF")
    lib.define("nms(Tensor dets, Tensor scores, float iou_threshold) -> Tensor")
    lib.define("qnms(Tensor dets, Tensor scores, float iou_threshold) -> Tensor")
    lib.impl("nms", _nms_reference, "CPU")
    _LIBRARY = lib
    return True
