"""Generate a synthetic sequence on disk: `generate_sequence(out_dir, preset, seed)`.

Frames are independent (each has its own random stream derived from (seed, frame)), so they can
be rendered by several processes and the result is the same byte for byte.
"""

from __future__ import annotations

import concurrent.futures as cf
import json
import multiprocessing
import os
import shutil
import uuid
from pathlib import Path
from typing import Optional

import numpy as np
from tqdm import tqdm

from idsplat_ns.data.camera import RollingShutter
from idsplat_ns.data.synthetic import writer
from idsplat_ns.data.synthetic.camera_render import render_camera
from idsplat_ns.data.synthetic.config import (
    MISCALIBRATED_CAMERA,
    SyntheticConfig,
    calibration_error,
    camera_names,
    config_to_dict,
    exposure_gain,
    pose_noise,
    get_preset,
)
from idsplat_ns.data.synthetic.lidar_sim import simulate_sweep
from idsplat_ns.data.synthetic.raycast import RayCaster
from idsplat_ns.data.synthetic.rig import cameras, lidar_pose
from idsplat_ns.data.synthetic.world import World, build_world
from idsplat_ns.data.images import write_instance_map
from idsplat_ns.errors import IDSplatError

GENERATOR_NAME = "idsplat_ns.data.synthetic"
GENERATOR_VERSION = 3
"""Bump when the output for a given (config, seed) changes, so that caches are remade.
2: pedestrians and cyclists (`num_pedestrians`, `num_cyclists`).
3: each road user's `name` in `instances.json` (its manoeuvre); traffic drawn per seed (`traffic`)."""


def sequence_name(config: SyntheticConfig, seed: int) -> str:
    """Folder name of the sequence for (config, seed)."""
    return f"synth_{config.name}_{seed}"


ROLLING_SHUTTER_FILE = "rolling_shutter.json"
"""In `idsplat_extras/`: each camera's rolling-shutter readout, written only when it is not global."""


def rolling_shutter_of(config: SyntheticConfig) -> Optional[RollingShutter]:
    """The cameras' rolling shutter (all three share it); None for a global shutter."""
    rig = config.cameras
    if rig.rolling_shutter_seconds <= 0:
        return None
    return RollingShutter(readout_seconds=rig.rolling_shutter_seconds, direction=rig.rolling_shutter_direction)


def generator_record(config: SyntheticConfig, seed: int) -> dict:
    """Contents of `idsplat_extras/generator.json`: what made the sequence and its conventions."""
    camera_time = "frame time + fixed per-camera offset, global shutter"
    if rolling_shutter_of(config) is not None:
        camera_time = ("frame time + fixed per-camera offset = mid-exposure of the centre line; rolling shutter, "
                       f"each line at its own time (idsplat_extras/{ROLLING_SHUTTER_FILE})")
    return {
        "generator": GENERATOR_NAME,
        "version": GENERATOR_VERSION,
        "preset": config.name,
        "seed": seed,
        "config": config_to_dict(config),
        "conventions": {
            "camera_pose": "camera-to-world, OpenCV axes (x right, y down, z forward)",
            "lidar_pose": "lidar-to-world at the sweep time, axes x right, y forward, z up",
            "lidar_sweep": "one rotation over [t - period/2, t + period/2), azimuth counter-clockwise from the "
            "sensor's right, starting behind; per-point t",
            "camera_time": camera_time,
            "pixel_centres": "pixel (i, j) is the ray through (i + 0.5, j + 0.5)",
            "cuboid_time": "cuboids are at the lidar sweep time (lidar/timestamps.json)",
        },
    }


def _frame_rng(seed: int, frame: int) -> np.random.Generator:
    return np.random.default_rng(np.random.SeedSequence([seed, frame, 0x11DA]))


