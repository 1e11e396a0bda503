"""PandaSet parser: the real dataset layout (and the synthetic street, which writes the same layout).

Layout of a sequence folder (see docs/formats/pandaset.md): ``camera/<cam>/{NN.jpg, poses.json,
intrinsics.json, timestamps.json}``, ``lidar/{NN.pkl.gz, poses.json, timestamps.json}`` with points
in the world frame (columns x, y, z, i, t, d; d = 0 Pandar64 spinning, d = 1 PandarGT front),
``annotations/cuboids/NN.pkl.gz``. Optional project extensions in ``idsplat_extras/``: rays that
returned nothing, ground-truth instance masks and their classes, and the cameras' rolling-shutter
readout (``rolling_shutter.json``; without it, as in PandaSet proper, images are global-shutter).

Conventions applied here, once: world recentred on the first kept lidar (ego) position; times in
seconds from the first kept frame; intensity scaled from 0..255 to [0, 1]; each returned point's
ray origin is the Pandar64 position at that point's own time (poses interpolated between sweeps).
PandaSet does not store rays that returned nothing; without the extension every ray returned.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Optional, Sequence

import numpy as np
import pandas as pd

from idsplat_ns.data.camera import CameraImage, Intrinsics, RollingShutter
from idsplat_ns.data.geometry import make_pose, quat_to_rotmat, rot_z
from idsplat_ns.data.lidar import LidarSweep, rays_from_points
from idsplat_ns.data.scene import Scene, recentring_transform
from idsplat_ns.data.tracks import ObjectTrack
from idsplat_ns.data.validation import (
    MAX_LIDAR_RANGE_M,
    MAX_SWEEP_TIME_OFFSET_S,
    check_within,
    check_columns,
    check_finite,
    check_frame_counts,
    check_image_sizes,
    check_intrinsics,
    check_pose,
    check_quaternion,
    check_regular_file,
    check_timestamps,
)
from idsplat_ns.errors import IDSplatError

PANDASET_CAMERAS = (
    "front_camera",
    "front_left_camera",
    "front_right_camera",
    "left_camera",
    "right_camera",
    "back_camera",
)
EXTRAS = "idsplat_extras"


def read_json(path: Path):
    """Read a JSON file; a missing or malformed file is one clear error naming it."""
    if not path.is_file():
        raise IDSplatError(f"{path}: missing; the PandaSet sequence is incomplete (re-download or regenerate it)")
    try:
        return json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as err:
        raise IDSplatError(f"{path}: not valid JSON ({err.__class__.__name__}); re-download or regenerate it") from None


def read_pickle(path: Path) -> pd.DataFrame:
    """Read a gzip-pickled DataFrame; a missing, truncated or corrupt file is one clear error naming it."""
    if not path.is_file():
        raise IDSplatError(f"{path}: missing; the PandaSet sequence is incomplete (re-download or regenerate it)")
    try:
        frame = pd.read_pickle(path)
    except Exception as err:  # pickle/gzip/zlib raise many unrelated types for a damaged file
        raise IDSplatError(f"{path}: unreadable pickle ({err.__class__.__name__}: {err}); re-download or regenerate it") from None
    if not isinstance(frame, pd.DataFrame):
        raise IDSplatError(f"{path}: holds a {type(frame).__name__}, expected a pandas DataFrame")
    return frame


def pose_from_json(entry: dict, where: str = "poses.json", frame: Optional[int] = None) -> np.ndarray:
    """A PandaSet pose dict ``{"position": {x,y,z}, "heading": {w,x,y,z}}`` as a 4x4 matrix.

    The values are validated here (finite position, non-zero quaternion), where the file and frame
    are known, so a NaN pose stops the load in one line instead of training on NaN.
    """
    p, h = entry["position"], entry["heading"]
    position = check_finite(np.array([p["x"], p["y"], p["z"]], dtype=np.float64), where, "position", frame)
    q = check_quaternion(np.array([h["w"], h["x"], h["y"], h["z"]], dtype=np.float64), where, "heading", frame)
    return check_pose(make_pose(quat_to_rotmat(q), position), where, "pose", frame)


def read_poses(path: Path) -> np.ndarray:
    """All poses of a ``poses.json`` as [F, 4, 4]."""
    entries = read_json(path)
    if not isinstance(entries, list) or not entries:
        raise IDSplatError(f"{path}: expected a non-empty list of poses; re-download or regenerate it")
    poses = []
    for i, e in enumerate(entries):
        try:
            poses.append(pose_from_json(e, str(path), i))
        except (KeyError, TypeError, ValueError) as err:
            raise IDSplatError(
                f"{path}: frame {i}: malformed pose entry ({err.__class__.__name__}: {err}); expected position x,y,z and heading w,x,y,z"
            ) from None
    return np.stack(poses)


def read_timestamps(path: Path) -> np.ndarray:
    """A ``timestamps.json`` as float64 seconds, checked finite and increasing."""
    stamps = read_json(path)
    try:
        values = np.asarray(stamps, dtype=np.float64)
    except (TypeError, ValueError) as err:
        raise IDSplatError(f"{path}: timestamps are not numbers ({err}); re-download or regenerate it") from None
    if values.ndim != 1 or values.size == 0:
        raise IDSplatError(f"{path}: expected a non-empty list of numbers, got shape {values.shape}")
    return check_timestamps(values, str(path))


def read_intrinsics(path: Path) -> dict[str, float]:
    """fx, fy, cx, cy of an ``intrinsics.json``; the focal lengths checked here, the principal point
    against the image size once the first image is opened."""
    intr = read_json(path)
    try:
        values = {k: float(intr[k]) for k in ("fx", "fy", "cx", "cy")}
    except (KeyError, TypeError, ValueError) as err:
        raise IDSplatError(f"{path}: intrinsics need numbers fx, fy, cx, cy ({err.__class__.__name__}: {err})") from None
    # Size unknown yet: a stand-in that accepts any principal point; _load_images checks it later.
    check_intrinsics(values["fx"], values["fy"], 0.0, 0.0, 1, 1, str(path))
    return values


def cuboid_yaw_to_rotation(yaw: np.ndarray) -> np.ndarray:
    """Box-to-world rotations [..., 3, 3] (x along the length) from PandaSet yaw [...].

    PandaSet's yaw 0 points the length axis along world +y, counter-clockwise; our box frame has
    x along the length, so the box x axis is Rz(yaw) applied to +y, i.e. Rz(yaw + pi/2).
    """
    return rot_z(np.asarray(yaw, dtype=np.float64) + np.pi / 2)


def _sequence_frame_count(root: Path) -> int:
    return len(read_timestamps(root / "lidar" / "timestamps.json"))


def _select_frames(num: int, start: int, end: Optional[int], path: Path) -> np.ndarray:
    end = num if end is None else end
    if not (0 <= start < end <= num):
        raise IDSplatError(f"{path}: frame range [{start}, {end}) is outside the sequence's {num} frames; fix start/end")
    return np.arange(start, end)


def load_sequence(
    path: str | Path,
    cameras: Optional[Sequence[str]] = None,
    start: int = 0,
    end: Optional[int] = None,
    load_lidar: bool = True,
    lidar_sensors: Sequence[int] = (0,),
    load_cuboids: bool = True,
) -> Scene:
    """Parse one PandaSet sequence folder into a :class:`Scene`.

    Args:
        path: the sequence folder (``.../pandaset/001``).
        cameras: camera folder names to load (default: every camera present, in PandaSet order).
        start, end: the half-open range of frame indices to keep.
        load_lidar: read the lidar sweeps (needed for initialisation and lidar supervision).
        lidar_sensors: which ``d`` values to keep: 0 the spinning Pandar64 (default; its pose is
            the one PandaSet gives), 1 the front PandarGT.
        load_cuboids: read the annotation cuboids as ground-truth tracks (evaluation only).
    """
    root = Path(path).expanduser()
    if not root.is_dir():
        raise IDSplatError(f"{root}: no such PandaSet sequence folder; pass --data to a folder with camera/ and lidar/ (or omit it for the built-in street)")
    if not (root / "camera").is_dir():
        raise IDSplatError(f"{root}: no camera/ folder here; is this a PandaSet sequence folder (e.g. pandaset/001)?")
    present = [c for c in PANDASET_CAMERAS if (root / "camera" / c).is_dir()]
    present += sorted(p.name for p in (root / "camera").iterdir() if p.is_dir() and p.name not in present)
    if cameras is None:
        cameras = present
    for cam in cameras:
        if cam not in present:
            raise IDSplatError(f"{root / 'camera'}: camera '{cam}' not in this sequence; available: {', '.join(present)}")
    if not cameras:
        raise IDSplatError(f"{root / 'camera'}: no camera folders found")

    num_frames = _sequence_frame_count(root)
    frames = _select_frames(num_frames, start, end, root)
    lidar_times_raw = read_timestamps(root / "lidar" / "timestamps.json")
    lidar_poses_raw = read_poses(root / "lidar" / "poses.json")
    if len(lidar_poses_raw) != num_frames:
        raise IDSplatError(f"{root / 'lidar' / 'poses.json'}: {len(lidar_poses_raw)} poses for {num_frames} timestamps")

    world_from_raw = recentring_transform(lidar_poses_raw[frames[0]])
    cam_meta = {}
    for cam in cameras:
        folder = root / "camera" / cam
        intr = read_intrinsics(folder / "intrinsics.json")
        poses = read_poses(folder / "poses.json")
        stamps = read_timestamps(folder / "timestamps.json")
        check_frame_counts(
            {str(folder / "poses.json"): len(poses), str(folder / "timestamps.json"): len(stamps)},
            num_frames, str(root / "lidar" / "timestamps.json"),
        )
        cam_meta[cam] = (intr, poses, stamps)
    time_origin = min([lidar_times_raw[frames[0]]] + [m[2][frames[0]] for m in cam_meta.values()])

    shutters = _read_rolling_shutter(root / EXTRAS / "rolling_shutter.json", cameras)
    images = _load_images(root, frames, cameras, cam_meta, world_from_raw, time_origin, shutters)
    sweeps = []
    if load_lidar:
        sweeps = [
            _load_sweep(root, f, lidar_times_raw, lidar_poses_raw, world_from_raw, time_origin, lidar_sensors)
            for f in frames
        ]
    tracks = _load_tracks(root, frames, lidar_times_raw, world_from_raw, time_origin) if load_cuboids else []

    metadata = {"num_frames_in_sequence": num_frames}
    instances_json = root / EXTRAS / "instances.json"
    if instances_json.is_file():
        metadata["gt_instances"] = {int(k): v for k, v in read_json(instances_json).items()}
    generator = root / EXTRAS / "generator.json"
    if generator.is_file():
        metadata["generator"] = read_json(generator)
    return Scene(
        name=root.name,
        source="synthetic" if "generator" in metadata else "pandaset",
        root=root,
        frame_indices=frames,
        frame_times=lidar_times_raw[frames] - time_origin,
        ego_poses=np.stack([world_from_raw @ p for p in lidar_poses_raw[frames]]),
        images=images,
        lidar=sweeps,
        tracks=tracks,
        world_from_raw=world_from_raw,
        time_origin_raw=float(time_origin),
        raw_time_unit_seconds=1.0,
        metadata=metadata,
    )


ROLLING_SHUTTER_DIRECTIONS = ("top_to_bottom", "bottom_to_top", "left_to_right", "right_to_left", "global")


def _read_rolling_shutter(path: Path, cameras: Sequence[str]) -> dict[str, RollingShutter]:
    """``{camera: RollingShutter}`` from ``idsplat_extras/rolling_shutter.json`` (``{camera:
    {"readout_seconds": s, "direction": d}}``); empty when the file is absent (PandaSet proper)."""
    if not path.is_file():
        return {}
    data = read_json(path)
    if not isinstance(data, dict):
        raise IDSplatError(f"{path}: expected an object of camera names; regenerate the sequence")
    out = {}
    for cam in cameras:
        entry = data.get(cam)
        if entry is None:
            continue
        readout = entry.get("readout_seconds") if isinstance(entry, dict) else None
        direction = entry.get("direction") if isinstance(entry, dict) else None
        if not isinstance(readout, (int, float)) or not np.isfinite(readout) or not 0 <= readout < 1:
            raise IDSplatError(f"{path}: {cam}: readout_seconds must be a number in [0, 1); regenerate the sequence")
        if direction not in ROLLING_SHUTTER_DIRECTIONS:
            raise IDSplatError(f"{path}: {cam}: direction {direction!r} is not one of {', '.join(ROLLING_SHUTTER_DIRECTIONS)}")
        out[cam] = RollingShutter(readout_seconds=float(readout), direction=direction)
    return out


def _load_images(root, frames, cameras, cam_meta, world_from_raw, time_origin, shutters) -> list[CameraImage]:
    images = []
    first_size: dict[str, tuple[int, tuple[int, int]]] = {}
    for f in frames:
        for cam in cameras:
            intr, poses, stamps = cam_meta[cam]
            path = root / "camera" / cam / f"{f:02d}.jpg"
            check_regular_file(path, "the image", "the PandaSet sequence is incomplete")
            width, height = _image_size(path)
            if cam not in first_size:  # the principal point can only be checked against a real size
                first_size[cam] = (int(f), (width, height))
                check_intrinsics(intr["fx"], intr["fy"], intr["cx"], intr["cy"], width, height,
                                 str(root / "camera" / cam / "intrinsics.json"))
            check_image_sizes([(str(root / "camera" / cam), *first_size[cam]), (str(root / "camera" / cam), int(f), (width, height))])
            mask = root / EXTRAS / "instance_masks" / cam / f"{f:02d}.png"
            images.append(
                CameraImage(
                    camera=cam,
                    frame_index=int(f),
                    time=float(stamps[f] - time_origin),
                    raw_timestamp=float(stamps[f]),
                    camera_to_world=world_from_raw @ poses[f],
                    intrinsics=Intrinsics(fx=intr["fx"], fy=intr["fy"], cx=intr["cx"], cy=intr["cy"], width=width, height=height),
                    image_path=path,
                    rolling_shutter=shutters.get(cam),
                    instance_mask_path=mask if mask.is_file() else None,
                )
            )
    return images


def _image_size(path: Path) -> tuple[int, int]:
    from PIL import Image, UnidentifiedImageError

    try:
        with Image.open(path) as im:
            return im.size
    except (UnidentifiedImageError, OSError) as err:
        raise IDSplatError(f"{path}: unreadable image ({err.__class__.__name__}); re-download or regenerate it") from None


def _load_sweep(root, f, lidar_times_raw, lidar_poses_raw, world_from_raw, time_origin, sensors) -> LidarSweep:
    path = root / "lidar" / f"{f:02d}.pkl.gz"
    df = read_pickle(path)
    check_columns(df.columns, ("x", "y", "z", "i", "t", "d"), str(path), "lidar DataFrame")
    df = df[df["d"].isin(list(sensors))]
    for column in ("x", "y", "z", "i", "t"):
        try:
            check_finite(df[column].to_numpy(np.float64), str(path), f"column {column}", int(f))
        except (TypeError, ValueError) as err:  # a non-numeric column in a damaged file
            raise IDSplatError(f"{path}: frame {f}: column {column} is not numeric ({err}); re-download or regenerate it") from None
    points = world_from_raw[:3, :3] @ df[["x", "y", "z"]].to_numpy(np.float64).T
    points = points.T + world_from_raw[:3, 3]
    t_raw = df["t"].to_numpy(np.float64)
    origins = _sensor_positions(t_raw, lidar_times_raw, lidar_poses_raw, world_from_raw)
    directions, ranges = rays_from_points(origins, points)
    check_within(ranges, 0.0, MAX_LIDAR_RANGE_M, str(path), "range from the sensor (x, y, z)", int(f), " m")
    check_within(t_raw - lidar_times_raw[f], -MAX_SWEEP_TIME_OFFSET_S, MAX_SWEEP_TIME_OFFSET_S, str(path),
                 "column t (from the sweep's stamp)", int(f), " s")
    intensities = (df["i"].to_numpy(np.float64) / 255.0).clip(0, 1).astype(np.float32)
    sensor_ids = df["d"].to_numpy().astype(np.int16)
    returned = np.ones(len(points), bool)

    extra = root / EXTRAS / "lidar_noreturn" / f"{f:02d}.npz"
    if extra.is_file():
        try:
            with np.load(extra) as z:
                keep = np.isin(z["d"], list(sensors))
                nr_origins = world_from_raw[:3, :3] @ z["origins"][keep].T
                nr_origins = nr_origins.T + world_from_raw[:3, 3]
                nr_dirs = z["directions"][keep] @ world_from_raw[:3, :3].T
                nr_t, nr_d = z["t"][keep], z["d"][keep]
        except (OSError, KeyError, ValueError) as err:
            raise IDSplatError(f"{extra}: unreadable ({err.__class__.__name__}: {err}); regenerate the sequence") from None
        n = len(nr_t)
        origins = np.concatenate([origins, nr_origins])
        directions = np.concatenate([directions, nr_dirs])
        ranges = np.concatenate([ranges, np.zeros(n)])
        intensities = np.concatenate([intensities, np.zeros(n, np.float32)])
        t_raw = np.concatenate([t_raw, nr_t])
        sensor_ids = np.concatenate([sensor_ids, nr_d.astype(np.int16)])
        returned = np.concatenate([returned, np.zeros(n, bool)])
    return LidarSweep(
        frame_index=int(f),
        time=float(lidar_times_raw[f] - time_origin),
        raw_timestamp=float(lidar_times_raw[f]),
        sensor_to_world=world_from_raw @ lidar_poses_raw[f],
        origins=origins,
        directions=directions,
        ranges=ranges,
        intensities=intensities,
        times=t_raw - time_origin,
        returned=returned,
        sensor_ids=sensor_ids,
    )


def _sensor_positions(t_raw, lidar_times_raw, lidar_poses_raw, world_from_raw) -> np.ndarray:
    """Pandar64 position [N, 3] at each time, linear between sweep poses (clamped at the ends)."""
    positions = lidar_poses_raw[:, :3, 3] @ world_from_raw[:3, :3].T + world_from_raw[:3, 3]
    if len(lidar_times_raw) == 1:
        return np.repeat(positions, len(t_raw), 0)
    return np.stack([np.interp(t_raw, lidar_times_raw, positions[:, k]) for k in range(3)], -1)


def _load_tracks(root, frames, lidar_times_raw, world_from_raw, time_origin) -> list[ObjectTrack]:
    folder = root / "annotations" / "cuboids"
    if not folder.is_dir():
        return []
    rows = []
    for f in frames:
        path = folder / f"{f:02d}.pkl.gz"
        if not path.is_file():
            continue
        df = read_pickle(path)
        needed = ["uuid", "label", "yaw", "position.x", "position.y", "position.z", "dimensions.x", "dimensions.y", "dimensions.z"]
        check_columns(df.columns, needed, str(path), "cuboid DataFrame")
        for column in needed[2:]:
            try:
                check_finite(df[column].to_numpy(np.float64), str(path), f"column {column}", int(f))
            except (TypeError, ValueError) as err:
                raise IDSplatError(f"{path}: frame {f}: column {column} is not numeric ({err})") from None
        if "cuboids.sensor_id" in df.columns:
            df = df[df["cuboids.sensor_id"] != 1]  # PandarGT duplicates of boxes in the overlap zone
        df = df.assign(frame=int(f))
        rows.append(df)
    if not rows:
        return []
    table = pd.concat(rows, ignore_index=True)
    tracks = []
    for uuid, group in table.groupby("uuid", sort=True):
        group = group.sort_values("frame").drop_duplicates("frame")
        fidx = group["frame"].to_numpy()
        centres = group[["position.x", "position.y", "position.z"]].to_numpy(np.float64)
        centres = centres @ world_from_raw[:3, :3].T + world_from_raw[:3, 3]
        R = world_from_raw[:3, :3] @ cuboid_yaw_to_rotation(group["yaw"].to_numpy(np.float64))
        poses = make_pose(R, centres)
        size = np.median(group[["dimensions.y", "dimensions.x", "dimensions.z"]].to_numpy(np.float64), axis=0)
        times = lidar_times_raw[fidx] - time_origin
        stationary = group["stationary"].to_numpy(bool) if "stationary" in group.columns else np.zeros(len(group), bool)
        speeds = None
        if len(fidx) > 1:
            step = np.linalg.norm(np.diff(centres, axis=0), axis=1) / np.maximum(np.diff(times), 1e-6)
            speeds = np.concatenate([step[:1], (step[:-1] + step[1:]) / 2, step[-1:]]) if len(step) > 1 else np.repeat(step, 2)
        tracks.append(
            ObjectTrack(
                track_id=str(uuid),
                label=str(group["label"].iloc[0]),
                frame_indices=fidx,
                times=times,
                poses=poses,
                size=size,
                moving=not bool(np.all(stationary)),
                speeds=speeds,
            )
        )
    return tracks
