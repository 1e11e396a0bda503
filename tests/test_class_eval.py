"""Class-aware evaluation: tracking per class with other classes' regions as don't-care (an oracle
pedestrian is no vehicle false positive), known per-class counts, absent classes absent, and DPSNR
per class from the moving objects' masks."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import torch

from _instances_fixtures import SENSOR, box_surface, make_scene
from idsplat_ns.data.dynamic_masks import class_dynamic_masks, dynamic_mask, moving_classes
from idsplat_ns.data.geometry import make_pose
from idsplat_ns.data.lidar import LidarSweep, rays_from_points
from idsplat_ns.data.tracks import ObjectTrack
from idsplat_ns.eval.image_metrics import dynamic_psnrs
from idsplat_ns.eval.metric_average import average_image_metrics
from idsplat_ns.eval.trajectory_eval import class_tracking_summaries, tracking_metrics
from idsplat_ns.instances.oracle import oracle_instance_tracks

PEDESTRIAN_SIZE = np.array([0.7, 0.7, 1.75])
CYCLIST_SIZE = np.array([1.8, 0.7, 1.7])
DT = 0.1


def _walker(track_id: str, label: str, start, velocity, size, num_frames: int, moving: bool = True) -> ObjectTrack:
    t = np.arange(num_frames) * DT
    centres = np.asarray(start, float)[None] + np.outer(t, velocity)
    return ObjectTrack(track_id, label, np.arange(num_frames), t,
                       make_pose(np.repeat(np.eye(3)[None], num_frames, 0), centres), np.asarray(size, float), moving)


def _with_road_users(scene, *tracks: ObjectTrack, rng_seed: int = 1):
    """The scene with extra tracks and 400 lidar returns on each extra box's surface per sweep."""
    rng = np.random.default_rng(rng_seed)
    sweeps = []
    for sweep in scene.lidar:
        extra = [box_surface(400, tr.size, rng) @ tr.poses[sweep.frame_index, :3, :3].T + tr.poses[sweep.frame_index, :3, 3]
                 for tr in tracks]
        pts = np.concatenate([sweep.points, *extra])
        origins = np.broadcast_to(SENSOR, pts.shape).copy()
        d, r = rays_from_points(origins, pts)
        n = len(pts)
        sweeps.append(LidarSweep(frame_index=sweep.frame_index, time=sweep.time, raw_timestamp=sweep.raw_timestamp,
                                 sensor_to_world=sweep.sensor_to_world, origins=origins, directions=d, ranges=r,
                                 intensities=np.zeros(n, np.float32), times=np.full(n, sweep.time),
                                 returned=np.ones(n, bool), sensor_ids=np.zeros(n, np.int16)))
    return replace(scene, lidar=sweeps, tracks=list(scene.tracks) + list(tracks))


@pytest.fixture(scope="module")
def street():
    """The hand-made scene (a moving car, a parked car) with a pedestrian walking across the front
    camera's view at 1.4 m/s, seen by the lidar."""
    scene = make_scene()
    walker = _walker("walker", "Pedestrian", (15.0, -4.0, PEDESTRIAN_SIZE[2] / 2), (0.0, 1.4, 0.0), PEDESTRIAN_SIZE,
                     scene.num_frames)
    return _with_road_users(scene, walker)


def _positions_of(tracks):
    """positions_at(t) of instance tracks on the 0.1 s frame grid: the canonical origins."""
    def positions_at(t: float) -> dict:
        k = int(round(t / DT))
        return {inst.instance_id: inst.poses[k, :3, 3] for inst in tracks.instances if inst.valid[k]}
    return positions_at


def _at_centres(scene, errors: dict):
    """positions_at(t) predicting each listed track's centre plus an offset; ``errors`` maps a
    prediction id to (track id, frames it is present, offset [3])."""
    tracks = {t.track_id: t for t in scene.tracks}

    def positions_at(t: float) -> dict:
        k = int(round(t / DT))
        return {pid: tracks[tid].poses[k, :3, 3] + np.asarray(off, float)
                for pid, (tid, frames, off) in errors.items() if k in frames}
    return positions_at


def test_oracle_pedestrian_is_tracked_and_not_a_vehicle_false_positive(street):
    oracle = oracle_instance_tracks(street)
    assert sorted(i.category for i in oracle.instances) == ["pedestrian", "vehicle"]
    assert {i.label for i in oracle.instances} == {"car", "Pedestrian"}
    m = tracking_metrics(street, _positions_of(oracle))
    F = street.num_frames
    # The headline (moving vehicles): the tracked pedestrian lies in a don't-care region.
    assert (m["mota@2m"], m["false_positives@2m"], m["objects@2m"], m["matches@2m"]) == (1.0, 0.0, F, F)
    assert m["all_mota@2m"] == 1.0 and m["all_false_positives@2m"] == 0.0
    # The pedestrian class and all road users, with their counts.
    assert (m["pedestrian_mota@2m"], m["pedestrian_objects@2m"], m["pedestrian_false_positives@2m"]) == (1.0, F, 0.0)
    assert (m["road_users_mota@2m"], m["road_users_objects@2m"], m["road_users_matches@2m"]) == (1.0, 2 * F, 2 * F)
    assert m["pedestrian_motp@2m"] == pytest.approx(0.0, abs=1e-9)
    # No cyclist in the data: no cyclist metric at all (not zeros).
    assert not any(k.startswith("cyclist_") for k in m)


