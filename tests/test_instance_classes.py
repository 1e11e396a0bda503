"""Instances carry a class (vehicle, pedestrian, cyclist, other) beside their raw label: from the
annotations (PandaSet and Waymo labels), from a detector's prompt, from size and speed for the
lidar-motion source; exported with the tracks."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from idsplat_ns.data.tracks import class_from_size_speed, label_group
from idsplat_ns.instances.masks.lidar_motion import LidarMotionMaskSource
from idsplat_ns.instances.motion_tracks import LidarMotionConfig, MotionCluster, MotionTrack
from idsplat_ns.instances.masks.base import PROMPT_CLASSES
from idsplat_ns.instances.tracks import InstanceTrack
from idsplat_ns.model.instance_summary import guess_class


@pytest.mark.parametrize("label,cls", [
    ("Car", "vehicle"), ("Pickup Truck", "vehicle"), ("Semi-truck", "vehicle"), ("Bus", "vehicle"),
    ("Trolley", "vehicle"), ("Pedestrian", "pedestrian"), ("Pedestrian with Object", "pedestrian"),
    ("Bicycle", "cyclist"), ("Motorcycle", "cyclist"), ("Personal Mobility Device", "cyclist"),
    ("Motorized Scooter", "cyclist"), ("Cones", "other"), ("Animals - Other", "other"),
    ("vehicle", "vehicle"), ("pedestrian", "pedestrian"), ("cyclist", "cyclist"), ("sign", "other"),  # Waymo
    ("person", "pedestrian"), ("  HUMAN ", "pedestrian"),
])
def test_dataset_labels_map_to_classes(label: str, cls: str) -> None:
    assert label_group(label) == cls


def test_every_detector_prompt_has_a_road_user_class() -> None:
    assert {p: label_group(p) for p in PROMPT_CLASSES} == {
        "car": "vehicle", "truck": "vehicle", "van": "vehicle", "bus": "vehicle", "train": "vehicle",
        "human": "pedestrian", "pedestrian": "pedestrian", "cyclist": "cyclist", "bicycle": "cyclist"}


@pytest.mark.parametrize("length,width,speed,cls", [
    (0.6, 0.5, 1.4, "pedestrian"),  # walking
    (0.6, 0.5, float("nan"), "pedestrian"),  # speed unknown: the footprint decides
    (0.9, 0.6, 5.0, "cyclist"),  # small but too fast to walk: a cyclist seen head-on
    (1.8, 0.5, 5.0, "cyclist"),
    (1.8, 1.3, 8.0, "vehicle"),  # a car seen from behind
    (1.8, 0.15, 8.0, "vehicle"),  # one flat face of a car
    (4.5, 1.8, 10.0, "vehicle"),
    (1.8, 4.5, 0.0, "vehicle"),  # axes in any order
    (float("nan"), float("nan"), 1.0, "other"),
])
def test_class_from_size_and_speed(length, width, speed, cls) -> None:
    assert class_from_size_speed(length, width, speed) == cls
    assert guess_class(length, width, speed) == (cls if cls != "other" else "unknown")


def _motion_track(size, speed: float, frames: int = 5, seed: int = 0) -> MotionTrack:
    """A track whose clusters are the points of a box footprint moving along x at ``speed``."""
    rng = np.random.default_rng(seed)
    track = MotionTrack(track_id=1)
    for f in range(frames):
        t = 0.1 * f
        pts = rng.uniform(-0.5, 0.5, (200, 3)) * np.asarray(size) + [10.0 + speed * t, 0.0, 1.0]
        track.clusters.append(MotionCluster(frame=f, points=pts, times=np.full(200, t)))
    return track


def test_lidar_motion_labels_from_footprint_and_speed() -> None:
    walker, rider = _motion_track((0.6, 0.6, 1.7), 1.4), _motion_track((1.8, 0.5, 1.6), 5.0)
    car = _motion_track((4.5, 1.8, 1.5), 10.0)
    assert walker.mean_speed() == pytest.approx(1.4, rel=0.1) and car.mean_speed() == pytest.approx(10.0, rel=0.05)
    assert (walker.label(), rider.label(), car.label()) == ("pedestrian", "cyclist", "car")
    assert car.footprint()[0] == pytest.approx(4.5, rel=0.05)
    # a pedestrian-sized cluster at cycling speed is a cyclist
    assert _motion_track((0.6, 0.6, 1.7), 5.0).label() == "cyclist"
    assert _motion_track((1.8, 1.3, 1.5), 8.0).label() == "car"  # the back of a car, not a cyclist
    assert _motion_track((12.0, 2.5, 3.5), 8.0).label() == "truck"


# The labels the rule of cache key ``labels`` 4 gives: (box size, speed) -> label.
LABELS_OF_KEY_4 = [((0.6, 0.6, 1.7), 1.4, "pedestrian"), ((0.6, 0.6, 1.7), 5.0, "cyclist"),
                   ((1.8, 0.5, 1.6), 5.0, "cyclist"), ((1.8, 1.3, 1.5), 8.0, "car"),
                   ((4.5, 1.8, 1.5), 10.0, "car"), ((12.0, 2.5, 3.5), 8.0, "truck"),
                   ((1.5, 2.5, 2.8), 7.0, "bus"),  # a bus seen from behind: car-sized on the ground, tall
                   ((0.5, 2.5, 2.8), 9.0, "bus")]  # its front from afar: a cyclist's footprint, but tall


def test_lidar_motion_cache_key_names_the_label_rule() -> None:
    # The cached instances.json carries the labels: a rule that labels these cases otherwise must
    # come with a new key (then record its labels here under that key).
    assert LidarMotionMaskSource(LidarMotionConfig()).cache_key()["labels"] == 4
    assert [_motion_track(size, speed).label() for size, speed, _ in LABELS_OF_KEY_4] == [
        label for _, _, label in LABELS_OF_KEY_4], "the lidar-motion label rule changed: bump cache_key()['labels']"


def _instance(label: str) -> InstanceTrack:
    F = 3
    return InstanceTrack(instance_id=1, label=label, canonical_points=np.zeros((5, 3)), canonical_colors=None,
                         poses=np.tile(np.eye(4), (F, 1, 1)), valid=np.ones(F, bool), point_counts=np.full(F, 5),
                         fitness=np.ones(F), canonical_frame=0)


def test_instance_class_follows_its_raw_label() -> None:
    assert [_instance(lb).category for lb in ("car", "Pedestrian with Object", "bicycle", "object")] == [
        "vehicle", "pedestrian", "cyclist", "other"]


def test_pandaset_pedestrian_cuboid_becomes_a_pedestrian_oracle_instance(tmp_path) -> None:
    from test_pandaset import OFFSET, write_sequence

    from idsplat_ns.data.pandaset import load_sequence
    from idsplat_ns.instances.oracle import oracle_instance_tracks
    from idsplat_ns.instances.tracks_json import tracks_from_json, tracks_to_json, write_tracks_json

    root = tmp_path / "005"
    write_sequence(root)
    rng = np.random.default_rng(3)
    for f in range(3):  # a walker 1.4 m/s along +y, with 60 lidar returns inside its box per sweep
        centre = OFFSET + np.array([8.0, -2.0 + 0.14 * f, 0.9])
        path = root / "annotations" / "cuboids" / f"{f:02d}.pkl.gz"
        df = pd.read_pickle(path)
        row = {"uuid": "walker", "label": "Pedestrian", "yaw": 0.0, "stationary": False, "camera_used": 0,
               "position.x": centre[0], "position.y": centre[1], "position.z": centre[2],
               "dimensions.x": 0.7, "dimensions.y": 0.7, "dimensions.z": 1.8, "attributes.object_motion": "Moving",
               "cuboids.sibling_id": "-", "cuboids.sensor_id": 0}
        pd.concat([df, pd.DataFrame([row])], ignore_index=True).to_pickle(path)
        lidar_path = root / "lidar" / f"{f:02d}.pkl.gz"
        lidar = pd.read_pickle(lidar_path)
        pts = centre + rng.uniform(-0.3, 0.3, (60, 3)) * [1, 1, 2.5]
        t0 = float(lidar["t"].median())
        extra = pd.DataFrame({"x": pts[:, 0], "y": pts[:, 1], "z": pts[:, 2], "i": 50.0, "t": t0, "d": 0})
        pd.concat([lidar, extra], ignore_index=True).to_pickle(lidar_path)
    scene = load_sequence(root)
    groups = {t.track_id: t.group for t in scene.tracks}
    assert groups == {"car-1": "vehicle", "parked": "vehicle", "walker": "pedestrian"}
    oracle = oracle_instance_tracks(scene)
    walker = next(i for i in oracle.instances if i.label == "Pedestrian")
    assert oracle.class_counts()["pedestrian"] == 1
    assert walker.category == "pedestrian" and len(walker.canonical_points) >= 150
    # idsplat-preprocess --export writes the raw label and the class; import keeps the label.
    data = tracks_to_json(oracle, scene)
    assert {(e["label"], e["class"]) for e in data["instances"]} >= {("Pedestrian", "pedestrian")}
    write_tracks_json(tmp_path / "tracks.json", oracle, scene)
    back = tracks_from_json(tmp_path / "tracks.json", scene)
    assert sorted(i.category for i in back.instances) == sorted(i.category for i in oracle.instances)
