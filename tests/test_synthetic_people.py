"""Pedestrians and cyclists of the synthetic street (idsplat_ns.data.synthetic.people*).

A 4-frame street at `tiny`'s sizes (wider images without shadows, denser lidar) with 3 pedestrians
and 1 cyclist.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from PIL import Image

from idsplat_ns.data.synthetic import CAMERA_NAMES, generate_sequence, get_preset
from idsplat_ns.data.synthetic.camera_render import render_camera
from idsplat_ns.data.synthetic.cli import config_from_args
from idsplat_ns.data.synthetic.generate import _frame_rng
from idsplat_ns.data.synthetic.lidar_sim import simulate_sweep, sweep_rays
from idsplat_ns.data.synthetic.people_placement import WALK_SPEED, CYCLE_SPEED, ground_height
from idsplat_ns.data.synthetic.raycast import RayCaster
from idsplat_ns.data.synthetic.rig import cameras
from idsplat_ns.data.synthetic.shapes import yaw_matrix
from idsplat_ns.data.synthetic.world import World, build_world
from idsplat_ns.errors import IDSplatError

TINY = get_preset("tiny")
PEOPLE = dataclasses.replace(
    TINY,
    name="tiny_people",
    num_frames=4,
    num_pedestrians=3,
    num_cyclists=1,
    cameras=dataclasses.replace(TINY.cameras, image_width=256, image_height=160, shadows=False),  # speed
    lidar=dataclasses.replace(TINY.lidar, azimuth_steps=512),
)
SEED = 2
PEOPLE_LABELS = ("Pedestrian", "Bicycle")


@pytest.fixture(scope="module")
def seq(tmp_path_factory) -> Path:
    return generate_sequence(tmp_path_factory.mktemp("people"), PEOPLE, seed=SEED, progress=False)


@pytest.fixture(scope="module")
def world() -> World:
    return build_world(PEOPLE, SEED)


def _people(world: World):
    return [o for o in world.road_users if o.label in PEOPLE_LABELS]


def _cuboids(seq: Path, k: int) -> pd.DataFrame:
    return pd.read_pickle(seq / "annotations" / "cuboids" / f"{k:02d}.pkl.gz")


# -- presets and the random stream -------------------------------------------------------------------


def test_presets_and_counts():
    assert TINY.num_pedestrians == 0 and TINY.num_cyclists == 0
    assert not _people(build_world(TINY, 0))  # the test suite's street has vehicles only
    for name, (p_min, c_min) in {"small": (2, 1), "bench": (3, 1)}.items():
        config = get_preset(name)
        assert config.num_pedestrians >= p_min and config.num_cyclists >= c_min
    assert config_from_args("small", None, None) is get_preset("small")
    changed = config_from_args("small", 5, 0)
    assert (changed.name, changed.num_pedestrians, changed.num_cyclists) == ("small_p5c0", 5, 0)
    with pytest.raises(IDSplatError, match="--pedestrians"):
        config_from_args("tiny", -1, None)
    with pytest.raises(IDSplatError, match="--cyclists"):
        config_from_args("tiny", None, 99)


def test_people_leave_the_street_and_its_vehicles_unchanged(world: World):
    """People come from their own random stream: the same seed gives the same street and vehicles."""
    bare = build_world(dataclasses.replace(PEOPLE, num_pedestrians=0, num_cyclists=0), SEED)
    others = [o for o in world.objects if o.label not in PEOPLE_LABELS]
    assert len(others) == len(bare.objects) and len(world.objects) == len(bare.objects) + 4
    for a, b in zip(others, bare.objects):
        assert (a.name, a.label, a.uuid, a.instance_id, a.trajectory) == (b.name, b.label, b.uuid, b.instance_id, b.trajectory)
        for pa, pb in zip(a.parts, b.parts):
            np.testing.assert_array_equal(pa.center, pb.center)
            np.testing.assert_array_equal(pa.color, pb.color)
    np.testing.assert_array_equal(world.sun_direction, bare.sun_direction)
    ids = [o.instance_id for o in world.road_users]
    assert ids == list(range(1, len(ids) + 1))  # people follow the vehicles' ids


def test_same_seed_same_people_other_seed_differs(seq: Path):
    """A fresh world from the same seed remakes the written masks and lidar exactly; another seed moves people."""
    again = build_world(PEOPLE, SEED)
    caster = RayCaster(again)
    cam = cameras(PEOPLE)[0]
    _, mask, _ = render_camera(caster, cam, 1 / PEOPLE.frame_rate + cam.time_offset, 1, PEOPLE.cameras.shadows)
    written = np.array(Image.open(seq / "idsplat_extras" / "instance_masks" / cam.name / "01.png"))
    np.testing.assert_array_equal(mask, written)
    sweep = simulate_sweep(caster, 1 / PEOPLE.frame_rate, _frame_rng(SEED, 1))
    lidar = pd.read_pickle(seq / "lidar" / "01.pkl.gz")
    np.testing.assert_array_equal(again.points_to_world(sweep.points), lidar[["x", "y", "z"]].to_numpy())
    place = lambda w: np.array([o.trajectory.pose(np.zeros(1))[0][0] for o in _people(w)])  # noqa: E731
    uuids = lambda w: [o.uuid for o in _people(w)]  # noqa: E731
    other = build_world(PEOPLE, SEED + 1)
    assert uuids(again) == uuids(build_world(PEOPLE, SEED)) != uuids(other)
    assert np.abs(place(again) - place(other)).max() > 0.5


# -- annotations -------------------------------------------------------------------------------------


def test_people_annotations(seq: Path, world: World):
    instances = json.loads((seq / "idsplat_extras" / "instances.json").read_text())
    people = {v["uuid"]: v for v in instances.values() if v["label"] in PEOPLE_LABELS}
    assert sorted(v["label"] for v in people.values()) == ["Bicycle", "Pedestrian", "Pedestrian", "Pedestrian"]
    assert all(v["moving"] for v in people.values())
    tracks = pd.concat([_cuboids(seq, k).assign(frame=k) for k in range(PEOPLE.num_frames)], ignore_index=True)
    tracks = tracks[tracks["uuid"].isin(list(people))]
    assert tracks["uuid"].nunique() == 4
    z0 = PEOPLE.world_offset[2]
    crossing = 0
    for uid, g in tracks.groupby("uuid"):
        g = g.sort_values("frame")
        label = people[uid]["label"]
        assert (g["label"] == label).all() and not g["stationary"].any()
        assert (g["attributes.object_motion"] == "Moving").all()
        width, length, height = g[["dimensions.x", "dimensions.y", "dimensions.z"]].iloc[0]
        dxy = np.diff(g[["position.x", "position.y"]].to_numpy(), axis=0)
        speed = np.linalg.norm(dxy, axis=1).mean() * PEOPLE.frame_rate
        yaw = g["yaw"].to_numpy()[:-1]
        along = (np.stack([-np.sin(yaw), np.cos(yaw)], 1) * dxy).sum(1) / np.linalg.norm(dxy, axis=1)
        assert (along > 0.99).all(), uid  # the box's length axis points where it goes
        if label == "Pedestrian":
            assert WALK_SPEED[0] - 0.01 <= speed <= WALK_SPEED[1] + 0.01
            assert 1.5 < height < 2.0 and 0.4 < width < 0.8 and 0.6 < length < 1.2
            assert (g["attributes.pedestrian_behavior"] == "Walking").all()
        else:
            assert CYCLE_SPEED[0] - 0.01 <= speed <= CYCLE_SPEED[1] + 0.01
            assert 1.4 < height < 1.9 and 0.45 < width < 0.8 and 1.6 < length < 2.0
            assert (g["attributes.rider_status"] == "With Rider").all()
        # Boxes stand on the ground: the road, or the raised sidewalk.
        bottom = g["position.z"].to_numpy() - height / 2 - z0
        local = (g[["position.x", "position.y"]].to_numpy() - np.array(PEOPLE.world_offset[:2])) @ world.local_to_world_rotation[:2, :2]
        np.testing.assert_allclose(bottom, ground_height(world.layout, local), atol=1e-6)
        road = np.abs(local[:, 1]) < world.layout.road_half_width
        if label == "Pedestrian" and road.all():
            crossing += 1
            heading = np.arctan2(*(local[-1] - local[0])[::-1])
            assert abs(abs(heading) - np.pi / 2) < 1e-6  # straight across the road
        elif label == "Pedestrian":  # along a sidewalk, clear of the trees and poles near the curb
            assert (np.abs(local[:, 1]) > world.layout.road_half_width + 2.0).all()
    assert crossing == 1


# -- sensors -----------------------------------------------------------------------------------------


def test_people_appear_in_masks_and_images(seq: Path, world: World):
    instances = json.loads((seq / "idsplat_extras" / "instances.json").read_text())
    people_ids = {int(k) for k, v in instances.items() if v["label"] in PEOPLE_LABELS}
    pixels = dict.fromkeys(people_ids, 0)
    for cam in CAMERA_NAMES:
        for k in range(PEOPLE.num_frames):
            mask = np.array(Image.open(seq / "idsplat_extras" / "instance_masks" / cam / f"{k:02d}.png"))
            for i in people_ids:
                pixels[i] += int((mask == i).sum())
    assert min(pixels.values()) >= 10, pixels
    # The images show them: without the people, the pixels of their masks change.
    bare = World(**{**world.__dict__, "objects": [o for o in world.objects if o.label not in PEOPLE_LABELS]})
    cam = cameras(PEOPLE)[0]
    with_people, mask, _ = render_camera(RayCaster(world), cam, cam.time_offset, 1, False)
    without, mask_bare, _ = render_camera(RayCaster(bare), cam, cam.time_offset, 1, False)
    on_people = np.isin(mask, list(people_ids))
    assert on_people.sum() >= 10 and not np.isin(mask_bare, list(people_ids)).any()
    diff = np.abs(with_people.astype(int) - without.astype(int)).sum(-1)
    assert (diff[on_people] > 12).mean() > 0.9
    assert (diff[mask == mask_bare] == 0).all()  # shadows off: nothing else changes


def test_cuboids_hold_the_lidar_hits_on_people(seq: Path, world: World):
    """Every lidar ray that meets a person (exact hit, before range noise) lies in its written cuboid
    moved to the ray's own time; people return points in the written sweeps."""
    caster = RayCaster(world)
    people = {o.instance_id: o for o in _people(world)}
    counts = dict.fromkeys(people, 0)
    period = 1.0 / PEOPLE.frame_rate
    for k in range(PEOPLE.num_frames - 1):
        origins, dirs, times = sweep_rays(caster, k * period)
        hits = caster.cast(origins, dirs, times)
        inst = np.where(hits.hit, caster.instance_of_object[np.maximum(hits.obj, 0)], 0)
        boxes = [{r["uuid"]: r for r in _cuboids(seq, j).to_dict("records")} for j in (k, k + 1)]
        pts_world = world.points_to_world(hits.point)
        for iid, person in people.items():
            rows = np.flatnonzero(inst == iid)
            if not len(rows):
                continue
            a, b = boxes[0][person.uuid], boxes[1][person.uuid]
            w = ((times[rows] - k * period) / period)[:, None]  # constant velocity: linear in time
            centre = (1 - w) * np.array([a[f"position.{c}"] for c in "xyz"]) + w * np.array([b[f"position.{c}"] for c in "xyz"])
            rot = yaw_matrix(np.array([a["yaw"] + np.pi / 2]))[0]  # box axes: x along the length
            local = np.einsum("ji,nj->ni", rot, pts_world[rows] - centre)
            half = np.array([a["dimensions.y"], a["dimensions.x"], a["dimensions.z"]]) / 2
            assert (np.abs(local) <= half + 1e-6).all(), (person.name, (np.abs(local) - half).max())
        written = simulate_sweep(caster, k * period, _frame_rng(SEED, k))
        for iid in people:
            counts[iid] += int((caster.instance_of_object[caster.part_object_arr[written.part]] == iid).sum())
    assert min(counts.values()) >= 5, counts


