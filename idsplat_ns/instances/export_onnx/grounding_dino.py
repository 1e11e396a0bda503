"""Grounding DINO (``GroundingDinoForObjectDetection``) as the detector file that
:class:`~idsplat_ns.instances.masks.grounded_sam2_onnx.GroundedSam2OnnxMasks` reads:

    inputs  img [1, 3, H, W] float32 (fixed H, W: the export size), input_ids [1, L] int64,
            attention_mask [1, L] bool, position_ids [1, L] int64, token_type_ids [1, L] int64,
            text_token_mask [1, L, L] bool (L dynamic)
    outputs logits [1, Q, 256] float32 (pre-sigmoid per text token; -inf past L),
            boxes [1, Q, 4] float32 (cx, cy, w, h in [0, 1])
"""

from __future__ import annotations

import contextlib
from pathlib import Path
from typing import Iterator

import torch

from idsplat_ns.errors import IDSplatError
from idsplat_ns.instances.export_onnx.common import export_graph, load_model

MODEL_TYPES = ("grounding-dino",)
INPUTS = ("img", "input_ids", "attention_mask", "position_ids", "token_type_ids", "text_token_mask")
OUTPUTS = ("logits", "boxes")
# bert-base-uncased IDs of [CLS], [SEP] and "." (the only IDs the dummy caption needs).
CLS, SEP, DOT = 101, 102, 1012


def reference_points_f32(spatial_shapes_list, valid_ratios: torch.Tensor, device) -> torch.Tensor:
    """``GroundingDinoEncoder.get_reference_points`` without ``torch.linspace``: the TorchScript
    exporter turns that linspace into float64 constants, and ONNX Runtime has no float64 GridSample.
    ``arange + 0.5`` gives the same cell centres. Returns [B, sum(h * w), levels, 2]."""
    refs = []
    for level, (height, width) in enumerate(spatial_shapes_list):
        ys = torch.arange(height, dtype=valid_ratios.dtype, device=device) + 0.5
        xs = torch.arange(width, dtype=valid_ratios.dtype, device=device) + 0.5
        ref_y, ref_x = torch.meshgrid(ys, xs, indexing="ij")
        ref_y = ref_y.reshape(-1)[None] / (valid_ratios[:, None, level, 1] * height)
        ref_x = ref_x.reshape(-1)[None] / (valid_ratios[:, None, level, 0] * width)
        refs.append(torch.stack((ref_x, ref_y), -1))
    return torch.cat(refs, 1)[:, :, None] * valid_ratios[:, None]


@contextlib.contextmanager
def export_patches(text_token_mask: torch.Tensor, position_ids: torch.Tensor) -> Iterator[None]:
    """Within the wrapper's forward only: the given phrase masks and float32 reference points.

    transformers derives the phrase masks and position IDs inside ``forward`` from hard-coded
    bert-base-uncased token IDs; the project computes them from the user's vocab
    (``bert_tokenizer.caption_inputs``) and passes them in, as the official Grounding DINO export
    does. For bert-base-uncased both agree (tested against transformers' own path).
    """
    from transformers.models.grounding_dino import modeling_grounding_dino as mgd

    masks_fn, ref_fn = mgd.generate_masks_with_special_tokens_and_transfer_map, mgd.GroundingDinoEncoder.get_reference_points
    mgd.generate_masks_with_special_tokens_and_transfer_map = lambda input_ids, special_tokens: (text_token_mask, position_ids)
    mgd.GroundingDinoEncoder.get_reference_points = staticmethod(reference_points_f32)
    try:
        yield
    finally:
        mgd.generate_masks_with_special_tokens_and_transfer_map = masks_fn
        mgd.GroundingDinoEncoder.get_reference_points = staticmethod(ref_fn)


class GroundingDinoOnnx(torch.nn.Module):
    """forward(img, input_ids, attention_mask, position_ids, token_type_ids, text_token_mask) -> (logits, boxes)."""

    def __init__(self, model: torch.nn.Module):
        super().__init__()
        self.model = model

    def forward(self, img: torch.Tensor, input_ids: torch.Tensor, attention_mask: torch.Tensor, position_ids: torch.Tensor,
                token_type_ids: torch.Tensor, text_token_mask: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        with export_patches(text_token_mask, position_ids):
            out = self.model(pixel_values=img, input_ids=input_ids, token_type_ids=token_type_ids,
                             attention_mask=attention_mask, return_dict=True)
        return out.logits, out.pred_boxes  # [1, Q, 256], [1, Q, 4]


def dummy_inputs(height: int, width: int) -> tuple[torch.Tensor, ...]:
    """Trace inputs: a random image and the caption "[CLS] a . b . [SEP]" with its phrase masks."""
    from transformers.models.grounding_dino.modeling_grounding_dino import generate_masks_with_special_tokens_and_transfer_map

    ids = torch.tensor([[CLS, 1000, DOT, 1001, 1002, DOT, SEP]], dtype=torch.int64)
    mask, pos = generate_masks_with_special_tokens_and_transfer_map(ids, torch.tensor([CLS, SEP, DOT]))
    img = torch.randn(1, 3, height, width, generator=torch.Generator().manual_seed(0))
    return img, ids, torch.ones_like(ids, dtype=torch.bool), pos, torch.zeros_like(ids), mask


MIN_SIDE = 128  # the coarsest feature level (stride 64) must be at least 2 cells on each side


def check_size(height: int, width: int) -> None:
    """One-line error for a detector size whose coarsest level would be a single cell: the traced
    ``linspace`` of transformers' proposal grid is wrong there (measured: boxes off by 0.25-0.9)."""
    if min(height, width) < MIN_SIDE:
        raise IDSplatError(f"--detector-size {height} {width}: both sides must be at least {MIN_SIDE}; "
                           "use the detector's working size, e.g. 800 1333")


def export_grounding_dino(checkpoint: Path, out_path: Path, height: int = 800, width: int = 1333) -> Path:
    """Export the checkpoint folder's Grounding DINO to ``out_path`` for a fixed ``height`` x ``width`` input.

    The input size is fixed because the Swin backbone's window padding and the deformable
    attention's level split are Python-side shape arithmetic that tracing freezes; the project
    resizes every image to a fixed-size export's H x W (``_static_hw``).
    """
    from transformers import GroundingDinoForObjectDetection

    check_size(height, width)
    model = load_model(GroundingDinoForObjectDetection, checkpoint, MODEL_TYPES, "Grounding DINO")
    text_len = {"input_ids": {1: "L"}, "attention_mask": {1: "L"}, "position_ids": {1: "L"},
                "token_type_ids": {1: "L"}, "text_token_mask": {1: "L", 2: "L"}}
    return export_graph(GroundingDinoOnnx(model), dummy_inputs(height, width), out_path, INPUTS, OUTPUTS, text_len)
