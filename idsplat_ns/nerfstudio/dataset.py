"""nerfstudio dataset over a Scene's images: loads pixels through the project's loader and adds
the ground-truth dynamic masks and the moving objects' pixel map (evaluation only) to each batch."""

from __future__ import annotations

from typing import Dict

import numpy as np
import torch
from nerfstudio.data.datasets.base_dataset import InputDataset

from idsplat_ns.data.dynamic_masks import dynamic_mask, moving_object_map
from idsplat_ns.data.images import load_rgb
from idsplat_ns.nerfstudio.model_inputs import split_data


class IDSplatDataset(InputDataset):
    """Images of one split of a Scene, at the dataparser's scale."""

    exclude_batch_keys_from_device = InputDataset.exclude_batch_keys_from_device + [
        "dynamic_mask", "dynamic_mask_pedestrian", "dynamic_mask_cyclist", "object_map", "object_ids"
    ]

    def __init__(self, dataparser_outputs, scale_factor: float = 1.0):
        super().__init__(dataparser_outputs, scale_factor)
        self.split = split_data(self.metadata)
        self.scene = self.split.scene
        self.split_images = self.split.images
        self.image_scale = float(self.split.image_scale) * scale_factor
        self.extra_groups = [g for g in ("pedestrian", "cyclist") if any(t.moving and t.group == g for t in self.scene.tracks)]

    def get_numpy_image(self, image_idx: int) -> np.ndarray:
        return load_rgb(self.split_images[image_idx], self.image_scale)

    def get_metadata(self, data: Dict) -> Dict:
        if self.split.split == "train":
            return {}
        image = self.split_images[data["image_idx"]]
        # Moving vehicles (the paper's DPSNR), plus the other classes the data has.
        out = {"dynamic_mask": torch.from_numpy(dynamic_mask(self.scene, image, self.image_scale))[..., None]}
        for group in self.extra_groups:
            mask = dynamic_mask(self.scene, image, self.image_scale, groups=(group,))
            out[f"dynamic_mask_{group}"] = torch.from_numpy(mask)[..., None]
        # Each moving road user's pixels: its own DPSNR in ns-eval's per-object diagnosis.
        object_map, object_ids = moving_object_map(self.scene, image, self.image_scale)
        out["object_map"], out["object_ids"] = torch.from_numpy(object_map), object_ids
        return out
