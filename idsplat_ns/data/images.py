"""Decoding images and ground-truth masks of a :class:`CameraImage` at a chosen scale."""

from __future__ import annotations

import io
from pathlib import Path
from typing import Optional

import numpy as np
from PIL import Image, UnidentifiedImageError

from idsplat_ns.data.camera import CameraImage, Intrinsics
from idsplat_ns.errors import IDSplatError

UNDISTORT_FROM = "undistort_from"  # CameraImage.metadata key: the lens model the pixels still have


def _open(image: CameraImage) -> Image.Image:
    try:
        if image.image_path is not None:
            with Image.open(image.image_path) as im:
                return im.convert("RGB")
        if image.image_bytes is not None:
            return Image.open(io.BytesIO(image.image_bytes)).convert("RGB")
    except (UnidentifiedImageError, OSError) as err:
        where = image.image_path or f"{image.camera} frame {image.frame_index}"
        raise IDSplatError(f"{where}: unreadable image ({err.__class__.__name__}); re-download or regenerate it") from None
    if image.image is not None:
        return Image.fromarray(image.image)
    raise IDSplatError(f"{image.camera} frame {image.frame_index}: the image has no path, bytes or pixels")


def undistorted_view(image: CameraImage) -> CameraImage:
    """The same image seen through a pinhole with the same K: pixels are undistorted on load.

    Rasterizers are pinhole; undistorting the image once (rather than distorting every render)
    keeps masks, projections and renders consistent through ``intrinsics``.
    """
    from dataclasses import replace

    if not image.intrinsics.has_distortion:
        return image
    pinhole = replace(image.intrinsics, distortion=(0.0, 0.0, 0.0, 0.0, 0.0))
    return replace(image, intrinsics=pinhole, metadata={**image.metadata, UNDISTORT_FROM: image.intrinsics})


def _undistort(pixels: np.ndarray, lens: Intrinsics) -> np.ndarray:
    import cv2

    h, w = pixels.shape[:2]
    lens = lens.scaled(w / lens.width) if w != lens.width else lens
    maps = cv2.initUndistortRectifyMap(lens.K, np.array(lens.distortion), None, lens.K, (w, h), cv2.CV_32FC1)
    return cv2.remap(pixels, maps[0], maps[1], interpolation=cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)


def load_rgb(image: CameraImage, scale: float = 1.0) -> np.ndarray:
    """The image as [H, W, 3] uint8, resized by ``scale`` to the size of ``intrinsics.scaled(scale)``.

    Views made by :func:`undistorted_view` are undistorted at full resolution first.
    """
    im = _open(image)
    lens = image.metadata.get(UNDISTORT_FROM)
    if lens is not None:
        im = Image.fromarray(_undistort(np.asarray(im), lens))
    target = image.intrinsics.scaled(scale)
    if im.size != (target.width, target.height):
        im = im.resize((target.width, target.height), Image.BILINEAR if scale >= 1 else Image.BOX)
    return np.array(im, dtype=np.uint8)  # a writable copy (torch.from_numpy warns on read-only arrays)


def read_instance_map(path: Path) -> np.ndarray:
    """[H, W] uint16 instance IDs from a single-channel 16-bit PNG (0 = no object)."""
    import cv2

    ids = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if ids is None or ids.ndim != 2 or ids.dtype != np.uint16:
        raise IDSplatError(f"{path}: not a single-channel uint16 PNG instance map; rewrite it as documented in docs/instances.md")
    return ids


def write_instance_map(path: Path, ids: np.ndarray) -> None:  # ids: [H, W] integer
    """Write one instance-ID map as a lossless 16-bit PNG (creating the folder)."""
    import cv2

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    if ids.max(initial=0) > np.iinfo(np.uint16).max or ids.min(initial=0) < 0:
        raise ValueError("instance IDs must fit in uint16")
    if not cv2.imwrite(str(path), ids.astype(np.uint16)):
        raise IDSplatError(f"{path}: could not write the instance map; check that the folder is writable")


def load_instance_mask(image: CameraImage, scale: float = 1.0) -> Optional[np.ndarray]:
    """The ground-truth instance-ID map [H, W] (int64) at ``scale`` (nearest), or None if there is none."""
    if image.instance_mask_path is None:
        return None
    mask = read_instance_map(image.instance_mask_path).astype(np.int64)
    target = image.intrinsics.scaled(scale)
    if mask.shape != (target.height, target.width):
        rows = np.minimum((np.arange(target.height) + 0.5) * mask.shape[0] / target.height, mask.shape[0] - 1).astype(int)
        cols = np.minimum((np.arange(target.width) + 0.5) * mask.shape[1] / target.width, mask.shape[1] - 1).astype(int)
        mask = mask[rows][:, cols]
    return mask
