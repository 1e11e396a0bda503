"""Oracle masks: ground-truth 3D boxes projected into every image (ablations and upper bounds only).

Each box is clipped at a near plane, projected with the full camera model, and filled as the convex
hull of its projected outline; nearer boxes are painted over farther ones. IDs are the track's
position in ``scene.tracks`` plus one. This reads the ground-truth tracks, so it is never a default.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from tqdm import tqdm

from idsplat_ns.data.camera import CameraImage
from idsplat_ns.data.scene import Scene
from idsplat_ns.data.dynamic_masks import box_silhouette
from idsplat_ns.errors import IDSplatError
from idsplat_ns.instances.masks.base import InstanceMaskSet, MaskSource, write_instance_map, write_labels
from idsplat_ns.instances.options import cli_option

@dataclass(frozen=True)
class GtBoxMasksConfig:
    """Which ground-truth boxes become oracle masks."""

    groups: tuple[str, ...] = ("vehicle", "pedestrian", "cyclist")
    """Label groups kept (see ``idsplat_ns.data.tracks.label_group``)."""
    moving_only: bool = False
    """Keep only tracks flagged as moving (Grounded-SAM-2 also sees parked objects, hence False)."""
    near_plane: float = 0.1
    """Metres: box parts closer to the camera than this are clipped away."""


def render_gt_box_masks(scene: Scene, image: CameraImage, track_ids: list[int], config: GtBoxMasksConfig) -> np.ndarray:
    """[H, W] uint16 oracle instance map of one image (ID = track index + 1)."""
    K = image.intrinsics
    ids = np.zeros((K.height, K.width), np.uint16)
    items = []
    for ti in track_ids:
        track = scene.tracks[ti]
        pose = track.pose_at_frame(image.frame_index)
        if pose is None:
            continue
        depth = float((pose[:3, 3] - image.camera_to_world[:3, 3]) @ image.camera_to_world[:3, 2])
        items.append((depth, ti, pose, track.size))
    for _, ti, pose, size in sorted(items, key=lambda x: -x[0]):  # far to near: near boxes win
        poly = box_silhouette(image, pose, size, config.near_plane)
        if poly is not None and len(poly) >= 3:
            cv2.fillConvexPoly(ids, poly, int(ti + 1))
    return ids


class GtBoxMaskSource(MaskSource):
    """Projects ground-truth boxes (oracle)."""

    name = "gt_boxes"

    def __init__(self, config: GtBoxMasksConfig):
        self.config = config

    def cache_key(self) -> dict:
        return {"source": self.name, "groups": list(self.config.groups), "moving_only": self.config.moving_only,
                "near_plane": self.config.near_plane}

    def generate(self, scene: Scene, out_dir: Path, progress: bool = True) -> InstanceMaskSet:
        if not scene.tracks:
            raise IDSplatError(f"scene {scene.name} has no ground-truth tracks; {cli_option('masks.kind')} gt_boxes needs annotations")
        keep = [i for i, t in enumerate(scene.tracks)
                if t.group in self.config.groups and (t.moving or not self.config.moving_only)]
        if len(keep) >= 65535:
            raise IDSplatError(f"scene {scene.name}: too many ground-truth tracks for uint16 IDs")
        out_dir.mkdir(parents=True, exist_ok=True)
        for image in tqdm(scene.images, desc="oracle masks", disable=not progress):
            write_instance_map(out_dir / image.camera / f"{image.frame_index:02d}.png",
                               render_gt_box_masks(scene, image, keep, self.config))
        labels = {i + 1: scene.tracks[i].label.lower() for i in keep}
        write_labels(out_dir, labels, {i + 1: {"track_id": scene.tracks[i].track_id} for i in keep})
        return InstanceMaskSet(out_dir, labels, self.name)
