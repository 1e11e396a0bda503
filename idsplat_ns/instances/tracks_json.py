"""Instance tracks as JSON, in the data's own world frame and clock, for exchange with other tools.

Layout (``idsplat-preprocess --export``; ``--pipeline.datamanager.import-tracks`` reads it)::

    {"format": "idsplat-tracks/1", "sequence": NAME, "world": "dataset",
     "instances": [{"id": 1, "label": "car", "class": "vehicle",
                    "times": [seconds, the data's own timestamps],
                    "poses": [[4x4 canonical-to-world in the data's own world frame], ...],
                    "num_points": [lidar points seen at each time],
                    "measured": [true where a registration measured the pose],
                    "canonical_points": [[x, y, z], ...]      (optional)
                    "canonical_colors": [[r, g, b], ...]      (optional: 0-255, one per canonical point)
                    "size": [length, width, height]}]}        (optional; used when there are no points)

``label`` is the raw class name (detector prompt, annotation label or the lidar-motion guess);
``class`` is its evaluation class (``vehicle``, ``pedestrian``, ``cyclist`` or ``other``), written on
export and, on import, used as the label of an entry that has no ``label``.

On import an instance is placed at each frame of the scene inside its time span (translation
interpolated linearly, rotation by slerp) and is absent outside it. Its points are the listed
canonical points, or else the lidar points inside a box of ``size`` around its canonical origin.
Their colours (the first colours of the instance's Gaussians) are the listed canonical colours, or
else projected from the training images, as for tracks that have none.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from idsplat_ns.atomic import atomic_path
from idsplat_ns.data.geometry import invert_pose
from idsplat_ns.data.scene import Scene
from idsplat_ns.errors import IDSplatError
from idsplat_ns.instances.tracks import InstanceTrack, InstanceTracks

FORMAT = "idsplat-tracks/1"
TIME_TOLERANCE_S = 1e-3  # a track time this close to a frame's time is that frame


def _seconds_offset(scene: Scene) -> float:
    """The data's own timestamp, in seconds, of the scene's t = 0."""
    return float(scene.time_origin_raw) * float(scene.raw_time_unit_seconds)


def tracks_to_json(tracks: InstanceTracks, scene: Scene) -> dict:
    """The dynamic instances of ``tracks`` (made on ``scene``) in the data's own frame and clock."""
    raw_from_world = invert_pose(scene.world_from_raw)
    offset = _seconds_offset(scene)
    out = []
    for inst in tracks.instances:
        measured = inst.valid if inst.measured_valid is None else inst.measured_valid
        keep = np.flatnonzero(inst.valid)
        out.append({
            "id": int(inst.instance_id),
            "label": inst.label,
            "class": inst.category,
            "times": [float(tracks.frame_times[k]) + offset for k in keep],
            "poses": [np.round(raw_from_world @ inst.poses[k], 6).tolist() for k in keep],
            "num_points": [int(inst.point_counts[k]) for k in keep],
            "measured": [bool(measured[k]) for k in keep],
            "canonical_points": np.round(inst.canonical_points, 4).tolist(),
        })
        if inst.canonical_colors is not None:  # what the Gaussians start from: a re-import trains the same
            out[-1]["canonical_colors"] = np.clip(np.round(inst.canonical_colors), 0, 255).astype(int).tolist()
    return {"format": FORMAT, "sequence": scene.name, "world": "dataset", "instances": out}


def write_tracks_json(path: Path, tracks: InstanceTracks, scene: Scene) -> None:
    """Write :func:`tracks_to_json` to ``path`` atomically."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(path) as tmp:
        Path(tmp).write_text(json.dumps(tracks_to_json(tracks, scene)))


def _field(entry: dict, name: str, where: str, shape_tail: tuple[int, ...]) -> np.ndarray:
    if name not in entry:
        raise IDSplatError(f"{where}: no {name!r}; see the layout in docs/instances.md")
    try:
        arr = np.asarray(entry[name], dtype=np.float64)
    except (TypeError, ValueError):
        raise IDSplatError(f"{where}: {name!r} is not a list of numbers") from None
    if arr.ndim != 1 + len(shape_tail) or arr.shape[1:] != shape_tail or not np.all(np.isfinite(arr)):
        raise IDSplatError(f"{where}: {name!r} must be finite numbers of shape [N{''.join(f', {d}' for d in shape_tail)}], got {list(arr.shape)}")
    return arr


def _points_in_box(scene: Scene, poses: np.ndarray, valid: np.ndarray, size: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Canonical points [N, 3] of the lidar inside the box at each valid frame, and counts [F]."""
    half = np.asarray(size, dtype=np.float64) / 2.0
    pts, counts = [], np.zeros(len(valid), dtype=np.int64)
    by_frame = {s.frame_index: s for s in scene.lidar}
    for k in np.flatnonzero(valid):
        sweep = by_frame.get(int(scene.frame_indices[k]))
        if sweep is None:
            continue
        T = invert_pose(poses[k])
        local = sweep.points @ T[:3, :3].T + T[:3, 3]
        inside = np.all(np.abs(local) <= half, axis=1)
        counts[k] = int(inside.sum())
        pts.append(local[inside])
    return (np.concatenate(pts) if pts else np.zeros((0, 3))), counts


