"""Hiding and highlighting instances in a render, without changing the model.

The viewer's show/hide, isolate and highlight controls come down to two operations here:

* :func:`render_camera_hiding` renders a :class:`~idsplat_ns.model.scene_model.SceneModel` with
  the Gaussians of some instance IDs left out (ID 0: the static background). The pixels an
  instance covered then show what is behind it, exactly as in a scene with that instance removed
  by :meth:`idsplat_ns.model.editing.SceneTensors.remove` (tests/test_viewer_controls.py). The
  model is not touched: the training thread may step it between two viewer renders.
* :func:`highlight` tints one instance's pixels with its palette colour.

No nerfstudio import here.
"""

from __future__ import annotations

from collections.abc import Iterable
import torch
from torch import Tensor

from idsplat_ns.model.instance_palette import instance_rgb


def visible_mask(instance_ids: Tensor, hidden: Iterable[int]) -> Tensor:  # [N] -> [N] bool
    """Which Gaussians to render: those whose instance ID is not in ``hidden``."""
    hidden = torch.as_tensor(sorted(set(int(i) for i in hidden)), dtype=torch.int64, device=instance_ids.device)
    return ~torch.isin(instance_ids.long(), hidden)


def without_hidden(posed: dict[str, Tensor], hidden: Iterable[int]) -> dict[str, Tensor]:
    """Posed Gaussians (``SceneModel.posed_gaussians``: per-Gaussian rows with ``instance_ids``)
    less the rows of the hidden IDs; the order of the kept rows is unchanged."""
    keep = visible_mask(posed["instance_ids"], hidden)
    return {k: v[keep] for k, v in posed.items()}


class _SceneHiding:
    """A read-only view of a SceneModel whose posed Gaussians leave out the hidden IDs; every
    other attribute is the model's own (decoder, embeddings, background, time offsets)."""

    def __init__(self, scene_model, hidden: frozenset[int]) -> None:
        self._scene = scene_model
        self._hidden = hidden

    def posed_gaussians(self, *args, **kwargs) -> dict[str, Tensor]:
        return without_hidden(self._scene.posed_gaussians(*args, **kwargs), self._hidden)

    def __getattr__(self, name: str):
        return getattr(self._scene, name)


def render_camera_hiding(scene_model, hidden: Iterable[int], *args, **kwargs) -> dict[str, Tensor]:
    """``scene_model.render_camera(*args, **kwargs)`` with the Gaussians of the ``hidden`` IDs
    left out."""
    hidden = frozenset(int(i) for i in hidden)
    if not hidden:
        return scene_model.render_camera(*args, **kwargs)
    # The class's own method on the view: the same code path as an ordinary render.
    return type(scene_model).render_camera(_SceneHiding(scene_model, hidden), *args, **kwargs)


def highlight(rgb: Tensor, instance_id: Tensor, target: int, strength: float = 0.5) -> Tensor:
    """``rgb`` [H, W, 3] with the pixels of instance ``target`` (``instance_id`` [H, W, 1], the
    render's ID map) blended towards its palette colour by ``strength``."""
    colour = torch.tensor(instance_rgb(target), dtype=rgb.dtype, device=rgb.device)
    mine = instance_id.long() == int(target)  # [H, W, 1]
    return torch.where(mine, (1 - strength) * rgb + strength * colour, rgb)
