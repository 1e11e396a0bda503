"""DINOv3 ViT (``DINOv3ViTModel``) as the feature file that
:class:`~idsplat_ns.instances.features.dinov3_onnx.Dinov3OnnxFeatures` reads:

    input   pixel_values [1, 3, H, W] float32 (H, W dynamic multiples of the patch size)
    output  hidden_states_<k> [1, 1 + R + H/p * W/p, C]: the tokens after block k (class token,
            R register tokens, then the patches row by row), before the final norm

Only the first k blocks are in the graph (the later ones do not change the output).
"""

from __future__ import annotations

import math
from pathlib import Path

import torch

from idsplat_ns.errors import IDSplatError
from idsplat_ns.instances.export_onnx.common import checkpoint_config, export_graph, load_model

MODEL_TYPES = ("dinov3_vit",)
PAPER_LAYER = 7  # the paper's choice (ViT-B/16 layer 7; its feature ablation)


def output_name(layer: int) -> str:
    return f"hidden_states_{layer}"


class Dinov3Onnx(torch.nn.Module):
    """forward(pixel_values [1, 3, H, W]) -> tokens after block ``layer`` [1, T, C]."""

    def __init__(self, model: torch.nn.Module, layer: int):
        super().__init__()
        self.model = model
        self.layer = layer

    def rope(self, pixel_values: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """DINOv3's 2D RoPE (cos, sin) [P, head_dim] for the input's patch grid.

        transformers caches the patch coordinates per grid size (``lru_cache``), which a trace would
        freeze as constants; computing them from the traced shape keeps H and W dynamic.
        """
        cfg, rope = self.model.config, self.model.rope_embeddings
        p = cfg.patch_size if isinstance(cfg.patch_size, int) else cfg.patch_size[0]
        gh, gw = pixel_values.shape[2] // p, pixel_values.shape[3] // p
        ys = (torch.arange(gh, dtype=torch.float32) + 0.5) / gh
        xs = (torch.arange(gw, dtype=torch.float32) + 0.5) / gw
        coords = 2.0 * torch.stack(torch.meshgrid(ys, xs, indexing="ij"), -1).flatten(0, 1) - 1.0  # [P, 2] (y, x)
        angles = (2 * math.pi * coords[:, :, None] * rope.inv_freq[None, None, :]).flatten(1, 2).tile(2)
        return torch.cos(angles), torch.sin(angles)

    def forward(self, pixel_values: torch.Tensor) -> torch.Tensor:
        hidden = self.model.embeddings(pixel_values)
        position_embeddings = self.rope(pixel_values)
        for block in self.model.model.layer[: self.layer]:
            hidden = block(hidden, position_embeddings=position_embeddings)
        return hidden


def check_layer(checkpoint: Path, layer: int) -> None:
    """One-line error unless ``layer`` is one of the checkpoint's blocks (read from its config.json)."""
    depth = checkpoint_config(checkpoint, MODEL_TYPES, "DINOv3 ViT").get("num_hidden_layers", 12)  # 12: the class default
    if not 1 <= layer <= depth:
        raise IDSplatError(f"--dinov3-layer {layer}: the checkpoint {checkpoint} has blocks 1..{depth}; choose one of them")


def export_dinov3(checkpoint: Path, out_path: Path, layer: int = PAPER_LAYER) -> Path:
    """Export the tokens after block ``layer`` of the checkpoint folder's DINOv3 ViT."""
    from transformers import DINOv3ViTModel

    check_layer(checkpoint, layer)
    model = load_model(DINOv3ViTModel, checkpoint, MODEL_TYPES, "DINOv3 ViT")
    p = model.config.patch_size if isinstance(model.config.patch_size, int) else model.config.patch_size[0]
    x = torch.randn(1, 3, 3 * p, 4 * p, generator=torch.Generator().manual_seed(0))  # non-square: H and W stay apart
    return export_graph(Dinov3Onnx(model, layer), (x,), out_path, ("pixel_values",), (output_name(layer),),
                        {"pixel_values": {2: "H", 3: "W"}, output_name(layer): {1: "T"}})
