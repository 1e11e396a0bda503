"""Categorical colours of instance IDs, shared by the instance renders (``ns-eval``'s
``instances`` images, the viewer's ``instances`` output and highlight) and the trajectories the
viewer draws, so that one instance has one colour everywhere.

Instance ``k >= 1`` gets entry ``(k - 1) % 256`` of colorcet's Glasbey palette
``glasbey_bw_minc_20``: 256 colours, each chosen as far as possible from the earlier ones and
from black and white, low-chroma colours left out (no entry is a grey, the static colour). The
first 32 differ pairwise by a CIEDE2000 of at least 8 (tests/test_viewer_controls.py).
The colour depends on the ID alone: an instance keeps it across frames, runs and edits
(``idsplat-edit`` keeps IDs; a duplicate gets a new ID and so a new colour). The static
background (ID 0) is mid grey and empty pixels (-1) are black.
No nerfstudio import here.
"""

from __future__ import annotations

import colorcet
import numpy as np
import torch
from torch import Tensor

PALETTE = np.asarray(colorcet.glasbey_bw_minc_20, dtype=np.float64)  # [256, 3] RGB in [0, 1]
STATIC_RGB = (0.5, 0.5, 0.5)
EMPTY_RGB = (0.0, 0.0, 0.0)


def instance_rgb(instance_id: int) -> tuple[float, float, float]:
    """RGB in [0, 1] of one ID (0: the static grey; negative: empty, black)."""
    if instance_id < 0:
        return EMPTY_RGB
    if instance_id == 0:
        return STATIC_RGB
    r, g, b = PALETTE[(int(instance_id) - 1) % len(PALETTE)]
    return float(r), float(g), float(b)


def instance_rgb_u8(instance_id: int) -> tuple[int, int, int]:
    """The colour of :func:`instance_rgb` as 0..255 integers (viser scene colours)."""
    r, g, b = instance_rgb(instance_id)
    return int(round(r * 255)), int(round(g * 255)), int(round(b * 255))


def instance_colors(ids: Tensor) -> Tensor:
    """[H, W] instance IDs (-1 empty, 0 static) as a colour image [H, W, 3] float in [0, 1]."""
    palette = torch.as_tensor(PALETTE, dtype=torch.float32, device=ids.device)  # [P, 3]
    ids = ids.long()
    rgb = palette[(ids - 1).remainder(len(PALETTE))]  # [H, W, 3]; IDs <= 0 are replaced below
    rgb = torch.where((ids == 0)[..., None], torch.tensor(STATIC_RGB, device=ids.device), rgb)
    return torch.where((ids < 0)[..., None], torch.tensor(EMPTY_RGB, device=ids.device), rgb)