def road_user_cuboids(world: World, t: float) -> list[dict]:
    """Devkit cuboid rows of the vehicles and people within lidar range of the ego at local time `t`.

    A box stands on the ground under its object (the sidewalk for pedestrians on it) and holds the
    whole body, swinging limbs included.
    """
    rows = []
    ego_xy, _ = world.ego.pose(np.array([t]))
    world_yaw = np.radians(world.config.world_yaw_deg)
    for obj in world.road_users:
        xy, heading = obj.trajectory.pose(np.array([t]))
        if np.linalg.norm(xy[0] - ego_xy[0]) > world.config.lidar.max_range:
            continue
        width, length, height = obj.dimensions
        base = obj.trajectory.height(np.array([t]))[0]
        centre = world.points_to_world(np.array([[xy[0, 0], xy[0, 1], base + height / 2]]))[0]
        # PandaSet yaw: 0 = length axis along world +y, counter-clockwise.
        yaw = float(np.mod(heading[0] + world_yaw - np.pi / 2 + np.pi, 2 * np.pi) - np.pi)
        rows.append(
            {
                "uuid": obj.uuid,
                "label": obj.label,
                "yaw": yaw,
                "stationary": not obj.moving,
                "camera_used": -1,
                "position.x": centre[0],
                "position.y": centre[1],
                "position.z": centre[2],
                "dimensions.x": width,
                "dimensions.y": length,
                "dimensions.z": height,
                "attributes.object_motion": "Moving" if obj.moving else "Parked",
                "cuboids.sibling_id": "-",
                "cuboids.sensor_id": -1,
                "attributes.rider_status": obj.attributes.get("attributes.rider_status", np.nan),
                "attributes.pedestrian_behavior": obj.attributes.get("attributes.pedestrian_behavior", np.nan),
                "attributes.pedestrian_age": obj.attributes.get("attributes.pedestrian_age", np.nan),
            }
        )
    return rows


# -- per-process state (a worker builds its own world once) ---------------------------------------
_STATE: dict = {}


def _frame_state(config: SyntheticConfig, seed: int, tmp: str) -> dict:
    """What rendering a frame reads: the world, its ray caster, the cameras, the folder, the seed."""
    world = build_world(config, seed)
    return dict(world=world, caster=RayCaster(world), cameras=cameras(config), tmp=Path(tmp), seed=seed)


def _init_worker(config: SyntheticConfig, seed: int, tmp: str) -> None:
    _STATE.update(_frame_state(config, seed, tmp))


def _make_frame(k: int, state: Optional[dict] = None) -> dict:
    """Render and write frame `k` (with ``state``, else the worker process's); returns its poses
    and time stamps. In-process generation passes its own state: threads share ``_STATE``."""
    state = _STATE if state is None else state
    world, caster, tmp, seed = state["world"], state["caster"], state["tmp"], state["seed"]
    cfg = world.config
    name = f"{k:02d}"
    t = k / cfg.frame_rate  # local clock: 0 at frame 0
    out: dict = {"cameras": {}}
    for c, cam in enumerate(state["cameras"]):
        t_img = t + cam.time_offset
        image, instance, _ = render_camera(caster, cam, t_img, cfg.cameras.supersample, cfg.cameras.shadows,
                                           rolling_shutter_of(cfg))
        if cfg.cameras.exposure_drift:
            gain = exposure_gain(cfg.cameras, c, t_img, cfg.num_frames / cfg.frame_rate)
            image = np.clip(np.round(image.astype(np.float64) * gain), 0, 255).astype(np.uint8)
        writer.write_jpeg(tmp / "camera" / cam.name / f"{name}.jpg", image, cfg.cameras.jpeg_quality)
        write_instance_map(tmp / "idsplat_extras" / "instance_masks" / cam.name / f"{name}.png", instance)
        rot, pos = cam.pose(world, t_img)
        if c == MISCALIBRATED_CAMERA and any(cfg.cameras.calibration_error_deg):
            rot = rot @ calibration_error(cfg.cameras)  # written wrong, rendered right
        if any(cfg.cameras.pose_noise):  # the ego's pose error, in the ego frame: written wrong too
            ego_rot, ego_pos = (a[0] for a in world.ego_pose(np.array([t_img])))
            noise_rot, noise_t = pose_noise(cfg.cameras, t_img, cfg.num_frames / cfg.frame_rate)
            pos = ego_rot @ (noise_rot @ (ego_rot.T @ (pos - ego_pos)) + noise_t) + ego_pos
            rot = ego_rot @ noise_rot @ ego_rot.T @ rot
        out["cameras"][cam.name] = (
            writer.pose_dict(world.local_to_world_rotation @ rot, world.points_to_world(pos[None])[0]),
            cfg.start_time + t_img,
        )
    sweep = simulate_sweep(caster, t, _frame_rng(seed, k))
    df = writer.lidar_frame(world.points_to_world(sweep.points), sweep.intensity, cfg.start_time + sweep.times)
    writer.write_pickle_gz(tmp / "lidar" / f"{name}.pkl.gz", df)
    writer.write_npz(
        tmp / "idsplat_extras" / "lidar_noreturn" / f"{name}.npz",
        origins=world.points_to_world(sweep.miss_origins),
        directions=world.directions_to_world(sweep.miss_directions),
        t=cfg.start_time + sweep.miss_times,
        d=np.zeros(len(sweep.miss_times), dtype=np.int64),
    )
    rot, pos = lidar_pose(world, np.array([t]))
    out["lidar"] = writer.pose_dict(world.local_to_world_rotation @ rot[0], world.points_to_world(pos)[0])
    writer.write_pickle_gz(
        tmp / "annotations" / "cuboids" / f"{name}.pkl.gz", writer.cuboid_frame(road_user_cuboids(world, t))
    )
    out["time"] = cfg.start_time + t
    out["gps"] = _gps(world, t)
    return out


