"""Every random draw of a training run, captured in a checkpoint and restored on resume, so that a
run killed and resumed continues exactly as the uninterrupted run would (same camera order, same
lidar ray batches, same MCMC noise and relocations).

The draws come from: the MCMC densifier's generator (noise, relocation, growth), the lidar
supervisor's generator (sweep and ray sampling), nerfstudio's camera sampler (a ``random.Random``
and the queue of cameras not yet seen in this pass), and the global torch/numpy/python generators
for anything else. Everything is kept as tensors and plain numbers, which ``torch.load`` with
``weights_only=True`` (nerfstudio's ``eval_setup``) accepts.
"""

from __future__ import annotations

import random
from typing import Any

import numpy as np
import torch


def capture_random_state(model: Any, datamanager: Any) -> dict:
    """The generators' states of a training pipeline's ``model`` and ``datamanager`` (CPU objects)."""
    state: dict = {"torch": torch.get_rng_state(), "numpy": _numpy_state(), "python": random.getstate()}
    densifier = getattr(model, "densifier", None)
    if densifier is not None and densifier.has_generator:
        state["mcmc"] = densifier.generator_state()
    lidar = getattr(model, "lidar", None)
    if lidar is not None:
        state["lidar"] = lidar.generator.get_state()
    if hasattr(datamanager, "random_generator"):
        state["camera_sampler"] = datamanager.random_generator.getstate()
    if hasattr(datamanager, "train_unseen_cameras"):
        state["unseen_cameras"] = list(datamanager.train_unseen_cameras)
    return state


def restore_random_state(state: dict, model: Any, datamanager: Any, device: torch.device | str) -> None:
    """Put back what :func:`capture_random_state` took; parts the checkpoint lacks are left as set up."""
    torch.set_rng_state(state["torch"])
    _set_numpy_state(state["numpy"])
    random.setstate(state["python"])
    densifier = getattr(model, "densifier", None)
    if densifier is not None and "mcmc" in state:
        densifier.set_generator_state(state["mcmc"], device)
    lidar = getattr(model, "lidar", None)
    if lidar is not None and "lidar" in state:
        lidar.generator.set_state(state["lidar"])
    if "camera_sampler" in state:
        datamanager.random_generator = random.Random()
        datamanager.random_generator.setstate(state["camera_sampler"])
    if "unseen_cameras" in state:
        datamanager.train_unseen_cameras = list(state["unseen_cameras"])


def _numpy_state() -> dict:
    """numpy's global Mersenne Twister state with its key array as a tensor (no numpy objects)."""
    name, keys, pos, has_gauss, cached = np.random.get_state()
    return {"name": str(name), "keys": torch.from_numpy(keys.astype(np.int64)), "pos": int(pos),
            "has_gauss": int(has_gauss), "cached_gaussian": float(cached)}


def _set_numpy_state(state: dict) -> None:
    np.random.set_state((state["name"], state["keys"].numpy().astype(np.uint32), state["pos"],
                         state["has_gauss"], state["cached_gaussian"]))
