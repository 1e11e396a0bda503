"""The scene model's camera backend (``--pipeline.model.camera-backend``; that the option reaches the
scene model is tested in test_scene_summary.py): ``torch`` renders what ``auto`` renders on the CPU,
and a backend the tensors cannot use fails in one line."""

from __future__ import annotations

import math

import pytest
import torch

from idsplat_ns.errors import IDSplatError
from idsplat_ns.model.gaussians import GaussianSet
from idsplat_ns.model.scene_model import DecoderConfig, SceneModel

K = torch.tensor([[40.0, 0.0, 32.0], [0.0, 40.0, 24.0], [0.0, 0.0, 1.0]])


def _scene(backend: str) -> SceneModel:
    gen = torch.Generator().manual_seed(0)
    g = GaussianSet(200, feature_dim=4)
    with torch.no_grad():
        g.means.copy_(torch.randn(200, 3, generator=gen) + torch.tensor([0.0, 0.0, 6.0]))
        g.scales.fill_(math.log(0.2))
        g.opacities.fill_(1.0)
        g.features_rgb.copy_(torch.randn(200, 3, generator=gen))
    return SceneModel(g, 1, DecoderConfig(feature_dim=4), camera_backend=backend).eval()


def test_the_torch_backend_renders_what_auto_renders_on_the_cpu():
    auto, torch_backend = _scene("auto"), _scene("torch")
    with torch.no_grad():
        a = auto.render_camera(torch.eye(4), K, 64, 48, None)
        b = torch_backend.render_camera(torch.eye(4), K, 64, 48, None)
    assert a["accumulation"].max() > 0.5  # the Gaussians are in view
    assert torch.equal(a["rgb"], b["rgb"]) and torch.equal(a["depth"], b["depth"])


def test_gsplat_on_cpu_tensors_fails_in_one_line_naming_the_way_out():
    with pytest.raises(IDSplatError, match="backend='torch'"):
        _scene("gsplat").render_camera(torch.eye(4), K, 64, 48, None)


def test_an_unknown_backend_is_refused_when_the_model_is_built():
    with pytest.raises(ValueError, match="camera_backend 'cuda'"):
        _scene("cuda")