def _gps(world: World, t: float) -> dict:
    """Approximate GPS record of the ego (lat/long from the world offset, velocity in world axes)."""
    _, pos = world.ego_pose(np.array([t]))
    p = world.points_to_world(pos)[0]
    lat0, long0 = 37.7749, -122.4194  # where the local origin is put
    d = p - world.local_to_world_offset
    lat = lat0 + d[1] / 111_320.0
    vel = world.directions_to_world(
        np.array([[np.cos(world.ego.heading), np.sin(world.ego.heading), 0.0]]) * world.ego.speed
    )[0]
    return {
        "lat": lat,
        "long": long0 + d[0] / (111_320.0 * np.cos(np.radians(lat0))),
        "height": float(p[2]),
        "xvel": float(vel[0]),
        "yvel": float(vel[1]),
    }


def _make_folders(tmp: Path, config: SyntheticConfig) -> None:
    for cam in camera_names(config.cameras):
        (tmp / "camera" / cam).mkdir(parents=True)
        (tmp / "idsplat_extras" / "instance_masks" / cam).mkdir(parents=True)
    for sub in ("lidar", "annotations/cuboids", "meta", "idsplat_extras/lidar_noreturn"):
        (tmp / sub).mkdir(parents=True, exist_ok=True)


def _record_matches(record_path: Path, record: dict) -> bool:
    try:
        return json.loads(record_path.read_text()) == json.loads(json.dumps(record))
    except (OSError, ValueError):
        return False


def is_current(out_dir: Path, preset: str | SyntheticConfig = "small", seed: int = 0) -> bool:
    """Whether ``out_dir`` holds this preset/seed made by this generator version and settings."""
    config = get_preset(preset)
    final = Path(out_dir) / sequence_name(config, seed)
    return _record_matches(final / "idsplat_extras" / "generator.json", generator_record(config, seed))


