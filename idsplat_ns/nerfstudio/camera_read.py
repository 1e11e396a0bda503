"""What a render needs from a nerfstudio ``Cameras``, read from the device in one transfer.

The datamanager hands the model a ``Cameras`` on the training device. Its image size, intrinsics,
sensor index and time are scalars the host needs (the image size allocates the render; the time
picks the instances' poses), and each ``int(...)`` or ``float(...)`` of a CUDA tensor waits for the
GPU to finish everything queued before it. They are gathered into one float64 vector and read once
(integers and float32 values are exact in float64).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

import torch
from nerfstudio.cameras.cameras import Cameras
from torch import Tensor


@dataclass(frozen=True)
class HostCamera:
    """One camera's render inputs on the host."""

    camera_to_world: Tensor  # [3, 4] CPU, the camera's dtype, OpenGL axes
    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    sensor: Optional[int]  # metadata["sensor_idx"]: a recorded camera of the rig; None for others
    time_seconds: Optional[float]  # metadata["time_seconds"]: the image's own time
    time_fraction: Optional[float]  # ``camera.times``: the viewer's [0, 1] slider


def read_camera(camera: Cameras) -> HostCamera:  # camera: a Cameras of shape [1]
    """The render inputs of ``camera`` in one device-to-host transfer."""
    meta = camera.metadata or {}
    optional = [meta.get("sensor_idx"), meta.get("time_seconds"), camera.times]
    parts = [camera.camera_to_worlds[0].reshape(-1), camera.width.reshape(-1)[:1], camera.height.reshape(-1)[:1],
             camera.fx.reshape(-1)[:1], camera.fy.reshape(-1)[:1], camera.cx.reshape(-1)[:1], camera.cy.reshape(-1)[:1],
             *(t.reshape(-1)[:1] for t in optional if t is not None)]
    values = torch.cat([p.to(torch.float64) for p in parts]).cpu()
    c2w = values[:12].reshape(3, 4).to(camera.camera_to_worlds.dtype)
    scalars = values[12:].tolist()
    width, height, fx, fy, cx, cy = scalars[:6]
    rest = iter(scalars[6:])
    sensor, time_seconds, fraction = (next(rest) if t is not None else None for t in optional)
    return HostCamera(c2w, int(width), int(height), fx, fy, cx, cy, None if sensor is None else int(sensor),
                      time_seconds, fraction)
