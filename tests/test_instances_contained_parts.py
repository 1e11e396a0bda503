"""Pieces of a long vehicle folded into it (issue 42): a cab whose points stay inside a lorry's
completed box, moving with it, joins the lorry with its points where they were in the world; a car
following the lorry, a piece inside it for only a few frames, and any instance beside a box
shorter than a truck's stay instances of their own."""

from __future__ import annotations

import numpy as np

from idsplat_ns.instances.amodal_centre import completed_box
from idsplat_ns.instances.contained_parts import BOXES_KEY, ContainedPartsConfig, absorb_contained_parts
from idsplat_ns.instances.tracks import InstanceTrack, InstanceTracks

F = 10
SPEED = 8.0  # m/s along x, 10 frames a second


def _poses(offset_x: float, yaw: float = 0.3) -> np.ndarray:
    """[F, 4, 4] canonical-to-world of an object ``offset_x`` ahead of the lorry's centre, all
    heading ``yaw`` and driving together; each canonical frame turned by its own angle (frames are
    any rigid choice)."""
    heading = np.array([1.0, 0.0, 0.0])
    out = np.tile(np.eye(4), (F, 1, 1))
    c, s = np.cos(yaw), np.sin(yaw)
    out[:, :3, :3] = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
    out[:, :3, 3] = (np.arange(F) * SPEED / 10)[:, None] * heading + offset_x * heading
    return out


def _track(iid: int, label: str, points: np.ndarray, poses: np.ndarray, valid=None) -> InstanceTrack:
    valid = np.ones(F, bool) if valid is None else valid
    counts = np.where(valid, len(points), 0)
    return InstanceTrack(iid, label, points, None, poses, valid, counts, valid.astype(float), 0,
                         point_frames=np.zeros(len(points), int), point_times=np.zeros(len(points)))


def _block(rng, centre, size, n=200) -> np.ndarray:
    return np.asarray(centre) + (rng.random((n, 3)) - 0.5) * np.asarray(size)


def _tracks(*instances: InstanceTrack, boxes: dict) -> InstanceTracks:
    return InstanceTracks(np.arange(F), np.arange(F) / 10.0, list(instances), metadata={BOXES_KEY: boxes})


def test_a_cab_inside_the_lorrys_box_joins_the_lorry() -> None:
    rng = np.random.default_rng(0)
    lorry = _track(1, "truck", _block(rng, (-2.0, 0, 1.5), (12, 2.5, 3.5), 2000), _poses(0.0, yaw=0.0))
    # The cab: its own canonical frame turned by 0.3 rad, its points 6.5 m ahead of the lorry's centre.
    cab_poses = _poses(6.5, yaw=0.3)
    cab_points = _block(rng, (0, 0, 1.2), (2.5, 2.4, 2.5), 150)
    cab = _track(2, "bus", cab_points, cab_poses)
    follower = _track(3, "car", _block(rng, (0, 0, 0.7), (4.5, 1.8, 1.4)), _poses(-12.0))  # 3 m behind its rear
    box = [16.5, 2.55, 1.0, 0.0]
    out = absorb_contained_parts(_tracks(lorry, cab, follower, boxes={1: box}))
    assert [i.instance_id for i in out.instances] == [1, 3]
    assert out.metadata["folded_parts"] == {"2": 1}
    joined = out.instances[0]
    assert len(joined.canonical_points) == 2150 and len(joined.point_frames) == 2150 and len(joined.point_times) == 2150
    # The cab's points sit where they were in the world, at every frame (both rigid, same motion).
    for f in (0, 5, 9):
        cab_world = cab_points @ cab_poses[f, :3, :3].T + cab_poses[f, :3, 3]
        moved = joined.canonical_points[2000:] @ joined.poses[f, :3, :3].T + joined.poses[f, :3, 3]
        assert np.allclose(moved, cab_world, atol=1e-9)
    assert joined.point_counts[0] == 2150


def test_what_is_not_a_part_stays_an_instance() -> None:
    rng = np.random.default_rng(1)
    lorry = _track(1, "truck", _block(rng, (0, 0, 1.5), (16, 2.5, 3.5), 2000), _poses(0.0, yaw=0.0))
    cab_points = _block(rng, (0, 0, 1.2), (2.5, 2.4, 2.5), 150)
    inside_twice = np.zeros(F, bool)
    inside_twice[:2] = True
    passing = _track(2, "car", cab_points, _poses(6.5), valid=inside_twice)  # too few shared frames
    beside_poses = _poses(6.5)
    beside_poses[:, 1, 3] += 3.0  # a lane over: outside the box across it
    beside = _track(3, "car", cab_points, beside_poses)
    tracks = _tracks(lorry, passing, beside, boxes={1: [16.5, 2.55, 1.0, 0.0]})
    assert [i.instance_id for i in absorb_contained_parts(tracks).instances] == [1, 2, 3]
    short = _tracks(lorry, _track(4, "car", cab_points, _poses(2.0)), boxes={1: [5.0, 2.0, 1.0, 0.0]})
    assert len(absorb_contained_parts(short).instances) == 2  # a car's box takes no parts
    inside = _tracks(lorry, _track(4, "car", cab_points, _poses(2.0)), boxes={1: [16.5, 2.55, 1.0, 0.0]})
    assert len(absorb_contained_parts(inside).instances) == 1
    assert len(absorb_contained_parts(inside, ContainedPartsConfig(enabled=False)).instances) == 2


def test_the_completed_box_is_the_typical_size_or_the_points_extent() -> None:
    rng = np.random.default_rng(2)
    short = _block(rng, (0, 0, 1), (3.0, 1.5, 1.5), 2000)
    assert np.allclose(completed_box(short, np.array([1.0, 0, 0]), (4.5, 1.85), 0.0)[:2], [4.5, 1.85])
    long = _block(rng, (0, 0, 1), (18.0, 2.5, 3.0), 4000)
    along = completed_box(long, np.array([2.0, 0.0, 0]), (12.0, 2.55), 0.0)  # longer than a bus: its extent
    assert along[2:] == [1.0, 0.0] and abs(along[0] - 18.0) < 0.05 and abs(along[1] - 2.55) < 0.05
    across = completed_box(long, np.array([0.0, 2.0, 0]), (12.0, 2.55), 0.0)  # heading along y: 18 m across it
    assert across[2:] == [0.0, 1.0] and across[0] == 12.0 and abs(across[1] - 18.0) < 0.05
