"""Masks brought from any tool, as a folder:

    <dir>/<camera>/<frame:02d>.png   uint16 instance-ID map per image (0 = no object, k >= 1 instance k),
                                     same size as the image; <frame> is the dataset frame index and
                                     <camera> the dataset's camera name (PandaSet: ``front_camera``).
    <dir>/instances.json             {"<k>": {"label": "car", ...}} for every ID k that appears;
                                     extra keys (uuid, moving, score) are kept but not used.

IDs must be consistent over the whole sequence and across cameras (the same object has the same
ID everywhere; where a tool only gives per-camera tracks, use distinct IDs per camera and lifting
merges them through shared lidar points). An image without a PNG has no masks (a missed frame).
The synthetic generator's ``idsplat_extras/instance_masks`` (with ``idsplat_extras/instances.json``)
is in this format.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Optional

from idsplat_ns.data.scene import Scene
from idsplat_ns.errors import IDSplatError
from idsplat_ns.instances.masks.base import INSTANCES_JSON, InstanceMaskSet, MaskSource
from idsplat_ns.instances.options import cli_option


@dataclass(frozen=True)
class PrecomputedMasksConfig:
    """Where precomputed masks are."""

    mask_dir: Optional[Path] = None
    """Folder with ``<camera>/<frame:02d>.png``."""
    instances_json: Optional[Path] = None
    """The class file; default ``<mask_dir>/instances.json``."""


def read_labels(path: Path) -> dict[int, str]:
    """Read ``instances.json`` into {id: label}."""
    if not path.is_file():
        raise IDSplatError(f"{path}: instances.json not found; write {{\"<id>\": {{\"label\": \"car\"}}}} for every mask ID")
    try:
        data = json.loads(path.read_text())
        labels = {int(k): str(v["label"]).strip().lower() for k, v in data.items()}
    except (ValueError, KeyError, TypeError, AttributeError) as err:
        raise IDSplatError(f"{path}: malformed ({err}); expected {{\"<id>\": {{\"label\": \"car\"}}}}") from None
    if any(k < 1 or k > 65535 for k in labels):
        raise IDSplatError(f"{path}: instance IDs must be in 1..65535 (0 is the background)")
    return labels


def load_mask_set(mask_dir: Path, instances_json: Optional[Path] = None, source: str = "precomputed") -> InstanceMaskSet:
    """Open a mask folder (checks the folder and the class file; PNGs are read on demand)."""
    mask_dir = Path(mask_dir)
    if not mask_dir.is_dir():
        raise IDSplatError(f"{mask_dir}: mask folder not found; give {cli_option('masks.precomputed.mask-dir')} a folder with <camera>/<frame:02d>.png")
    labels = read_labels(Path(instances_json) if instances_json else mask_dir / INSTANCES_JSON)
    return InstanceMaskSet(root=mask_dir, labels=labels, source=source)


def folder_fingerprint(mask_dir: Path) -> str:
    """Hash of the names, sizes and modification times of every file under ``mask_dir``."""
    h = hashlib.blake2b(digest_size=16)
    for p in sorted(Path(mask_dir).rglob("*")):
        if p.is_file():
            st = p.stat()
            h.update(f"{p.relative_to(mask_dir)}|{st.st_size}|{st.st_mtime_ns}\n".encode())
    return h.hexdigest()


class PrecomputedMaskSource(MaskSource):
    """Reads masks from a user-given folder (nothing is copied)."""

    name = "precomputed"

    def __init__(self, config: PrecomputedMasksConfig):
        if config.mask_dir is None:
            raise IDSplatError(f"{cli_option('masks.precomputed.mask-dir')} is not set; give the folder of precomputed instance masks")
        self.config = config

    def cache_key(self) -> dict:
        json_path = self.config.instances_json or Path(self.config.mask_dir) / INSTANCES_JSON
        return {"source": self.name, "dir": str(Path(self.config.mask_dir).resolve()),
                "fingerprint": folder_fingerprint(Path(self.config.mask_dir)),
                "instances_json": str(json_path), "json_fingerprint": hashlib.blake2b(Path(json_path).read_bytes(), digest_size=16).hexdigest()
                if Path(json_path).is_file() else "missing"}

    @property
    def writes_output(self) -> bool:
        return False

    def generate(self, scene: Scene, out_dir: Path, progress: bool = True) -> InstanceMaskSet:
        masks = load_mask_set(Path(self.config.mask_dir), self.config.instances_json)
        if not any(masks.path(im.camera, im.frame_index).is_file() for im in scene.images):
            raise IDSplatError(
                f"{self.config.mask_dir}: no mask PNG matches any image of {scene.name} "
                f"(expected e.g. {masks.path(scene.images[0].camera, scene.images[0].frame_index) if scene.images else '<camera>/00.png'})"
            )
        return masks