def generate_sequence(
    out_dir: Path | str,
    preset: str | SyntheticConfig = "small",
    seed: int = 0,
    *,
    overwrite: bool = False,
    workers: int | None = None,
    progress: bool = True,
) -> Path:
    """Write the synthetic street for `preset` and `seed` under `out_dir`; returns the sequence folder.

    The folder is `out_dir/synth_<preset>_<seed>` in the PandaSet layout plus `idsplat_extras/`.
    It is written to a temporary sibling and renamed when complete. If it already exists and was
    made by the same generator version, preset configuration and seed, it is returned as is;
    otherwise `overwrite=True` is needed. `workers` > 1 renders frames in that many processes
    (default: up to 2 for sequences of 20 frames or more, where it pays for the process start-up).
    """
    config = get_preset(preset)
    if workers is None:
        workers = min(2, os.cpu_count() or 1) if config.num_frames >= 20 else 1
    out_dir = Path(out_dir)
    writer.check_writable(out_dir)
    final = out_dir / sequence_name(config, seed)
    record = generator_record(config, seed)
    record_path = final / "idsplat_extras" / "generator.json"
    if final.exists() and not overwrite:
        if _record_matches(record_path, record):
            return final
        raise IDSplatError(f"{final} exists and was not made with these settings; remove it or pass --overwrite")
    # Unique per call: two threads of one process may generate the same street at once.
    tmp = out_dir / f".{final.name}.tmp-{os.getpid()}-{uuid.uuid4().hex[:8]}"
    _make_folders(tmp, config)
    try:
        frames = _render_frames(config, seed, tmp, workers, progress)
        _write_sequence_files(config, seed, tmp, frames, record)
        writer.replace_folder_atomically(tmp, final)
    finally:
        if tmp.exists():
            shutil.rmtree(tmp)
    return final


def _render_frames(config: SyntheticConfig, seed: int, tmp: Path, workers: int, progress: bool) -> list[dict]:
    bar = tqdm(total=config.num_frames, desc=f"synthetic {config.name}", unit="frame", disable=not progress)
    try:
        if workers <= 1:
            state = _frame_state(config, seed, str(tmp))
            frames = []
            for k in range(config.num_frames):
                frames.append(_make_frame(k, state))
                bar.update()
            return frames
        ctx = multiprocessing.get_context("spawn")  # safe under torch and threads
        with cf.ProcessPoolExecutor(workers, mp_context=ctx, initializer=_init_worker,
                                    initargs=(config, seed, str(tmp))) as pool:
            frames = []
            for frame in pool.map(_make_frame, range(config.num_frames)):
                frames.append(frame)
                bar.update()
            return frames
    finally:
        bar.close()


def _write_sequence_files(config: SyntheticConfig, seed: int, tmp: Path, frames: list[dict], record: dict) -> None:
    """Per-sequence JSON files: intrinsics, poses, time stamps, GPS, instances, generator record."""
    world = build_world(config, seed)
    for cam in cameras(config):
        folder = tmp / "camera" / cam.name
        writer.write_json(folder / "intrinsics.json", {"fx": cam.fx, "fy": cam.fy, "cx": cam.cx, "cy": cam.cy})
        writer.write_json(folder / "poses.json", [f["cameras"][cam.name][0] for f in frames])
        writer.write_json(folder / "timestamps.json", [f["cameras"][cam.name][1] for f in frames])
    writer.write_json(tmp / "lidar" / "poses.json", [f["lidar"] for f in frames])
    writer.write_json(tmp / "lidar" / "timestamps.json", [f["time"] for f in frames])
    writer.write_json(tmp / "meta" / "timestamps.json", [f["time"] for f in frames])
    writer.write_json(tmp / "meta" / "gps.json", [f["gps"] for f in frames])
    instances = {
        str(v.instance_id): {"uuid": v.uuid, "label": v.label, "moving": v.moving, "name": v.name}
        for v in world.road_users
    }
    writer.write_json(tmp / "idsplat_extras" / "instances.json", instances)
    shutter = rolling_shutter_of(config)
    if shutter is not None:
        writer.write_json(tmp / "idsplat_extras" / ROLLING_SHUTTER_FILE, {
            cam.name: {"readout_seconds": shutter.readout_seconds, "direction": shutter.direction}
            for cam in cameras(config)
        })
    writer.write_json(tmp / "idsplat_extras" / "generator.json", record)


__all__ = ["generate_sequence", "is_current", "sequence_name", "road_user_cuboids", "GENERATOR_VERSION"]
