"""Camera pose refinement: small rigid corrections of the cameras' poses, learned with the scene,
per camera (the rig's calibration) and per image (each frame's pose).

Real rigs are calibrated to fractions of a degree (Waymo's and PandaSet's camera-to-lidar
calibrations are off by that much), and a camera turned by 1 degree misplaces a point 35 m away by
0.6 m. The lidar fixes the geometry; each camera ``c`` gets a correction ``E_c = [exp(w_c) | t_c]``
applied in the camera's own frame to every image of that camera, training and held-out alike:
``V' = E_c V`` for the world-to-camera matrix ``V``. Zero at the start (identity), kept near zero by
a Gaussian prior (:meth:`RigCorrection.prior`) where the images do not ask for more. Per camera,
not per image: a calibration error is the same in every frame, and only a per-camera correction
also corrects the held-out frames.

Recorded poses also carry errors that change over a drive (PandaSet's are known to). Each training
image ``i`` can get its own correction ``E_i`` (:class:`ImagePoseCorrection`), on top of its
camera's: ``V' = E_i E_c V``. A held-out frame takes the correction interpolated in time between its
camera's training images (:class:`~idsplat_ns.model.camera_knots.CameraKnots`): a pose error that
wanders over the drive is corrected there too, one that jumps from frame to frame cannot be.
"""

from __future__ import annotations

import math
from typing import Optional, Sequence

import numpy as np
import torch
from torch import Tensor, nn

from idsplat_ns.model.camera_knots import CameraKnots
from idsplat_ns.model.so3 import so3_exp


def rigid_correction(rotation: Tensor, translation: Tensor) -> Tensor:  # [3] axis-angle, [3] -> [4, 4]
    """``[exp(rotation) | translation]`` as a 4x4 matrix, differentiable in both."""
    top = torch.cat([so3_exp(rotation), translation[:, None]], dim=1)  # [3, 4]
    bottom = torch.tensor([[0.0, 0.0, 0.0, 1.0]], dtype=top.dtype, device=top.device)
    return torch.cat([top, bottom], dim=0)


def correction_sizes(rotation: Tensor, translation: Tensor) -> tuple[np.ndarray, np.ndarray]:  # [N, 3], [N, 3]
    """Per row: the rotation's angle in degrees [N] and the translation's length in metres [N]."""
    with torch.no_grad():
        return (torch.rad2deg(rotation.norm(dim=-1)).cpu().numpy().astype(np.float64),
                translation.norm(dim=-1).cpu().numpy().astype(np.float64))


def prior_in_units(rotation: Tensor, translation: Tensor, rotation_sigma_deg: float,
                   translation_sigma_m: float) -> Tensor:  # rotation, translation: [N, 3]
    """Mean over rows of the squared corrections in units of their expected size (0 for no rows)."""
    if rotation.shape[0] == 0:
        return rotation.sum()
    rot = rotation / math.radians(rotation_sigma_deg)
    trans = translation / translation_sigma_m
    return (rot.square().sum(-1) + trans.square().sum(-1)).mean()


class RigCorrection(nn.Module):
    """A rotation (so(3), radians) and translation (metres) per camera, in the camera frame."""

    def __init__(self, num_cameras: int) -> None:
        super().__init__()
        self.rotation = nn.Parameter(torch.zeros(num_cameras, 3))  # [C, 3] axis-angle
        self.translation = nn.Parameter(torch.zeros(num_cameras, 3))  # [C, 3]

    @property
    def num_cameras(self) -> int:
        return int(self.rotation.shape[0])

    def correction(self, sensor: int) -> Tensor:  # -> [4, 4]
        """``E_c`` of camera ``sensor`` (camera frame, world-to-camera side)."""
        return rigid_correction(self.rotation[sensor], self.translation[sensor])

    def forward(self, viewmat: Tensor, sensor: int) -> Tensor:  # viewmat: [4, 4] world-to-camera
        """``viewmat`` of an image of camera ``sensor`` with that camera's correction (unchanged for
        a camera the rig does not have, such as the viewer's)."""
        if not 0 <= sensor < self.num_cameras:
            return viewmat
        return self.correction(sensor).to(viewmat) @ viewmat

    def prior(self, rotation_sigma_deg: float, translation_sigma_m: float) -> Tensor:
        """Mean over cameras of the squared corrections in units of their expected size."""
        return prior_in_units(self.rotation, self.translation, rotation_sigma_deg, translation_sigma_m)

    def summary(self) -> list[tuple[float, float]]:
        """Per camera: (rotation in degrees, translation in metres) of its correction."""
        deg, metres = correction_sizes(self.rotation, self.translation)
        return list(zip(deg.tolist(), metres.tolist()))


class ImagePoseCorrection(CameraKnots):
    """A rotation (so(3), radians) and translation (metres) per training image, in its camera's
    frame, interpolated in time per camera for the camera's other frames."""

    def __init__(self, knot_times: Sequence[np.ndarray]) -> None:
        """``knot_times[c]``: the times [s] of camera ``c``'s training images."""
        super().__init__(knot_times)
        self.rotation = nn.Parameter(torch.zeros(self.num_knots, 3))  # [K, 3] axis-angle
        self.translation = nn.Parameter(torch.zeros(self.num_knots, 3))  # [K, 3]

    def correction_at(self, sensor: int, time: Optional[float]) -> Optional[Tensor]:  # -> [4, 4]
        """``E_i`` of camera ``sensor`` at ``time`` [s]; None where there is none."""
        p = self.value_at(torch.cat([self.rotation, self.translation], dim=1), sensor, time)
        return None if p is None else rigid_correction(p[:3], p[3:])

    def forward(self, viewmat: Tensor, sensor: int, time: Optional[float]) -> Tensor:  # viewmat: [4, 4]
        """``viewmat`` of camera ``sensor`` at ``time`` with the image's correction (unchanged where
        there is none: a camera the recording does not have, no time)."""
        E = self.correction_at(sensor, time)
        return viewmat if E is None else E.to(viewmat) @ viewmat

    def prior(self, rotation_sigma_deg: float, translation_sigma_m: float) -> Tensor:
        """Mean over training images of the squared corrections in units of their expected size."""
        return prior_in_units(self.rotation, self.translation, rotation_sigma_deg, translation_sigma_m)

    def smoothness(self, rotation_sigma_deg: float, translation_sigma_m: float) -> Tensor:
        """Mean over the training images between two others of their camera of how far each
        correction is from the interpolation of its neighbours' at its time, in units of the
        expected correction: a pose error that wanders smoothly costs nothing, a correction that
        absorbs what the scene should fit in one image is drawn back to its neighbours'."""
        residual = self.interpolation_residual(torch.cat([self.rotation, self.translation], dim=1))
        return prior_in_units(residual[:, :3], residual[:, 3:], rotation_sigma_deg, translation_sigma_m)

    def summary(self) -> list[tuple[float, float]]:
        """Per camera: the median over its training images of (rotation in degrees, translation in
        metres) of their corrections (0, 0 for a camera without training images)."""
        deg, metres = correction_sizes(self.rotation, self.translation)
        bounds = self._host_starts.tolist()
        return [(float(np.median(deg[s:e])), float(np.median(metres[s:e]))) if e > s else (0.0, 0.0)
                for s, e in zip(bounds[:-1], bounds[1:])]
