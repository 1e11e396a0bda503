"""LPIPS (Zhang et al. 2018) without downloads.

The backbone (torchvision AlexNet or VGG16 ImageNet weights) is a file the user gives, e.g.
``alexnet-owt-7be5be79.pth`` or ``vgg16-397923af.pth`` from torchvision's model zoo. The small
linear calibration layers ship inside the ``lpips`` wheel (``lpips/weights/v0.1/<net>.pth``) and are
read from there. Nothing is fetched at run time; a missing file is one clear error.
"""

from __future__ import annotations

import importlib.util
from pathlib import Path
from typing import Optional

import torch
from torch import Tensor, nn

from idsplat_ns.errors import IDSplatError

# Backbone layers whose ReLU outputs LPIPS compares: (slice end indices into .features, channels).
_LAYERS = {
    "alex": ((2, 5, 8, 10, 12), (64, 192, 384, 256, 256)),
    "vgg": ((4, 9, 16, 23, 30), (64, 128, 256, 512, 512)),
}
LPIPS_NOTE = (
    "LPIPS not computed: no backbone weights given (nothing is downloaded); pass "
    "--pipeline.model.lpips-backbone <torchvision alexnet or vgg16 .pth file>"
)
"""The line ns-eval's JSON and report carry in place of LPIPS when no backbone file is given."""
_SHIFT = (-0.030, -0.088, -0.188)
_SCALE = (0.458, 0.448, 0.450)


def _backbone(net: str) -> nn.Sequential:
    from torchvision import models

    if net == "alex":
        return models.alexnet(weights=None).features
    if net == "vgg":
        return models.vgg16(weights=None).features
    raise IDSplatError(f"lpips_net='{net}': use 'alex' or 'vgg'")


def default_linear_weights(net: str) -> Path:
    """The calibration weights shipped in the ``lpips`` wheel for ``net``."""
    spec = importlib.util.find_spec("lpips")
    if spec is None or spec.origin is None:
        raise IDSplatError("LPIPS needs the 'lpips' package for its calibration weights: pip install lpips==0.1.4")
    return Path(spec.origin).parent / "weights" / "v0.1" / f"{net}.pth"


class LPIPS(nn.Module):
    """Learned perceptual distance between images in [0, 1]; lower is more similar."""

    def __init__(self, net: str = "alex") -> None:
        super().__init__()
        ends, channels = _LAYERS[net] if net in _LAYERS else (None, None)
        if ends is None:
            raise IDSplatError(f"lpips_net='{net}': use 'alex' or 'vgg'")
        self.net = net
        self.features = _backbone(net)[: ends[-1]]
        self.ends = ends
        self.lins = nn.ModuleList([nn.Conv2d(c, 1, 1, bias=False) for c in channels])
        self.register_buffer("shift", torch.tensor(_SHIFT)[None, :, None, None])
        self.register_buffer("scale", torch.tensor(_SCALE)[None, :, None, None])
        self.requires_grad_(False)
        self.eval()

    @classmethod
    def from_files(cls, backbone: Path, net: str = "alex", linear: Optional[Path] = None) -> "LPIPS":
        """Load the user's torchvision backbone weights and the calibration weights."""
        model = cls(net)
        backbone = Path(backbone).expanduser()
        if not backbone.is_file():
            raise IDSplatError(f"{backbone}: LPIPS backbone weights not found; give torchvision's {net} ImageNet .pth file")
        state = torch.load(backbone, map_location="cpu", weights_only=True)
        feats = {k[len("features."):]: v for k, v in state.items() if k.startswith("features.")}
        try:
            model.features.load_state_dict({k: v for k, v in feats.items() if int(k.split(".")[0]) < model.ends[-1]})
        except RuntimeError as err:
            raise IDSplatError(f"{backbone}: not torchvision {net} weights ({str(err).splitlines()[0]})") from None
        lin_path = Path(linear or default_linear_weights(net))
        if not lin_path.is_file():
            raise IDSplatError(f"{lin_path}: LPIPS calibration weights not found; reinstall lpips==0.1.4 (it ships them)")
        lin_state = torch.load(lin_path, map_location="cpu", weights_only=True)
        for i, lin in enumerate(model.lins):
            lin.weight.copy_(lin_state[f"lin{i}.model.1.weight"])
        return model

    def forward(self, pred: Tensor, gt: Tensor) -> Tensor:
        """pred, gt: [H, W, 3] or [B, H, W, 3] in [0, 1]. Returns the mean distance (scalar)."""
        if pred.dim() == 3:
            pred, gt = pred[None], gt[None]
        x = (pred.permute(0, 3, 1, 2) * 2 - 1 - self.shift) / self.scale
        y = (gt.permute(0, 3, 1, 2) * 2 - 1 - self.shift) / self.scale
        total = 0.0
        start = 0
        for lin, end in zip(self.lins, self.ends):
            block = self.features[start:end]
            x, y = block(x), block(y)
            start = end
            nx = x / (x.pow(2).sum(1, keepdim=True).sqrt() + 1e-10)
            ny = y / (y.pow(2).sum(1, keepdim=True).sqrt() + 1e-10)
            total = total + lin((nx - ny) ** 2).mean(dim=(2, 3))
        return total.mean()
