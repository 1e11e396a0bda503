"""Train / evaluation frame splits of the paper's protocols.

Frames are selected linearly spaced: with a train fraction f of F frames, ``F - round(f F)``
evaluation frames are spread evenly strictly inside the sequence (so evaluation interpolates
between training frames), and the rest train. At f = 1 every frame is used for both, as in the
paper's view-density study. Protocols that say "every k-th frame" use ``eval_every=k``.
"""

from __future__ import annotations

from typing import Optional

import numpy as np

from idsplat_ns.errors import IDSplatError


def split_frames(
    num_frames: int, train_fraction: float = 0.5, eval_every: Optional[int] = None, eval_offset: int = 0
) -> tuple[np.ndarray, np.ndarray]:
    """Indices (into the kept frames) of the training frames and of the evaluation frames.

    ``eval_every=k`` makes frames ``i`` with ``i % k == eval_offset`` the evaluation frames and
    overrides ``train_fraction``.
    """
    if num_frames < 1:
        raise IDSplatError("the scene has no frames: check the start/end frame options")
    frames = np.arange(num_frames)
    if eval_every is not None:
        if eval_every < 2:
            raise IDSplatError(f"eval_every={eval_every}: must be >= 2 (or None to use train_fraction)")
        is_eval = frames % eval_every == eval_offset % eval_every
        return frames[~is_eval], frames[is_eval]
    if not 0.0 < train_fraction <= 1.0:
        raise IDSplatError(f"train_fraction={train_fraction}: must be in (0, 1]")
    if train_fraction >= 1.0:
        return frames, frames.copy()
    num_eval = num_frames - int(round(train_fraction * num_frames))
    num_eval = min(max(num_eval, 1), num_frames - 1) if num_frames > 1 else 0
    if num_eval == 0:
        return frames, frames.copy()
    eval_idx = np.unique(np.round(np.linspace(0, num_frames - 1, num_eval + 2)[1:-1]).astype(int))
    is_eval = np.zeros(num_frames, bool)
    is_eval[eval_idx] = True
    return frames[~is_eval], frames[is_eval]
