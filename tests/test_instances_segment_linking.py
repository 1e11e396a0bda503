"""Split segments linked back to their instance through the vehicle's box (segment_linking.py)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from idsplat_ns.data.geometry import invert_pose, make_pose, rot_z, transform_points, yaw_of
from idsplat_ns.instances.segment_linking import SegmentLinkConfig, box_frame, link_segment
from idsplat_ns.instances.tracks import InstanceTrack

LENGTH, WIDTH, HEIGHT = 4.5, 1.85, 1.5
F, DT = 14, 0.2  # frames, seconds
# The sensor, world: ahead of the car while it is far (it sees the front and right side), then
# inside the turn (the rear and left side).
SENSORS = np.array([[25.0, 0.0, 1.8]] * 7 + [[0.0, -12.0, 1.8]] * 7)  # [F, 3]


def _box_poses() -> np.ndarray:  # -> [F, 4, 4] box -> world: a car turning left at 5 m/s on a 15 m radius
    radius, speed = 15.0, 5.0
    out = []
    for f in range(F):
        a = -0.9 + speed / radius * DT * f  # angle on the circle about (0, 0)
        out.append(make_pose(rot_z(a + np.pi / 2), np.array([radius * np.cos(a), radius * np.sin(a), 0.75])))
    return np.stack(out)


def _visible_faces(box_pose: np.ndarray, sensor: np.ndarray) -> np.ndarray:  # -> [N, 3] box frame
    """Grid points on the vertical faces of the box that face the sensor (what a lidar sees)."""
    s = transform_points(invert_pose(box_pose), sensor[None])[0]
    u = np.linspace(-0.48, 0.48, 15)  # faces stop short of their edges, so no two share a point
    h = np.linspace(-0.5, 0.5, 6) * HEIGHT
    faces = []
    for axis, half, along in ((0, LENGTH / 2, WIDTH), (1, WIDTH / 2, LENGTH)):
        for sign in (-1.0, 1.0):
            if (s[axis] - sign * half) * sign <= 0:  # the sensor is behind this face's plane
                continue
            a, z = np.meshgrid(u * along, h)
            p = np.zeros((a.size, 3))
            p[:, axis], p[:, 1 - axis], p[:, 2] = sign * half, a.ravel(), z.ravel()
            faces.append(p)
    return np.concatenate(faces)


def _part(frames: list[int], to_canonical: np.ndarray, label: str = "car") -> InstanceTrack:
    """A registered part of the car over ``frames``: its own canonical frame (``to_canonical``: box
    frame -> canonical), poses exact, points the faces the sensor saw, mapped into that frame."""
    box = _box_poses()
    poses = np.tile(np.eye(4), (F, 1, 1))
    valid = np.zeros(F, bool)
    points, point_frames = [], []
    for f in frames:
        poses[f] = box[f] @ invert_pose(to_canonical)
        valid[f] = True
        seen = _visible_faces(box[f], SENSORS[f])
        points.append(transform_points(to_canonical, seen))
        point_frames.append(np.full(len(seen), f, np.int32))
    counts = np.zeros(F, np.int64)
    counts[frames] = [len(p) for p in points]
    return InstanceTrack(instance_id=1, label=label, canonical_points=np.concatenate(points), canonical_colors=None,
                         poses=poses, valid=valid, point_counts=counts, fitness=valid.astype(float),
                         canonical_frame=frames[0], point_frames=np.concatenate(point_frames))


def _sensors() -> np.ndarray:  # -> [F, 3]
    return SENSORS.copy()


TIMES = np.arange(F) * DT
# Canonical frames as registration makes them: an origin somewhere on the seen part, axes those of the
# world at the reference frame (so neither is the box frame).
TO_NEAR = make_pose(rot_z(0.7), np.array([0.8, -0.6, 0.1]))
TO_FAR = make_pose(rot_z(-1.9), np.array([-2.6, 1.4, -0.2]))


def test_both_parts_see_different_faces():
    box = _box_poses()
    far = {tuple(np.round(p, 3)) for f in range(4) for p in _visible_faces(box[f], SENSORS[f])}
    near = {tuple(np.round(p, 3)) for f in range(9, F) for p in _visible_faces(box[f], SENSORS[f])}
    assert not far & near  # no shared surface: registration could not join them


def test_box_frame_is_the_vehicle_centre_and_direction_of_travel():
    part = _part([9, 10, 11, 12, 13], TO_NEAR)
    B = box_frame(part, _sensors())
    assert B is not None
    truth = TO_NEAR  # box frame -> canonical
    assert np.linalg.norm(B[:2, 3] - truth[:2, 3]) < 0.15
    assert abs(np.degrees(yaw_of(B[:3, :3]) - yaw_of(truth[:3, :3]))) < 4.0  # the chord of a turn, not its tangent
    assert box_frame(replace(part, label="thing"), _sensors()) is None  # no typical size
    parked = replace(part, poses=np.tile(part.poses[9], (F, 1, 1)))
    assert box_frame(parked, _sensors()) is None  # no direction of travel


def test_a_segment_seen_from_other_faces_is_linked_into_the_instance_frame():
    near = _part([9, 10, 11, 12, 13], TO_NEAR)
    far = _part([0, 1, 2, 3], TO_FAR)
    linked = link_segment(near, far, _sensors(), TIMES)
    assert linked is not None
    assert linked.valid[[0, 1, 2, 3, 9, 10, 11, 12, 13]].all() and not linked.valid[4:9].any()
    box = _box_poses()
    for f in (0, 1, 2, 3):
        truth = box[f] @ invert_pose(TO_NEAR)  # the pose the near part's frame would have had
        centre_error = np.linalg.norm(linked.poses[f][:2, 3] - truth[:2, 3])
        assert centre_error < 0.4, (f, centre_error)
        assert abs(np.degrees(yaw_of(linked.poses[f][:3, :3]) - yaw_of(truth[:3, :3]))) < 6.0
    np.testing.assert_allclose(linked.poses[9:], near.poses[9:])  # the instance's own frames are untouched
    # Every point keeps its world position at its frame.
    world = np.stack([transform_points(linked.poses[f], p[None])[0]
                      for p, f in zip(linked.canonical_points, linked.point_frames)])
    before = np.concatenate([
        np.stack([transform_points(near.poses[f], p[None])[0] for p, f in zip(near.canonical_points, near.point_frames)]),
        np.stack([transform_points(far.poses[f], p[None])[0] for p, f in zip(far.canonical_points, far.point_frames)]),
    ])
    np.testing.assert_allclose(world, before, atol=1e-9)
    # Which part is the instance does not matter.
    assert link_segment(far, near, _sensors(), TIMES) is not None


def test_segments_that_cannot_be_the_same_vehicle_stay_apart():
    near = _part([9, 10, 11, 12, 13], TO_NEAR)
    far = _part([0, 1, 2, 3], TO_FAR)
    jumped = replace(far, poses=far.poses + make_pose(np.zeros((3, 3)), np.array([25.0, 0.0, 0.0])))
    assert link_segment(near, jumped, _sensors(), TIMES) is None  # 25 m more in 1.2 s: not the car's speed
    stopped = replace(far, poses=np.tile(far.poses[0], (F, 1, 1)))
    assert link_segment(near, stopped, _sensors(), TIMES) is None  # no direction of travel
    interleaved = _part([5, 7, 8], TO_FAR)
    assert link_segment(_part([4, 6, 9, 10], TO_NEAR), interleaved, _sensors(), TIMES) is None
    assert link_segment(near, far, _sensors(), TIMES, SegmentLinkConfig(max_gap=0.5)) is None  # 1.2 s apart
    assert link_segment(near, replace(far, label="traffic cone"), _sensors(), TIMES) is None


def test_a_lone_misregistered_frame_inside_the_other_part_is_dropped_to_link():
    # The near part also holds far frame 3, registered a quarter turn and 2.7 m off (seed 0's
    # turning pickup): the parts overlap in time only through that frame.
    near = _part([3, 9, 10, 11, 12, 13], TO_NEAR)
    wrong = near.poses.copy()
    wrong[3] = near.poses[3] @ make_pose(rot_z(np.pi / 2), np.array([2.7, 0.0, 0.0]))
    near = replace(near, poses=wrong)
    far = _part([0, 1, 2, 4, 5], TO_FAR)
    linked = link_segment(near, far, _sensors(), TIMES)
    assert linked is not None
    assert not linked.valid[3] and linked.valid[[0, 1, 2, 4, 5, 9]].all()
    assert 3 not in set(linked.point_frames.tolist())  # its points left with it
    box = _box_poses()
    for f in (0, 1, 2, 4, 5):
        assert np.linalg.norm(linked.poses[f][:2, 3] - (box[f] @ invert_pose(TO_NEAR))[:2, 3]) < 0.4
    assert link_segment(near, far, _sensors(), TIMES, SegmentLinkConfig(max_intruders=0)) is None
    two = _part([3, 4, 9, 10, 11, 12, 13], TO_NEAR)
    assert link_segment(two, _part([0, 1, 2, 5, 6], TO_FAR), _sensors(), TIMES) is not None  # up to 3 by default
    assert link_segment(two, _part([0, 1, 2, 5, 6], TO_FAR), _sensors(), TIMES,
                        SegmentLinkConfig(max_intruders=1)) is None  # two intruders


def test_bad_link_settings_are_one_line_errors():
    import pytest

    from idsplat_ns.errors import IDSplatError

    with pytest.raises(IDSplatError, match="speed-ratio must be >= 1"):
        SegmentLinkConfig(speed_ratio=0.0)
    with pytest.raises(IDSplatError, match="max-intruders must be >= 0"):
        SegmentLinkConfig(max_intruders=-1)


def test_misregistered_first_frames_before_the_whole_segment_are_dropped_to_link():
    """Seed 8: the instance's first three frames registered a quarter turn off, ahead of the
    whole segment, so the segment sat inside the instance's span and no frame of either part was
    "inside" the other's alone. The fewest frames that put one part before the other are dropped."""
    near = _part([1, 2, 3, 9, 10, 11, 12, 13], TO_NEAR)
    wrong = near.poses.copy()
    for f in (1, 2, 3):
        wrong[f] = near.poses[f] @ make_pose(rot_z(-np.pi / 2), np.array([1.5, 0.5, 0.0]))
    near = replace(near, poses=wrong)
    far = _part([4, 5, 6, 7], TO_FAR)
    linked = link_segment(near, far, _sensors(), TIMES)
    assert linked is not None
    assert not linked.valid[[1, 2, 3]].any() and linked.valid[[4, 5, 6, 7, 9, 13]].all()
    box = _box_poses()
    for f in (4, 5, 6, 7):
        assert np.linalg.norm(linked.poses[f][:2, 3] - (box[f] @ invert_pose(TO_NEAR))[:2, 3]) < 0.4
    # Only up to max_intruders frames (parts that alternate, half of a part: the test above).
    assert link_segment(near, far, _sensors(), TIMES, SegmentLinkConfig(max_intruders=2)) is None
