"""The mask-source interface and the instance-mask set every source produces.

Every source writes (or points to) a folder in the precomputed format (see
:mod:`idsplat_ns.instances.masks.precomputed`): one uint16 PNG instance-ID map per camera and frame,
``<dir>/<camera>/<frame:02d>.png``, and ``instances.json`` with each ID's class. A missing PNG means
"no masks for that image" (a missed frame), not an error.
"""

from __future__ import annotations

import json
from abc import ABC, abstractmethod
from dataclasses import dataclass
from pathlib import Path
from typing import Optional

import numpy as np

from idsplat_ns.data.images import read_instance_map, write_instance_map  # noqa: F401 (re-exported)
from idsplat_ns.data.scene import Scene

PROMPT_CLASSES: tuple[str, ...] = ("car", "truck", "van", "bus", "train", "human", "cyclist", "bicycle", "pedestrian")
"""The paper's Grounded-SAM-2 class prompts (supplementary, "Instance decomposition")."""

INSTANCES_JSON = "instances.json"


def mask_filename(camera: str, frame_index: int) -> str:
    """Relative path of one image's instance map inside a mask folder."""
    return f"{camera}/{frame_index:02d}.png"


@dataclass
class InstanceMaskSet:
    """Instance masks of a sequence, stored in the precomputed folder format."""

    root: Path
    """Folder with ``<camera>/<frame:02d>.png``."""
    labels: dict[int, str]
    """Class name of each instance ID (IDs >= 1)."""
    source: str
    """Which mask source made them (``grounded_sam2``, ``precomputed``, ``gt_boxes``, ...)."""

    def path(self, camera: str, frame_index: int) -> Path:
        return self.root / mask_filename(camera, frame_index)

    def load(self, camera: str, frame_index: int) -> Optional[np.ndarray]:
        """[H, W] uint16 instance IDs of one image, or None when that image has no mask file."""
        p = self.path(camera, frame_index)
        return read_instance_map(p) if p.is_file() else None


def write_labels(root: Path, labels: dict[int, str], extra: Optional[dict[int, dict]] = None) -> None:
    """Write ``instances.json``: ``{"<id>": {"label": str, ...}}``."""
    data = {str(k): {"label": v, **(extra or {}).get(k, {})} for k, v in sorted(labels.items())}
    (root / INSTANCES_JSON).write_text(json.dumps(data, indent=1))


class MaskSource(ABC):
    """Makes instance masks for every image of a scene, with IDs consistent over the sequence."""

    name: str = "base"

    @abstractmethod
    def cache_key(self) -> dict:
        """Everything the masks depend on besides the scene (settings, model files' sizes/dates)."""

    @property
    def writes_output(self) -> bool:
        """True when :meth:`generate` writes into ``out_dir`` (so the runner caches it)."""
        return True

    @abstractmethod
    def generate(self, scene: Scene, out_dir: Path, progress: bool = True) -> InstanceMaskSet:
        """Masks for ``scene``; sources that compute them write the folder format into ``out_dir``."""
