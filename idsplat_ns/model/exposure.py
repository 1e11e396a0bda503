"""Per-image colour correction: exposure and white balance that drift over a drive.

Auto-exposure changes an image's brightness from frame to frame (gains of 0.7-1.3 are ordinary),
which no per-camera term can absorb. Each training image gets an affine colour transform
``rgb' = (I + A) rgb + b`` (``A`` [3, 3], ``b`` [3]; 12 numbers, zero at the start: identity),
learned with the scene and kept near identity by a prior (:meth:`ImageExposure.prior`) and,
optionally, near its neighbours in time (:meth:`ImageExposure.smoothness`). Any other
time of the same camera takes the transform interpolated in time
(:class:`~idsplat_ns.model.camera_knots.CameraKnots`); a camera without training images is left as
rendered. DriveStudio and OmniRe fit such an affine per image.
"""

from __future__ import annotations

from typing import Optional, Sequence

import numpy as np
import torch
from torch import Tensor, nn

from idsplat_ns.model.camera_knots import CameraKnots


class ImageExposure(CameraKnots):
    """One affine colour transform per training image, interpolated in time per camera."""

    def __init__(self, knot_times: Sequence[np.ndarray]) -> None:
        """``knot_times[c]``: the times [s] of camera ``c``'s training images."""
        super().__init__(knot_times)
        self.affine = nn.Parameter(torch.zeros(self.num_knots, 3, 4))  # [K, 3, 4] (A | b), 0: identity

    def transform_at(self, sensor: int, time: Optional[float]) -> Optional[Tensor]:
        """The [3, 4] correction ``(A | b)`` of camera ``sensor`` at ``time`` [s]; None where there is none."""
        return self.value_at(self.affine, sensor, time)

    def forward(self, rgb: Tensor, sensor: int, time: Optional[float]) -> Tensor:  # rgb: [..., 3]
        """``rgb`` corrected as camera ``sensor`` saw it at ``time`` (unchanged without a transform)."""
        d = self.transform_at(sensor, time)
        if d is None:
            return rgb
        return rgb + rgb @ d[:, :3].T + d[:, 3]

    def prior(self) -> Tensor:
        """Mean square of the transforms' offsets from identity (a scalar to add to the loss)."""
        return self.affine.square().mean() if self.affine.numel() else self.affine.sum()

    def smoothness(self) -> Tensor:
        """Mean square of each transform's offset from the interpolation of its camera's neighbours
        at its time (a scalar to add to the loss): a gain that drifts smoothly over the drive costs
        nothing, one image's transform that fits what the scene should is drawn back to its
        neighbours', and so is what a held-out frame between them is given."""
        residual = self.interpolation_residual(self.affine)
        return residual.square().mean() if residual.numel() else self.affine.sum() * 0.0
