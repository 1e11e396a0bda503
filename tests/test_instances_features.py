"""Weight-free point features: DAISY, FPFH and RGB; bilinear sampling; the extractor choice."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from _instances_fixtures import CAR_SIZE, box_surface, make_scene
from idsplat_ns.errors import IDSplatError
from idsplat_ns.instances.features.base import sample_bilinear
from idsplat_ns.instances.features.config import FeatureConfig, make_feature_extractor, resolve_feature_kind
from idsplat_ns.instances.features.daisy import DaisyFeatures
from idsplat_ns.instances.features.fpfh import FpfhFeatures
from idsplat_ns.instances.features.rgb import RgbFeatures
from idsplat_ns.instances.registration import RegistrationConfig, register


def _texture(h=160, w=200, seed=0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    small = rng.integers(0, 255, (h // 8, w // 8, 3)).astype(np.uint8)
    return cv2.resize(small, (w, h), interpolation=cv2.INTER_CUBIC)


def _cos(a, b):
    a = a / np.linalg.norm(a, axis=1, keepdims=True)
    b = b / np.linalg.norm(b, axis=1, keepdims=True)
    return np.sum(a * b, 1)


def test_daisy_matches_shifted_image_points():
    img = _texture()
    shift = np.array([7.0, 4.0])
    moved = np.roll(img, (4, 7), axis=(0, 1))
    rng = np.random.default_rng(1)
    uv = rng.uniform(30, 130, (50, 2)).astype(np.float32)
    daisy = DaisyFeatures()
    a, b = daisy.describe(img, uv), daisy.describe(moved, uv + shift)
    assert a.shape == (50, 200)
    same = _cos(a, b)
    other = _cos(a, np.roll(b, 1, axis=0))
    assert np.median(same) > 0.97
    assert np.median(same) - np.median(other) > 0.1
    # nearest neighbour in descriptor space is the true correspondence for most points
    sim = (a / np.linalg.norm(a, axis=1, keepdims=True)) @ (b / np.linalg.norm(b, axis=1, keepdims=True)).T
    assert np.mean(np.argmax(sim, 1) == np.arange(50)) > 0.8


def test_fpfh_registers_a_rigidly_moved_car():
    rng = np.random.default_rng(0)
    src = box_surface(2000, CAR_SIZE, rng) + [15.0, 3.0, 0.75]
    T = np.eye(4)
    T[:3, :3] = Rotation.from_euler("z", 25, degrees=True).as_matrix()
    T[:3, 3] = [2.0, -1.0, 0.0]
    tgt = box_surface(2000, CAR_SIZE, rng) + [15.0, 3.0, 0.75]  # another sampling of the same surface
    tgt = tgt @ T[:3, :3].T + T[:3, 3]
    fpfh = FpfhFeatures()
    fs, ft = fpfh.describe_points(src), fpfh.describe_points(tgt)
    assert fs.shape == (2000, 33)
    result = register(src, fs, tgt, ft, RegistrationConfig(max_iterations=20000, similarity_threshold=0.9))
    assert result.success
    # a box is symmetric: compare the centre's motion (any symmetric solution moves it the same way)
    centre = np.array([15.0, 3.0, 0.75, 1.0])
    np.testing.assert_allclose((result.transform @ centre)[:3], (T @ centre)[:3], atol=0.1)


def test_rgb_features_and_extractor_choice(capsys):
    img = np.zeros((10, 10, 3), np.uint8)
    img[:, 5:] = 255
    f = RgbFeatures().describe(img, np.array([[1.0, 1.0], [7.0, 2.0]]))
    np.testing.assert_allclose(f, [[-0.5] * 3, [0.5] * 3])
    scene = make_scene(num_frames=1)
    assert resolve_feature_kind(FeatureConfig(), scene) == "daisy"
    assert "DINOv3" in capsys.readouterr().out
    assert resolve_feature_kind(FeatureConfig(kind="fpfh"), scene) == "fpfh"
    with pytest.raises(IDSplatError, match="features.kind"):
        make_feature_extractor("sift", FeatureConfig())


def test_image_extractor_fills_every_observation():
    from idsplat_ns.instances.lifting import LiftingConfig, lift_instances
    from idsplat_ns.instances.masks.gt_boxes import GtBoxMasksConfig, GtBoxMaskSource
    import tempfile
    from pathlib import Path

    scene = make_scene(num_frames=2)
    with tempfile.TemporaryDirectory() as d:
        masks = GtBoxMaskSource(GtBoxMasksConfig()).generate(scene, Path(d), progress=False)
        lifted = lift_instances(scene, masks, LiftingConfig(), progress=False)
    feats = RgbFeatures().extract(scene, lifted, progress=False)
    for iid, obs in lifted.observations.items():
        for o in obs:
            f = feats.features[(iid, o.frame)]
            assert f.shape == (len(o.points), 3)
            # reference: the colour of the painted pixel in its image
            ref = np.stack([scene.images[i].image[int(v), int(u)] for i, (u, v) in zip(o.image_ids, o.uv)])
            np.testing.assert_array_equal(feats.colors[(iid, o.frame)], ref)


def test_bilinear_sampling_reference():
    grid = np.arange(12, dtype=np.float32).reshape(3, 4, 1)
    xy = np.array([[0.0, 0.0], [1.5, 0.0], [1.0, 1.5], [3.0, 2.0], [-1.0, 5.0]])
    out = sample_bilinear(grid, xy)[:, 0]
    np.testing.assert_allclose(out, [0.0, 1.5, 7.0, 11.0, 8.0])