def tracks_from_json(path: Path, scene: Scene) -> InstanceTracks:
    """Read a tracks file and place its instances on ``scene``'s frames (see the module docstring)."""
    path = Path(path)
    try:
        data = json.loads(path.read_text())
    except FileNotFoundError:
        raise IDSplatError(f"{path}: tracks file not found; write one with idsplat-preprocess --export") from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as err:
        raise IDSplatError(f"{path}: not readable as JSON ({err.__class__.__name__}); write it with idsplat-preprocess --export") from None
    if not isinstance(data, dict) or not isinstance(data.get("instances"), list):
        raise IDSplatError(f"{path}: no 'instances' list; see the layout in docs/instances.md")
    world_from_raw, offset = scene.world_from_raw, _seconds_offset(scene)
    frame_times = np.asarray(scene.frame_times, dtype=np.float64)
    instances, seen_ids = [], set()
    for n, entry in enumerate(data["instances"]):
        has_id = isinstance(entry, dict) and isinstance(entry.get("id"), int) and not isinstance(entry["id"], bool)
        # Named by its id, as the user's own tools and ns-eval name it; by position only without one.
        where = f"{path}: instance id {entry['id']}" if has_id else f"{path}: instances[{n}]"
        if not has_id or entry["id"] < 1:
            raise IDSplatError(f"{where}: needs an integer 'id' >= 1 (0 is the static background)")
        if entry["id"] in seen_ids:
            raise IDSplatError(f"{where}: id {entry['id']} appears twice; instance ids must be unique")
        seen_ids.add(entry["id"])
        times = _field(entry, "times", where, ()) - offset
        poses_raw = _field(entry, "poses", where, (4, 4))
        if len(poses_raw) != len(times) or len(times) == 0:
            raise IDSplatError(f"{where}: {len(times)} times and {len(poses_raw)} poses; give one pose per time, at least one")
        if np.any(np.diff(times) <= 0):
            raise IDSplatError(f"{where}: 'times' must increase strictly")
        poses_w = world_from_raw @ poses_raw
        valid = (frame_times >= times[0] - TIME_TOLERANCE_S) & (frame_times <= times[-1] + TIME_TOLERANCE_S)
        t_clamped = np.clip(frame_times, times[0], times[-1])
        poses = np.tile(np.eye(4), (len(frame_times), 1, 1))
        if len(times) == 1:
            poses[:] = poses_w[0]
        else:
            rot = Slerp(times, Rotation.from_matrix(poses_w[:, :3, :3]))(t_clamped)
            poses[:, :3, :3] = rot.as_matrix()
            for axis in range(3):
                poses[:, axis, 3] = np.interp(t_clamped, times, poses_w[:, axis, 3])
        colors = None
        if "canonical_points" in entry:
            points = _field(entry, "canonical_points", where, (3,))
            if "canonical_colors" in entry:
                colors = _field(entry, "canonical_colors", where, (3,))
                if len(colors) != len(points) or colors.min(initial=0) < 0 or colors.max(initial=0) > 255:
                    raise IDSplatError(f"{where}: 'canonical_colors' must be one [r, g, b] in 0-255 per canonical point "
                                       f"({len(points)}), got {len(colors)}")  # fmt: skip
                colors = np.round(colors).astype(np.uint8)
            counts = np.zeros(len(frame_times), dtype=np.int64)
            if "num_points" in entry:
                listed = _field(entry, "num_points", where, ())
                nearest = np.abs(frame_times[:, None] - times[None]).argmin(1)
                close = np.abs(frame_times - times[nearest]) <= TIME_TOLERANCE_S
                counts[close & valid] = listed[nearest[close & valid]].astype(np.int64)
        elif "size" in entry:
            points, counts = _points_in_box(scene, poses, valid, _field(entry, "size", where, ()))
        else:
            raise IDSplatError(f"{where}: needs 'canonical_points' or a box 'size' [length, width, height] to find its lidar points")
        if not valid.any():
            continue  # outside the frames loaded
        instances.append(InstanceTrack(
            instance_id=int(entry["id"]), label=str(entry.get("label", entry.get("class", "object"))), canonical_points=points,
            canonical_colors=colors, poses=poses, valid=valid, point_counts=counts, fitness=valid.astype(np.float64),
            canonical_frame=int(np.argmax(np.where(valid, counts, -1))),
        ))
    return InstanceTracks(np.asarray(scene.frame_indices), frame_times, instances, [],
                          {"source": "imported", "file": str(path)})