def test_per_class_counts_on_a_scene_with_a_known_answer():
    scene = make_scene()
    F = scene.num_frames
    walker = _walker("walker", "Pedestrian with Object", (15.0, -4.0, 0.9), (0.0, 1.4, 0.0), PEDESTRIAN_SIZE, F)
    rider = _walker("rider", "Bicycle", (25.0, 5.0, 0.85), (-4.0, 0.0, 0.0), CYCLIST_SIZE, F)
    standing = _walker("standing", "Pedestrian", (10.0, 6.0, 0.9), (0.0, 0.0, 0.0), PEDESTRIAN_SIZE, F, moving=False)
    scene = _with_road_users(scene, walker, rider, standing)
    positions_at = _at_centres(scene, {
        1: ("moving", range(F), (0.3, 0.0, 0.0)),  # the car, 0.3 m off at every frame
        2: ("walker", range(3), (0.0, 0.0, 0.0)),  # the walker, lost after 3 frames
        3: ("rider", range(4), (0.0, 0.0, 0.0)),  # the rider: a new id from frame 4 (a switch)
        4: ("rider", range(4, F), (0.0, 0.0, 0.0)),
        5: ("standing", range(F), (0.0, 0.0, 0.0)),  # a standing pedestrian tracked as an instance
        6: ("moving", range(2), (0.0, 12.0, 0.0)),  # a ghost 12 m beside the car, frames 0 and 1
    })
    res = {name: r[2.0] for name, r in class_tracking_summaries(scene, positions_at, observed=None).items()}
    assert set(res) == {"vehicle", "pedestrian", "cyclist", "road_users"}
    counts = {name: (r.num_objects, r.num_matches, r.num_switches, r.num_false_positives, r.num_misses)
              for name, r in res.items()}
    # Other classes' boxes are don't care; the standing pedestrian is a pedestrian, so it is a
    # false positive for pedestrians and road users only; the ghost is one in every evaluation.
    assert counts["vehicle"] == (F, F, 0, 2, 0)
    assert counts["pedestrian"] == (F, 3, 0, F + 2, F - 3)
    assert counts["cyclist"] == (F, F - 1, 1, 2, 0)
    assert counts["road_users"] == (3 * F, 2 * F + 2, 1, F + 2, F - 3)
    assert res["vehicle"].mota == pytest.approx(1 - 2 / F) and res["vehicle"].motp == pytest.approx(0.3)
    assert res["cyclist"].mota == pytest.approx(1 - 3 / F)


def test_a_class_the_data_lacks_has_no_metrics(street):
    only_people = replace(street, tracks=[t for t in street.tracks if t.group == "pedestrian"])
    m = tracking_metrics(only_people, _positions_of(oracle_instance_tracks(street)))
    F = only_people.num_frames
    assert (m["pedestrian_objects@2m"], m["pedestrian_matches@2m"]) == (F, F)
    # the car's instance is now a false positive of the pedestrian evaluation (nothing annotated there)
    assert (m["pedestrian_false_positives@2m"], m["pedestrian_mota@2m"]) == (F, 0.0)
    assert not any(k.startswith(("mota", "all_", "cyclist_", "objects")) for k in m)


def test_dpsnr_per_class_from_the_moving_objects_masks(street):
    assert moving_classes(street) == ["vehicle", "pedestrian"]
    image = next(im for im in street.images if im.camera == "front_camera" and im.frame_index == 2)
    masks = class_dynamic_masks(street, image)
    assert set(masks) == {"dynamic_mask", "dynamic_mask_pedestrian"}  # no cyclist: no key, no zero
    car, person = masks["dynamic_mask"], masks["dynamic_mask_pedestrian"]
    assert car.sum() > 200 and person.sum() > 50 and not (car & person).any()
    assert np.array_equal(car, dynamic_mask(street, image))  # the paper's DPSNR mask is the vehicles'
    # Errors of 0.1 on the pedestrian's pixels and 0.01 on the car's: 20 dB and 40 dB.
    gt = torch.full((image.intrinsics.height, image.intrinsics.width, 3), 0.5, dtype=torch.float64)
    pred = gt.clone()
    pred[torch.from_numpy(person)] += 0.1
    pred[torch.from_numpy(car)] += 0.01
    dp = dynamic_psnrs(pred, gt, {k: torch.from_numpy(v)[..., None] for k, v in masks.items()})
    assert set(dp) == {"dpsnr", "dpsnr_pedestrian"}
    assert dp["dpsnr_pedestrian"] == pytest.approx(20.0, abs=1e-6) and dp["dpsnr"] == pytest.approx(40.0, abs=1e-6)


def test_average_over_images_keeps_absent_classes_absent():
    per_image = [{"psnr": 20.0, "dpsnr": 18.0, "num_rays_per_sec": 2e6},
                 {"psnr": 22.0, "dpsnr": 20.0, "dpsnr_pedestrian": 15.0, "num_rays_per_sec": 4e6},
                 {"psnr": 24.0, "num_rays_per_sec": 3e6}]
    avg = average_image_metrics(per_image, get_std=True)
    assert avg["psnr"] == 22.0 and avg["psnr_std"] == pytest.approx(2.0) and "psnr_num_images" not in avg
    assert (avg["dpsnr"], avg["dpsnr_num_images"]) == (19.0, 2)
    assert (avg["dpsnr_pedestrian"], avg["dpsnr_pedestrian_num_images"], avg["dpsnr_pedestrian_std"]) == (15.0, 1, 0.0)
    assert "dpsnr_cyclist" not in avg and avg["render_mpix_per_s"] == pytest.approx(3.0) and avg["num_images"] == 3
