"""Give a scene model the shape of a checkpoint's parts before its state dict is loaded.

ns-eval and the viewer rebuild the model from today's data, code and settings, which can find
other instances (re-run preprocessing), or none, or another deformation than the run trained
with: the checkpoint is the truth, so its trajectories and deformation are rebuilt in its shape
(as placeholders that the state dict then fills).
"""

from __future__ import annotations

import torch
from torch import nn

from idsplat_ns.model.deformation import InstanceDeformation
from idsplat_ns.model.trajectories import InstanceTrajectories


def trajectories_like(scene_model: nn.Module, state_dict: dict, refine: bool, device: torch.device | str,
                      prefix: str = "scene_model.") -> bool:
    """Make ``scene_model``'s instance trajectories (and the camera time offsets that come with
    them) the checkpoint's shape: none when it has none. Returns whether they were rebuilt."""
    key = prefix + "trajectories."
    if key + "positions" not in state_dict:
        scene_model.trajectories = None
        scene_model.camera_time_offset = None
        return False
    Z, F = state_dict[key + "positions"].shape[:2]
    ids = state_dict[key + "instance_ids"]
    current = scene_model.trajectories
    if current is not None and current.positions.shape[:2] == (Z, F) and torch.equal(current.instance_ids.cpu(), ids.cpu()):
        return False
    scene_model.trajectories = InstanceTrajectories.placeholder(Z, F, refine=refine).to(device)
    offsets = state_dict.get(prefix + "camera_time_offset")
    if offsets is not None and scene_model.camera_time_offset is None:
        scene_model.camera_time_offset = nn.Parameter(torch.zeros_like(offsets))
    return True


def deformation_like(scene_model: nn.Module, state_dict: dict, device: torch.device | str,
                     prefix: str = "scene_model.") -> None:
    """Give ``scene_model`` the checkpoint's deformation (or none), whatever today's settings say."""
    codes = state_dict.get(prefix + "deformation.codes")
    if codes is None:
        scene_model.deformation = None
        return
    D, F, C = codes.shape
    first = state_dict[prefix + "deformation.mlp.0.weight"]
    hidden = int(first.shape[0])
    freqs = (int(first.shape[1]) - C - 3) // 6
    current = scene_model.deformation
    if current is not None and tuple(current.codes.shape) == (D, F, C) and current.mlp[0].out_features == hidden \
            and current.position_freqs == freqs:
        return
    scene_model.deformation = InstanceDeformation.placeholder(D, F, C, hidden, freqs).to(device)