def _silhouette(caster: RayCaster, person, t: float) -> np.ndarray:
    """Which rays of a fixed grid in the person's box frame (looking from its left) hit it at time `t`."""
    width, length, height = person.dimensions
    u, v = np.meshgrid(np.linspace(-length / 2, length / 2, 60), np.linspace(0.02, height, 90))
    o_box = np.stack([u.ravel(), np.full(u.size, 3.0), v.ravel()], 1)
    xy, heading = person.trajectory.pose(np.array([t]))
    rot = yaw_matrix(heading)[0]
    base = np.array([xy[0, 0], xy[0, 1], person.trajectory.height(np.array([t]))[0]])
    hits = caster.cast(o_box @ rot.T + base, np.tile(rot @ [0.0, -1.0, 0.0], (u.size, 1)), np.full(u.size, t))
    return caster.instance_of_object[np.maximum(hits.obj, 0)] * hits.hit == person.instance_id


def test_limbs_move_inside_the_rigid_cuboid(world: World):
    """Seen in the box frame, a walker's and a cyclist's silhouettes change over time; a car's does not."""
    bare_world = World(**{**world.__dict__, "objects": [world.objects[0]] + [o for o in world.road_users]})
    caster = RayCaster(bare_world)
    for person in _people(world):
        shapes = [_silhouette(caster, person, t) for t in (0.0, 0.15, 0.3)]
        assert shapes[0].sum() > 200, person.name
        changed = [(a ^ b).sum() / a.sum() for a, b in zip(shapes[:-1], shapes[1:])]
        assert min(changed) > 0.03, (person.name, changed)  # cyclists: ~0.06-0.09 (big solid wheels)
    car = next(o for o in world.vehicles if o.moving)
    shapes = [_silhouette(caster, car, t) for t in (0.0, 0.3)]
    assert shapes[0].sum() > 200 and (shapes[0] == shapes[1]).all()  # the rigid case the test tells apart


def test_parser_reads_people_as_tracks(seq: Path):
    """The PandaSet parser turns the people's cuboids into moving tracks of the pedestrian and cyclist groups."""
    from idsplat_ns.data.pandaset import load_sequence

    scene = load_sequence(seq, load_lidar=False)
    people = [t for t in scene.tracks if t.label in PEOPLE_LABELS]
    assert sorted(t.group for t in people) == ["cyclist", "pedestrian", "pedestrian", "pedestrian"]
    assert all(t.moving and len(t.frame_indices) == PEOPLE.num_frames for t in people)
    for t in people:  # size (length, width, height) and an upright box
        assert t.size[2] > 1.4 and t.size[0] > t.size[1]
        np.testing.assert_allclose(t.poses[:, 2, 2], 1.0, atol=1e-9)
