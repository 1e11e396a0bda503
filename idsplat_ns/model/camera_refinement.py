"""Camera calibration refinement: one small rigid correction per camera of the rig, learned with
the scene.

Real rigs are calibrated to fractions of a degree (Waymo's and PandaSet's camera-to-lidar
calibrations are off by that much), and a camera turned by 1 degree misplaces a point 35 m away by
0.6 m. The lidar fixes the geometry; each camera ``c`` gets a correction ``E_c = [exp(w_c) | t_c]``
applied in the camera's own frame to every image of that camera, training and held-out alike:
``V' = E_c V`` for the world-to-camera matrix ``V``. Zero at the start (identity), kept near zero by
a Gaussian prior (:meth:`RigCorrection.prior`) where the images do not ask for more. Per camera,
not per image: a calibration error is the same in every frame, and only a per-camera correction
also corrects the held-out frames.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor, nn

from idsplat_ns.model.trajectories import so3_exp


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
        E = torch.eye(4, dtype=self.rotation.dtype, device=self.rotation.device)
        E = E.index_put((torch.arange(3, device=E.device)[:, None], torch.arange(3, device=E.device)[None]),
                        so3_exp(self.rotation[sensor]))
        return E.index_put((torch.arange(3, device=E.device), torch.full((3,), 3, device=E.device)),
                           self.translation[sensor])

    def forward(self, viewmat: Tensor, sensor: int) -> Tensor:  # viewmat: [4, 4] world-to-camera
        """``viewmat`` of an image of camera ``sensor`` with that camera's correction (unchanged for
        a camera the rig does not have, such as the viewer's)."""
        if not 0 <= sensor < self.num_cameras:
            return viewmat
        return self.correction(sensor).to(viewmat) @ viewmat

    def prior(self, rotation_sigma_deg: float, translation_sigma_m: float) -> Tensor:
        """Mean over cameras of the squared corrections in units of their expected size."""
        rot = self.rotation / math.radians(rotation_sigma_deg)
        trans = self.translation / translation_sigma_m
        return (rot.square().sum(-1) + trans.square().sum(-1)).mean()

    def summary(self) -> list[tuple[float, float]]:
        """Per camera: (rotation in degrees, translation in metres) of its correction."""
        with torch.no_grad():
            deg = torch.rad2deg(self.rotation.norm(dim=-1)).tolist()
            metres = self.translation.norm(dim=-1).tolist()
        return list(zip(deg, metres))
