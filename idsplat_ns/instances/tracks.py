"""The result of instance decomposition: per instance, a label and its class, canonical points and
per-frame poses.

Conventions (../shared/DESIGN.md): instance IDs start at 1 (0 is the static background); the pose
``poses[k]`` maps the instance's canonical frame to the world at ``frame_times[k]``.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Optional

import numpy as np

from idsplat_ns.data.geometry import invert_pose
from idsplat_ns.data.tracks import label_group
from idsplat_ns.errors import IDSplatError
from idsplat_ns.instances.cache import load_npz, save_npz


@dataclass
class InstanceTrack:
    """One rigid instance over the sequence."""

    instance_id: int
    """ID >= 1, unique within the sequence."""
    label: str
    """Raw class name from the mask source (a detector prompt such as ``car``, an annotation label
    such as ``Pedestrian with Object`` in oracle mode, or the lidar-motion source's guess)."""
    canonical_points: np.ndarray
    """[N, 3] float64 lidar points in the canonical frame (all successfully registered times)."""
    canonical_colors: Optional[np.ndarray]
    """[N, 3] uint8 RGB of those points where images exist, else None."""
    poses: np.ndarray
    """[F, 4, 4] canonical-to-world per scene frame. Where ``valid`` is false the pose of the nearest
    valid frame is repeated, so that consumers that ignore ``valid`` still get a finite pose."""
    valid: np.ndarray
    """[F] bool: a pose was estimated (registration succeeded) at that frame."""
    point_counts: np.ndarray
    """[F] int lidar points of the instance at each frame (0 where not seen)."""
    fitness: np.ndarray
    """[F] float registration fitness at each frame (1 at the canonical frame, 0 where not registered)."""
    canonical_frame: int
    """Index of the frame with the most points, which defines the canonical frame."""
    measured_valid: Optional[np.ndarray] = None
    """[F] bool frames with a registration measurement, kept once smoothing has replaced ``poses``
    and ``valid`` (None before smoothing, when it equals ``valid``)."""
    point_frames: Optional[np.ndarray] = None
    """[N] int frame each canonical point was registered from (None where not recorded), so that
    points of frames the smoother rejects can leave the canonical set."""
    point_times: Optional[np.ndarray] = None
    """[N] float64 seconds: when each canonical point's lidar ray was fired (None where not
    recorded). A frame's registration poses the instance at about its points' mean time, and the
    smoother places it there (see ``measurement_times``)."""

    def keep_points_of_frames(self, frames: np.ndarray, min_points: int = 10) -> "InstanceTrack":
        """A copy whose canonical points come only from ``frames`` ([F] bool); unchanged when the
        origin frames are unknown or fewer than ``min_points`` would remain."""
        if self.point_frames is None:
            return self
        keep = np.asarray(frames, bool)[self.point_frames]
        if keep.all() or keep.sum() < min_points:
            return self
        colors = None if self.canonical_colors is None else self.canonical_colors[keep]
        times = None if self.point_times is None else self.point_times[keep]
        return replace(self, canonical_points=self.canonical_points[keep], canonical_colors=colors,
                       point_frames=self.point_frames[keep], point_times=times)

    def with_points_posed_by(self, poses: np.ndarray) -> "InstanceTrack":  # poses: [N, 4, 4]
        """A copy whose canonical points are re-derived for new poses, one per point ([N, 4, 4],
        canonical -> world, e.g. the smoothed trajectory at each point's ray time): each point keeps
        the world position it had under ``self.poses`` at its frame. Points of unknown origin frame
        are left as they are."""
        if self.point_frames is None:
            return self
        M = invert_pose(poses) @ self.poses[self.point_frames]  # old canonical -> world -> new canonical
        pts = np.einsum("nij,nj->ni", M[:, :3, :3], self.canonical_points) + M[:, :3, 3]
        return replace(self, canonical_points=pts)

    def measurement_times(self, frame_times: np.ndarray) -> np.ndarray:  # frame_times: [F] -> [F]
        """When each frame's registration saw the instance: the mean ray time of its points where
        they are recorded, else the frame's time. Falls back to ``frame_times`` when the result
        would not increase strictly."""
        out = np.array(frame_times, dtype=np.float64, copy=True)
        if self.point_frames is None or self.point_times is None:
            return out
        sums = np.bincount(self.point_frames, weights=self.point_times, minlength=len(out))[: len(out)]
        counts = np.bincount(self.point_frames, minlength=len(out))[: len(out)]
        seen = counts > 0
        out[seen] = sums[seen] / counts[seen]
        return out if np.all(np.diff(out) > 0) else np.array(frame_times, dtype=np.float64, copy=True)

    @property
    def category(self) -> str:
        """The evaluation class of the label: ``vehicle``, ``pedestrian``, ``cyclist`` or ``other``."""
        return label_group(self.label)

    @property
    def num_valid(self) -> int:
        return int(self.valid.sum())

    def displacement(self) -> float:
        """Largest distance (metres) between two valid positions of the canonical origin."""
        t = self.poses[self.valid, :3, 3]
        if len(t) < 2:
            return 0.0
        return float(np.max(np.linalg.norm(t[:, None] - t[None], axis=-1)))


@dataclass
class InstanceTracks:
    """All instances of one sequence, plus those converted to static background."""

    frame_indices: np.ndarray
    """[F] dataset frame indices (as in ``Scene.frame_indices``)."""
    frame_times: np.ndarray
    """[F] float64 seconds since the sequence start."""
    instances: list[InstanceTrack]
    """Dynamic instances (the model gives each an ID and a trajectory)."""
    static_instances: list[InstanceTrack] = field(default_factory=list)
    """Instances whose displacement was below the static threshold (kept for inspection; their
    points stay in the background)."""
    metadata: dict = field(default_factory=dict)
    """Which mask source and feature extractor ran, config hashes, smoothing status."""

    def class_counts(self) -> dict[str, int]:
        """Dynamic instances per class, e.g. ``{"vehicle": 5, "pedestrian": 2}`` (classes present only)."""
        counts: dict[str, int] = {}
        for inst in self.instances:
            counts[inst.category] = counts.get(inst.category, 0) + 1
        return counts

    def instance(self, instance_id: int) -> InstanceTrack:
        for inst in self.instances + self.static_instances:
            if inst.instance_id == instance_id:
                return inst
        raise KeyError(instance_id)

    def save(self, path: Path) -> None:
        """Write to ``path`` (a ``.npz``); the caller handles atomicity (see ``cache.atomic_path``)."""
        arrays: dict[str, np.ndarray] = {"frame_indices": self.frame_indices, "frame_times": self.frame_times}
        index = []
        for group, insts in (("dynamic", self.instances), ("static", self.static_instances)):
            for inst in insts:
                key = f"i{inst.instance_id}"
                index.append({"id": inst.instance_id, "label": inst.label, "group": group,
                              "canonical_frame": inst.canonical_frame,
                              "has_colors": inst.canonical_colors is not None})
                arrays[f"{key}_points"] = inst.canonical_points
                arrays[f"{key}_poses"] = inst.poses
                arrays[f"{key}_valid"] = inst.valid
                arrays[f"{key}_counts"] = inst.point_counts
                arrays[f"{key}_fitness"] = inst.fitness
                if inst.canonical_colors is not None:
                    arrays[f"{key}_colors"] = inst.canonical_colors
                if inst.measured_valid is not None:
                    arrays[f"{key}_measured_valid"] = inst.measured_valid
                if inst.point_frames is not None:
                    arrays[f"{key}_point_frames"] = inst.point_frames
                if inst.point_times is not None:
                    arrays[f"{key}_point_times"] = inst.point_times
        save_npz(path, arrays, {"instances": index, "metadata": self.metadata})

    @classmethod
    def load(cls, path: Path) -> "InstanceTracks":
        """Read a file written by :meth:`save`."""
        path = Path(path)
        if not path.is_file():
            raise IDSplatError(f"{path}: instance tracks file not found; run idsplat-preprocess first")
        data, meta = load_npz(path)
        out = cls(data["frame_indices"], data["frame_times"], [], [], meta["metadata"])
        for entry in meta["instances"]:
            key = f"i{entry['id']}"
            inst = InstanceTrack(
                instance_id=entry["id"], label=entry["label"],
                canonical_points=data[f"{key}_points"],
                canonical_colors=data[f"{key}_colors"] if entry["has_colors"] else None,
                poses=data[f"{key}_poses"], valid=data[f"{key}_valid"],
                point_counts=data[f"{key}_counts"], fitness=data[f"{key}_fitness"],
                canonical_frame=entry["canonical_frame"],
                measured_valid=data.get(f"{key}_measured_valid"),
                point_frames=data.get(f"{key}_point_frames"),
                point_times=data.get(f"{key}_point_times"),
            )
            (out.instances if entry["group"] == "dynamic" else out.static_instances).append(inst)
        return out


def fill_invalid_poses(poses: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """Copy of poses [F, 4, 4] where each invalid frame takes the pose of the nearest valid frame
    (identity when no frame is valid)."""
    out = np.array(poses, dtype=np.float64, copy=True)
    good = np.nonzero(valid)[0]
    if len(good) == 0:
        out[:] = np.eye(4)
        return out
    for k in np.nonzero(~np.asarray(valid))[0]:
        out[k] = out[good[np.argmin(np.abs(good - k))]]
    return out
