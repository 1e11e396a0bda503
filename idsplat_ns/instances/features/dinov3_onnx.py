"""DINOv3 ViT-B/16 patch features through ONNX Runtime (the paper's layer 7).

The model file is the user's (nothing downloads). Expected signature (see docs/instances.md):

    input   ``pixel_values``  float32 [1, 3, H, W], RGB in [0, 1] normalised with the ImageNet
            mean (0.485, 0.456, 0.406) and std (0.229, 0.224, 0.225); H and W multiples of 16.
    output  the hidden states of one layer, either tokens [1, T, C] (T = prefix tokens + H/16 * W/16,
            the class and register tokens first, as DINOv3 orders them) or a map [1, C, H/16, W/16].
            The output is chosen by name (``output_name``) or, when unset, is the first output.

The image is resized so that its shorter side is ``short_side`` pixels (rounded to multiples of 16).
The paper upsamples the patch features bilinearly to the image size and samples them at the
projected points; sampling the patch grid bilinearly at the points' positions gives the same values
without materialising a full-resolution feature map.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Optional

import cv2
import numpy as np

from idsplat_ns.errors import IDSplatError
from idsplat_ns.instances.features.base import ImageFeatureExtractor, sample_bilinear
from idsplat_ns.instances.onnx_session import model_identity, open_session
from idsplat_ns.instances.options import cli_option
from idsplat_ns.ranges import AT_LEAST_ONE, bounded

IMAGENET_MEAN = np.array([0.485, 0.456, 0.406], np.float32)
IMAGENET_STD = np.array([0.229, 0.224, 0.225], np.float32)


@dataclass(frozen=True)
class Dinov3Config:
    """Where the DINOv3 export is and how images are prepared for it."""

    model_path: Optional[Path] = None
    """ONNX file of DINOv3 ViT-B/16 that outputs layer 7's hidden states."""
    input_name: str = "pixel_values"
    """Name of the image input."""
    output_name: Optional[str] = None
    """Name of the feature output (None: the first output)."""
    patch_size: int = bounded(16, AT_LEAST_ONE)
    """ViT patch size in pixels."""
    short_side: int = bounded(448, AT_LEAST_ONE)
    """The image's shorter side is resized to this (multiple of ``patch_size``)."""
    threads: int = 0
    """ONNX Runtime intra-op threads (0: its default)."""


def prepare_image(rgb: np.ndarray, short_side: int, patch: int) -> np.ndarray:  # rgb: [H, W, 3] uint8
    """[1, 3, h, w] float32 network input: resized (short side ``short_side``, multiples of ``patch``), normalised."""
    H, W = rgb.shape[:2]
    scale = short_side / min(H, W)
    h = max(patch, int(round(H * scale / patch)) * patch)
    w = max(patch, int(round(W * scale / patch)) * patch)
    x = cv2.resize(rgb, (w, h), interpolation=cv2.INTER_AREA if scale < 1 else cv2.INTER_LINEAR)
    x = (x.astype(np.float32) / 255.0 - IMAGENET_MEAN) / IMAGENET_STD
    return np.ascontiguousarray(x.transpose(2, 0, 1)[None])


def patch_grid(output: np.ndarray, grid_h: int, grid_w: int) -> np.ndarray:
    """Model output (tokens [1, T, C] or map [1, C, h, w]) as a grid [h, w, C]."""
    if output.ndim == 4:
        if output.shape[2:] != (grid_h, grid_w):
            raise IDSplatError(f"DINOv3 output map is {output.shape[2:]}, expected {(grid_h, grid_w)} patches; check the export")
        return output[0].transpose(1, 2, 0)
    if output.ndim == 3:
        n = grid_h * grid_w
        if output.shape[1] < n:
            raise IDSplatError(f"DINOv3 output has {output.shape[1]} tokens for {n} patches; check the export")
        return output[0, output.shape[1] - n :].reshape(grid_h, grid_w, -1)  # drop class/register tokens
    raise IDSplatError(f"DINOv3 output has shape {output.shape}; expected [1, T, C] or [1, C, h, w]")


class Dinov3OnnxFeatures(ImageFeatureExtractor):
    """DINOv3 patch features bilinearly interpolated at the painted pixels."""

    name = "dinov3"

    def __init__(self, config: Dinov3Config):
        self.config = config
        if config.model_path is None or not Path(config.model_path).is_file():
            open_session(config.model_path, cli_option("features.dinov3.model-path"))  # raises the one-line error
        self._session = None  # loaded on first use, so cached runs never load the model
        self._output = config.output_name

    def _ensure_session(self):
        if self._session is None:
            c = self.config
            self._session = open_session(c.model_path, cli_option("features.dinov3.model-path"), c.threads)
            names = [i.name for i in self._session.get_inputs()]
            if c.input_name not in names:
                raise IDSplatError(f"{c.model_path}: no input named {c.input_name!r} (inputs: {names}); set {cli_option('features.dinov3.input-name')}")
            outputs = [o.name for o in self._session.get_outputs()]
            self._output = c.output_name or outputs[0]
            if self._output not in outputs:
                raise IDSplatError(f"{c.model_path}: no output named {self._output!r} (outputs: {outputs}); set {cli_option('features.dinov3.output-name')}")
        return self._session

    def cache_key(self) -> dict:
        c = self.config
        return {"extractor": self.name, "model": model_identity(c.model_path), "input": c.input_name,
                "output": c.output_name, "patch": c.patch_size, "short_side": c.short_side}

    def feature_grid(self, rgb: np.ndarray) -> np.ndarray:
        """[h, w, C] patch features of one image."""
        x = prepare_image(rgb, self.config.short_side, self.config.patch_size)
        session = self._ensure_session()
        out = session.run([self._output], {self.config.input_name: x})[0]
        p = self.config.patch_size
        return patch_grid(np.asarray(out, np.float32), x.shape[2] // p, x.shape[3] // p)

    def describe(self, rgb: np.ndarray, uv: np.ndarray) -> np.ndarray:
        grid = self.feature_grid(rgb)
        gh, gw = grid.shape[:2]
        # Pixel (continuous, origin at the image corner) to patch-centre coordinates.
        xy = np.stack([uv[:, 0] * gw / rgb.shape[1] - 0.5, uv[:, 1] * gh / rgb.shape[0] - 0.5], 1)
        return sample_bilinear(grid, xy)
