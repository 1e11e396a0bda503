"""Noisy copies of instance masks, to test how the pipeline copes with imperfect segmentation:
edges dilated or eroded per instance, instances missing in some frames, spurious masks, and
identities swapped between two instances of one image (a tracker's ID switch)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from idsplat_ns.data.scene import Scene
from idsplat_ns.instances.masks.base import InstanceMaskSet, write_instance_map, write_labels


@dataclass(frozen=True)
class MaskNoiseConfig:
    """How masks are corrupted."""

    max_edge_px: int = 3
    """Each instance's mask in each image is dilated or eroded by up to this many pixels (random)."""
    miss_probability: float = 0.1
    """Probability that an instance's mask is dropped from an image (missed detection)."""
    spurious_per_sequence: int = 1
    """Spurious masks added: each is a random ellipse with a new ID in several frames of one camera."""
    spurious_frames: int = 5
    """How many consecutive frames each spurious mask appears in."""
    spurious_label: str = "car"
    """Class given to spurious masks."""
    swap_probability: float = 0.0
    """Probability that, in an image with two or more instances, two of them exchange their IDs."""
    seed: int = 0
    """Random seed."""


def _kernel(r: int) -> np.ndarray:
    return cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1))


def perturb_instance_map(ids: np.ndarray, config: MaskNoiseConfig, rng: np.random.Generator) -> np.ndarray:
    """One noisy copy of an instance map [H, W] (uint16)."""
    out = np.zeros_like(ids)
    for k in np.unique(ids):
        if k == 0 or rng.random() < config.miss_probability:
            continue
        m = (ids == k).astype(np.uint8)
        r = int(rng.integers(-config.max_edge_px, config.max_edge_px + 1))
        if r > 0:
            m = cv2.dilate(m, _kernel(r))
        elif r < 0:
            m = cv2.erode(m, _kernel(-r))
        out[(m > 0) & (out == 0)] = k
    present = np.unique(out[out > 0])
    if len(present) >= 2 and rng.random() < config.swap_probability:
        a, b = rng.choice(present, size=2, replace=False)
        in_a, in_b = out == a, out == b
        out[in_a], out[in_b] = b, a
    return out


def perturb_mask_set(masks: InstanceMaskSet, scene: Scene, out_dir: Path, config: MaskNoiseConfig) -> InstanceMaskSet:
    """Write a noisy copy of ``masks`` for every image of ``scene`` into ``out_dir``."""
    rng = np.random.default_rng(config.seed)
    labels = dict(masks.labels)
    next_id = max(labels, default=0) + 1
    spurious: dict[tuple[str, int], list[tuple[int, tuple]]] = {}
    cameras, frames = scene.camera_names, sorted({im.frame_index for im in scene.images})
    for _ in range(config.spurious_per_sequence):
        cam = cameras[int(rng.integers(len(cameras)))]
        start = int(rng.integers(0, max(1, len(frames) - config.spurious_frames)))
        K = scene.images_of(cam)[0].intrinsics
        centre = (int(rng.uniform(0.2, 0.8) * K.width), int(rng.uniform(0.4, 0.8) * K.height))
        axes = (max(3, K.width // 12), max(3, K.height // 12))
        for f in frames[start : start + config.spurious_frames]:
            spurious.setdefault((cam, f), []).append((next_id, (centre, axes)))
        labels[next_id] = config.spurious_label
        next_id += 1
    out_dir.mkdir(parents=True, exist_ok=True)
    for image in scene.images:
        ids = masks.load(image.camera, image.frame_index)
        if ids is None:
            continue
        noisy = perturb_instance_map(ids, config, rng)
        for k, (centre, axes) in spurious.get((image.camera, image.frame_index), []):
            blob = np.zeros(noisy.shape, np.uint8)
            cv2.ellipse(blob, centre, axes, 0, 0, 360, 1, -1)
            noisy[blob > 0] = k
        write_instance_map(out_dir / image.camera / f"{image.frame_index:02d}.png", noisy)
    write_labels(out_dir, labels)
    return InstanceMaskSet(out_dir, labels, f"{masks.source}+noise")
