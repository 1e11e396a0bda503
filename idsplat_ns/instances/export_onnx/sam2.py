"""SAM 2 (``Sam2Model``) as the two files that
:class:`~idsplat_ns.instances.masks.grounded_sam2_onnx.GroundedSam2OnnxMasks` reads:

    encoder  image [1, 3, S, S] -> high_res_feats_0 [1, C/8, S/4, S/4], high_res_feats_1 [1, C/4, S/8, S/8],
             image_embed [1, C, S/16, S/16]  (S = the checkpoint's image size, 1024; C = 256)
    decoder  image_embed, high_res_feats_0, high_res_feats_1, point_coords [1, N, 2] (S x S frame),
             point_labels [1, N] float32 (2, 3 = box corners; 1/0 points; -1 not a point),
             mask_input [1, 1, S/4, S/4], has_mask_input [1]
             -> masks [1, M, S/4, S/4] (logits), iou_predictions [1, M]   (N dynamic)

Box prompts enter as two corner points labelled 2 and 3 plus a padding point, which is what
SAM 2's image predictor and transformers' ``input_boxes`` path both compute (tested).
"""

from __future__ import annotations

from pathlib import Path

import torch

from idsplat_ns.instances.export_onnx.common import export_graph, load_model

# sam2_video is the model_type of the facebook/sam2.1-hiera-* folders; Sam2Model loads their image part.
MODEL_TYPES = ("sam2", "sam2_video")
ENCODER_OUTPUTS = ("high_res_feats_0", "high_res_feats_1", "image_embed")
DECODER_INPUTS = ("image_embed", "high_res_feats_0", "high_res_feats_1", "point_coords", "point_labels",
                  "mask_input", "has_mask_input")
DECODER_OUTPUTS = ("masks", "iou_predictions")


class Sam2EncoderOnnx(torch.nn.Module):
    """forward(image [1, 3, S, S]) -> (high_res_feats_0, high_res_feats_1, image_embed), no-memory embedding added.

    Hiera's positional embedding (a bicubic resize of a learnt grid plus a tiled window grid) is
    precomputed for the fixed S x S input and stored as a constant: traced, its ``tile`` became an
    ``If`` whose branches disagree on shape, and ONNX Runtime's graph optimiser then produced
    garbage in some runs (measured on ONNX Runtime 1.26; correct with optimisations off).
    """

    def __init__(self, model: torch.nn.Module):
        super().__init__()
        self.model = model
        backbone = model.vision_encoder.backbone
        grid = image_size(model) // backbone.config.patch_stride[0]
        with torch.no_grad():
            self.register_buffer("pos_embed", backbone._get_pos_embed((grid, grid)).clone())  # [1, g, g, C]

    def forward(self, image: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        backbone = self.model.vision_encoder.backbone
        backbone._get_pos_embed = lambda hw: self.pos_embed  # instance attribute: this model only, removed below
        try:
            feats = self.model.get_image_embeddings(image)  # the decoder's conv_s0 / conv_s1 already applied
        finally:
            del backbone._get_pos_embed
        return feats[0], feats[1], feats[2]


class Sam2DecoderOnnx(torch.nn.Module):
    """Prompt encoder + mask decoder on precomputed image features (one prompt set per call)."""

    def __init__(self, model: torch.nn.Module, multimask: bool):
        super().__init__()
        self.model = model
        self.multimask = multimask

    def forward(self, image_embed: torch.Tensor, high_res_feats_0: torch.Tensor, high_res_feats_1: torch.Tensor,
                point_coords: torch.Tensor, point_labels: torch.Tensor, mask_input: torch.Tensor,
                has_mask_input: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        pe = self.model.prompt_encoder
        labels = point_labels.round().to(torch.int64)[:, None]  # [1, 1, N]: one prompt set
        sparse = pe._embed_points(point_coords[:, None], labels, pad=True)  # [1, 1, N + 1, C]
        has = has_mask_input.reshape(-1, 1, 1, 1)
        # Blend rather than branch so that one graph serves both cases (as SAM's own ONNX export does).
        dense = has * pe.mask_embed(mask_input) + (1 - has) * pe.no_mask_embed.weight.reshape(1, -1, 1, 1)
        masks, iou, _, _ = self.model.mask_decoder(
            image_embeddings=image_embed, image_positional_embeddings=self.model.get_image_wide_positional_embeddings(),
            sparse_prompt_embeddings=sparse, dense_prompt_embeddings=dense, multimask_output=self.multimask,
            high_resolution_features=[high_res_feats_0, high_res_feats_1])
        return masks[:, 0], iou[:, 0]  # [1, M, S/4, S/4], [1, M]


def image_size(model: torch.nn.Module) -> int:
    return int(model.config.prompt_encoder_config.image_size)


def export_sam2(checkpoint: Path, encoder_path: Path, decoder_path: Path, multimask: bool = False) -> tuple[Path, Path]:
    """Export the checkpoint folder's SAM 2 image encoder and prompt/mask decoder.

    ``multimask=False`` (one mask per box, SAM 2's stability fallback to the best of three) is how
    Grounded-SAM-2 prompts SAM 2 with boxes; ``True`` returns the three candidates.
    """
    from transformers import Sam2Model

    model = load_model(Sam2Model, checkpoint, MODEL_TYPES, "SAM 2")
    S = image_size(model)
    gen = torch.Generator().manual_seed(0)
    image = torch.randn(1, 3, S, S, generator=gen)
    encoder = Sam2EncoderOnnx(model)
    export_graph(encoder, (image,), encoder_path, ("image",), ENCODER_OUTPUTS)
    with torch.no_grad():
        hr0, hr1, embed = encoder(image)
    prompt = (torch.tensor([[[0.2 * S, 0.3 * S], [0.6 * S, 0.7 * S]]]), torch.tensor([[2.0, 3.0]]),
              torch.zeros(1, 1, S // 4, S // 4), torch.zeros(1))
    export_graph(Sam2DecoderOnnx(model, multimask), (embed, hr0, hr1, *prompt), decoder_path, DECODER_INPUTS, DECODER_OUTPUTS,
                 {"point_coords": {1: "N"}, "point_labels": {1: "N"}})
    return Path(encoder_path), Path(decoder_path)
