"""Consistent instance IDs over a camera's frames by mask IoU and class (used when the SAM 2 export
has no video memory): detections of each frame are assigned to the live tracks of the same class by
Hungarian matching on mask IoU; unmatched detections start new tracks."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import linear_sum_assignment


@dataclass
class _Track:
    track_id: int
    label: str
    mask: np.ndarray  # [h, w] bool, last seen mask
    last_frame: int


@dataclass
class IouTracker:
    """Assigns track IDs to per-frame masks of one camera."""

    min_iou: float = 0.3
    """Minimum mask IoU to continue a track."""
    max_gap: int = 3
    """A track not seen for more than this many frames ends."""
    next_id: int = 1
    """The ID the next new track gets (share one counter across cameras for global uniqueness)."""
    tracks: list[_Track] = field(default_factory=list)

    def update(self, frame: int, masks: list[np.ndarray], labels: list[str]) -> list[int]:
        """Track IDs for this frame's masks [h, w] bool (same order)."""
        live = [t for t in self.tracks if self._frames_unseen(t, frame) <= self.max_gap]
        ids = [-1] * len(masks)
        if live and masks:
            iou = np.zeros((len(masks), len(live)))
            for i, m in enumerate(masks):
                for j, t in enumerate(live):
                    if t.label == labels[i]:
                        inter = np.logical_and(m, t.mask).sum()
                        union = np.logical_or(m, t.mask).sum()
                        iou[i, j] = inter / union if union else 0.0
            rows, cols = linear_sum_assignment(-iou)
            for i, j in zip(rows, cols):
                if iou[i, j] >= self.min_iou:
                    ids[i] = live[j].track_id
                    live[j].mask, live[j].last_frame = masks[i], frame
        for i in range(len(masks)):
            if ids[i] < 0:
                ids[i] = self.next_id
                self.tracks.append(_Track(self.next_id, labels[i], masks[i], frame))
                self.next_id += 1
        self.tracks = [t for t in self.tracks if self._frames_unseen(t, frame) <= self.max_gap]
        return ids

    @staticmethod
    def _frames_unseen(track: _Track, frame: int) -> int:
        """Frames between the track's last sighting and ``frame`` in which it was not seen."""
        return frame - track.last_frame - 1
