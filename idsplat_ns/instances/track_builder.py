"""One instance's track while registration builds it (paper Sec. 3.3).

The builder holds the instance's pose at every frame, which frames are accepted, the best
registration fitness seen at each, and the canonical point set: one chunk per accepted frame, that
frame's whole observation mapped into the canonical frame, in the order the frames were accepted
(registration samples the concatenated set, so the order is part of the result). The passes of
:mod:`idsplat_ns.instances.trajectory_passes` change a track only through :meth:`TrackBuilder.accept`,
:meth:`~TrackBuilder.drop`, :meth:`~TrackBuilder.repose` and :meth:`~TrackBuilder.coast`, so the
poses, the accepted frames and the chunks cannot disagree.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Iterable, Optional

import numpy as np

from idsplat_ns.data.geometry import invert_pose, transform_points
from idsplat_ns.instances.amodal_centre import sensors_in_canonical
from idsplat_ns.instances.features.base import PointFeatures
from idsplat_ns.instances.lifting import InstanceObservation
from idsplat_ns.instances.tracks import InstanceTrack, fill_invalid_poses


@dataclass
class Chunk:
    """An accepted frame's observation in the canonical frame."""

    frame: int
    points: np.ndarray  # [N, 3] canonical


@dataclass
class TrackBuilder:
    """The state of one instance's track; see the module docstring."""

    instance_id: int
    label: str
    observations: dict[int, InstanceObservation]  # by frame
    poses: np.ndarray  # [F, 4, 4] canonical -> world
    valid: np.ndarray  # [F] bool: the frame's pose is accepted
    fitness: np.ndarray  # [F] best registration fitness seen at the frame
    chunks: list[Chunk]  # one per accepted frame that brought its points, in acceptance order
    reference_frame: int  # the canonical frame's frame: the densest view
    times: Optional[np.ndarray] = None  # [F] seconds
    sensor_positions: Optional[np.ndarray] = None  # [F, 3] world: where the lidar was at each frame
    features: Optional[PointFeatures] = None
    feature_id: Optional[int] = None  # the mask instance whose features these observations have

    @classmethod
    def start(
        cls,
        instance_id: int,
        label: str,
        observations: list[InstanceObservation],
        num_frames: int,
        features: Optional[PointFeatures] = None,
        times: Optional[np.ndarray] = None,  # [F] seconds
        sensor_positions: Optional[np.ndarray] = None,  # [F, 3] world
        feature_id: Optional[int] = None,
    ) -> "TrackBuilder":
        """A track of the densest observation alone: the canonical frame is the centre of that
        observation's axis-aligned box, with the world's axes."""
        ref = min(observations, key=lambda o: (-len(o.points), o.frame))
        centre = 0.5 * (ref.points.min(0) + ref.points.max(0))
        poses = np.tile(np.eye(4), (num_frames, 1, 1))
        poses[ref.frame, :3, 3] = centre
        valid = np.zeros(num_frames, bool)
        fitness = np.zeros(num_frames)
        valid[ref.frame], fitness[ref.frame] = True, 1.0
        return cls(instance_id, label, {o.frame: o for o in observations}, poses, valid, fitness,
                   [Chunk(ref.frame, ref.points - centre)], int(ref.frame), times, sensor_positions, features,
                   instance_id if feature_id is None else feature_id)

    @classmethod
    def registered(
        cls,
        observations: dict[int, InstanceObservation],  # by frame
        poses: np.ndarray,  # [F, 4, 4] canonical -> world
        times: Optional[np.ndarray] = None,  # [F] seconds
        label: str = "",
        sensor_positions: Optional[np.ndarray] = None,  # [F, 3] world
        fitness: Optional[np.ndarray] = None,  # [F]
    ) -> "TrackBuilder":
        """A track whose every observed frame is accepted at ``poses`` (frames in order)."""
        frames = sorted(observations)
        valid = np.zeros(len(poses), bool)
        valid[frames] = True
        chunks = [Chunk(f, transform_points(invert_pose(poses[f]), observations[f].points)) for f in frames]
        return cls(0, label, dict(observations), poses.copy(), valid,
                   np.ones(len(poses)) if fitness is None else fitness.copy(), chunks, frames[0] if frames else 0,
                   times, sensor_positions)

    # --- what the track holds ---

    @property
    def frames(self) -> list[int]:
        """The frame of each chunk, in chunk order."""
        return [c.frame for c in self.chunks]

    @property
    def point_counts(self) -> np.ndarray:  # -> [F] lidar points observed at each frame
        counts = np.zeros(len(self.poses), np.int64)
        for f, o in self.observations.items():
            counts[f] = len(o.points)
        return counts

    def pending(self) -> list[InstanceObservation]:
        """Observations whose frame has no accepted pose, in the order they were given."""
        return [o for o in self.observations.values() if not self.valid[o.frame]]

    def points(self, chunks: Optional[Iterable[int]] = None) -> np.ndarray:  # -> [N, 3] canonical
        """The canonical points of ``chunks`` (indices; all by default), concatenated in that order."""
        index = range(len(self.chunks)) if chunks is None else chunks
        return np.concatenate([self.chunks[k].points for k in index])

    def features_of(self, frame: int) -> np.ndarray:  # -> [N, D]
        """The point features of the observation at ``frame``."""
        f = None if self.features is None else self.features.features.get((self.feature_id, frame))
        if f is None:  # every lifted observation is described by the extractors; anything else is a bug
            extractor = None if self.features is None else self.features.extractor
            raise ValueError(f"{extractor} gave no features for instance {self.feature_id} at frame {frame}")
        return f

    def chunk_features(self, chunks: Optional[Iterable[int]] = None) -> np.ndarray:  # -> [N, D]
        index = range(len(self.chunks)) if chunks is None else chunks
        return np.concatenate([self.features_of(self.chunks[k].frame) for k in index])

    def colours_of(self, frame: int) -> Optional[np.ndarray]:  # -> [N, 3] or None
        if self.features is None or not self.features.colors:
            return None
        return self.features.colors.get((self.feature_id, frame))

    def sensor_at(self, frame: int) -> Optional[np.ndarray]:  # -> [3] world
        return None if self.sensor_positions is None else self.sensor_positions[frame]

    def chunk_sensors(self, chunks: Optional[Iterable[int]] = None) -> Optional[np.ndarray]:  # -> [N, 3] canonical
        """The sensor that saw each point of ``chunks``, in the canonical frame (a chunk is its
        frame's points mapped by that frame's pose, so the same pose maps its sensor)."""
        if self.sensor_positions is None:
            return None
        index = list(range(len(self.chunks)) if chunks is None else chunks)
        frames = np.asarray([self.chunks[k].frame for k in index], dtype=np.int64)
        local = sensors_in_canonical(self.poses, self.sensor_positions, frames)  # [K, 3]
        return np.repeat(local, [len(self.chunks[k].points) for k in index], axis=0)

    def nearest_chunks(self, frame: int, count: int, max_gap: float = np.inf) -> list[int]:
        """Indices of the (up to) ``count`` chunks nearest to ``frame`` in time, nearest first (ties
        in chunk order), leaving out those further than ``max_gap`` seconds."""
        gaps = np.abs(self.times[np.asarray(self.frames)] - self.times[frame])
        return [int(k) for k in np.argsort(gaps, kind="stable")[:count] if gaps[k] <= max_gap]

    # --- the only ways a pass changes the track ---

    def accept(self, obs: InstanceObservation, transform: np.ndarray) -> None:  # transform: [4, 4]
        """The frame's pose is ``transform`` and its points join the canonical set."""
        self.poses[obs.frame], self.valid[obs.frame] = transform, True
        self.chunks.append(Chunk(obs.frame, transform_points(invert_pose(transform), obs.points)))

    def coast(self, frame: int, pose: np.ndarray) -> None:  # pose: [4, 4]
        """The frame's pose is ``pose``; its points do not join the canonical set."""
        self.poses[frame], self.valid[frame] = pose, True

    def repose(self, frame: int, transform: np.ndarray, fitness: float) -> None:  # transform: [4, 4]
        """An accepted frame's pose replaced; its chunk re-mapped with the new pose."""
        self.poses[frame], self.fitness[frame] = transform, fitness
        for chunk in self.chunks:
            if chunk.frame == frame:
                chunk.points = transform_points(invert_pose(transform), self.observations[frame].points)

    def drop(self, frame: int) -> None:
        """The frame's pose is no longer accepted, and its points leave the canonical set."""
        self.valid[frame] = False
        self.chunks = [c for c in self.chunks if c.frame != frame]

    # --- the result ---

    def track(self) -> InstanceTrack:
        """The finished track: invalid frames' poses filled from the valid ones, per-point frames
        and (when every chunk's observation has them) lidar ray times."""
        colours = [self.colours_of(c.frame) for c in self.chunks]
        point_frames = np.concatenate([np.full(len(c.points), c.frame, np.int32) for c in self.chunks])
        # Every chunk is its frame's whole observation, in order, so the ray times line up.
        point_times = None
        if all(self.observations[c.frame].times is not None for c in self.chunks):
            point_times = np.concatenate([self.observations[c.frame].times for c in self.chunks])
            if len(point_times) != len(point_frames):  # a chunk that is not a whole observation: a bug
                raise ValueError(f"instance {self.instance_id}: canonical chunks do not match their observations' ray times")
        return InstanceTrack(
            instance_id=self.instance_id, label=self.label, canonical_points=self.points(),
            canonical_colors=None if any(c is None for c in colours) else np.concatenate(colours),
            poses=fill_invalid_poses(self.poses, self.valid), valid=self.valid, point_counts=self.point_counts,
            fitness=self.fitness, canonical_frame=self.reference_frame, point_frames=point_frames, point_times=point_times,
        )
