"""Static conversion: the paper's displacement rule and the world-overlap stationarity test."""

from __future__ import annotations

import numpy as np

from idsplat_ns.instances.lifting import InstanceObservation, LiftedInstances
from idsplat_ns.instances.static_conversion import (
    StaticConversionConfig, convert_static_instances, extent_growth, is_stationary, world_overlap_fractions,
)  # fmt: skip
from idsplat_ns.instances.tracks import InstanceTrack, InstanceTracks

LENGTH, WIDTH, HEIGHT = 4.5, 1.8, 1.5


def _face_points(rng: np.random.Generator, face: str, n: int = 2500) -> np.ndarray:  # -> [n, 3] box frame
    """Random points on one face of a car-sized box centred at the origin."""
    u, v = rng.uniform(-0.5, 0.5, n), rng.uniform(-0.5, 0.5, n)
    if face == "left":
        return np.stack([u * LENGTH, np.full(n, WIDTH / 2), v * HEIGHT], 1)
    if face == "rear":
        return np.stack([np.full(n, -LENGTH / 2), u * WIDTH, v * HEIGHT], 1)
    if face == "front":
        return np.stack([np.full(n, LENGTH / 2), u * WIDTH, v * HEIGHT], 1)
    raise ValueError(face)


def _observations(positions: np.ndarray, seed: int = 0) -> list[InstanceObservation]:
    """A box at ``positions`` [F, 3]; the ego drives past it, so the visible faces change from
    rear+left to left+front (what makes registration slide on real parked cars)."""
    rng = np.random.default_rng(seed)
    obs = []
    for f, p in enumerate(positions):
        faces = ("rear", "left") if f < len(positions) // 2 else ("left", "front")
        pts = np.concatenate([_face_points(rng, face) for face in faces]) + p
        obs.append(InstanceObservation(f, pts, np.zeros(len(pts), np.int32), np.zeros((len(pts), 2), np.float32)))
    return obs


def _track(iid: int, positions: np.ndarray) -> InstanceTrack:
    F = len(positions)
    poses = np.tile(np.eye(4), (F, 1, 1))
    poses[:, :3, 3] = positions
    return InstanceTrack(iid, "car", np.zeros((1, 3)), None, poses, np.ones(F, bool),
                         np.full(F, 100), np.ones(F), 0)


def test_overlap_separates_parked_from_moving():
    F = 8
    parked = np.tile([20.0, 5.0, 0.75], (F, 1))
    turning = parked + np.outer(np.arange(F), [1.0, 1.0, 0.0])  # leaves the planes of its faces
    f_parked = world_overlap_fractions(_observations(parked), 0.10)
    f_turning = world_overlap_fractions(_observations(turning), 0.10)
    assert len(f_parked) == len(f_turning) == F
    # the shared left face agrees in every frame; the face seen only in half the frames does too
    assert f_parked.min() > 0.45 and np.median(f_parked) > 0.9
    assert f_turning.max() < 0.1
    cfg = StaticConversionConfig(overlap_point_fraction=0.4)
    assert is_stationary(_observations(parked), cfg)
    assert not is_stationary(_observations(turning), cfg)
    assert abs(extent_growth(_observations(parked))) < 0.1


def test_flat_side_sliding_along_itself_is_not_stationary():
    """A box driving along its length: its side points stay on their plane (overlap is high),
    but the union of the views grows by the distance travelled."""
    F = 8
    moving = np.tile([20.0, 5.0, 0.75], (F, 1)) + np.outer(np.arange(F), [1.5, 0.0, 0.0])
    obs = _observations(moving)
    assert np.median(world_overlap_fractions(obs, 0.10)) > 0.4  # point distances alone are fooled
    assert extent_growth(obs) > 9.0  # 7 steps of 1.5 m
    assert not is_stationary(obs, StaticConversionConfig(overlap_point_fraction=0.4))


def test_slid_registration_of_a_parked_car_becomes_static():
    F = 8
    truth = np.tile([20.0, 5.0, 0.75], (F, 1))
    # registration slid 3 m along the car once the visible side changed: 3 m of false displacement
    registered = truth.copy()
    registered[F // 2 :, 0] += 3.0
    moving_truth = truth + np.outer(np.arange(F), [1.5, 0.0, 0.0])
    tracks = InstanceTracks(np.arange(F), np.arange(F) * 0.1, [_track(1, registered), _track(2, moving_truth)], [], {})
    lifted = LiftedInstances({1: "car", 2: "car"}, {1: _observations(truth), 2: _observations(moving_truth, seed=1)})
    cfg = StaticConversionConfig(overlap_point_fraction=0.4)

    paper_only = convert_static_instances(tracks, StaticConversionConfig(use_world_overlap=False), lifted)
    assert [i.instance_id for i in paper_only.instances] == [1, 2]  # displacement alone is fooled

    converted = convert_static_instances(tracks, cfg, lifted)
    assert [i.instance_id for i in converted.instances] == [2]
    assert [i.instance_id for i in converted.static_instances] == [1]
    assert converted.metadata["static_by_world_overlap"] == [1]
    # without the observations only the displacement rule can be applied
    assert [i.instance_id for i in convert_static_instances(tracks, cfg).instances] == [1, 2]


def test_car_that_parks_for_half_the_sequence_stays_dynamic():
    F = 10
    positions = np.tile([20.0, 5.0, 0.75], (F, 1))
    positions[F // 2 :, 0] += 2.0 * np.arange(1, F - F // 2 + 1)  # drives off after frame 4
    tracks = InstanceTracks(np.arange(F), np.arange(F) * 0.1, [_track(1, positions)], [], {})
    lifted = LiftedInstances({1: "car"}, {1: _observations(positions)})
    converted = convert_static_instances(tracks, StaticConversionConfig(overlap_point_fraction=0.4), lifted)
    assert [i.instance_id for i in converted.instances] == [1]


def test_sparse_or_single_frame_instances_are_not_scored():
    one = _observations(np.array([[0.0, 0.0, 0.0]]))
    assert len(world_overlap_fractions(one, 0.1)) == 0
    assert not is_stationary(one, StaticConversionConfig())
    few = [InstanceObservation(f, np.zeros((3, 3)) + f, np.zeros(3, np.int32), np.zeros((3, 2), np.float32)) for f in range(4)]
    assert len(world_overlap_fractions(few, 0.1, min_points=10)) == 0


def test_near_other_clouds_matches_a_tree_of_the_others_per_cloud():
    from scipy.spatial import cKDTree

    from idsplat_ns.instances.static_conversion import near_other_clouds

    rng = np.random.default_rng(4)
    clouds = [rng.normal(size=(int(n), 3)) * 0.6 + rng.normal(size=3) * 0.3 for n in rng.integers(1, 120, 13)]
    got = near_other_clouds(clouds, 0.1)
    for k, cloud in enumerate(clouds):
        others = cKDTree(np.concatenate([c for j, c in enumerate(clouds) if j != k]))
        dist, _ = others.query(cloud, k=1, distance_upper_bound=0.1)
        assert np.array_equal(got[k], np.isfinite(dist)), k
    assert near_other_clouds([clouds[0]], 0.1)[0].sum() == 0 and near_other_clouds([], 0.1) == []
