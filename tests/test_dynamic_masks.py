"""Dynamic-region masks: projected moving boxes cover the moving objects' true pixels."""

from dataclasses import replace

import numpy as np

from idsplat_ns.data.camera import CameraImage, Intrinsics
from idsplat_ns.data.dynamic_masks import box_silhouette, dynamic_mask
from idsplat_ns.data.pandaset import load_sequence


def test_box_projection_covers_ground_truth_moving_pixels(tiny_street):
    scene = load_sequence(tiny_street)
    boxes_only = replace(scene, metadata={k: v for k, v in scene.metadata.items() if k != "gt_instances"})
    covered = total = box_pixels = 0
    for image in scene.images:
        truth = dynamic_mask(scene, image)  # from the synthetic instance masks
        boxes = dynamic_mask(boxes_only, image)  # from the projected moving cuboids
        covered += (truth & boxes).sum()
        total += truth.sum()
        box_pixels += boxes.sum()
    assert total > 500  # the tiny street shows moving cars
    assert covered / total > 0.95  # a box contains its object
    assert box_pixels < 3.0 * total  # and is not much bigger than it


def test_box_silhouette_clips_at_the_near_plane():
    intr = Intrinsics(fx=100, fy=100, cx=100, cy=100, width=200, height=200)
    image = CameraImage(camera="c", frame_index=0, time=0.0, raw_timestamp=0.0, camera_to_world=np.eye(4), intrinsics=intr)
    pose = np.eye(4)
    pose[:3, 3] = [0, 0, 2.0]  # box centre 2 m ahead, 6 m long along z: its back half is behind the camera
    poly = box_silhouette(image, pose, np.array([1.0, 1.0, 6.0]), near=0.1)
    assert poly is not None and len(poly) >= 4
    assert np.all(np.abs(poly) < 1e6)  # the clipped near face projects to finite, large pixels
    assert poly[:, 0].min() < 0 and poly[:, 0].max() > 200  # it covers the whole image width
    behind = np.eye(4)
    behind[:3, 3] = [0, 0, -5.0]
    assert box_silhouette(image, behind, np.array([1.0, 1.0, 1.0])) is None
