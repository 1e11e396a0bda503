"""`idsplat-synth`: write the built-in synthetic street in the PandaSet layout."""

from __future__ import annotations

import argparse
import dataclasses
import time
from pathlib import Path

from idsplat_ns.data.synthetic.config import (
    PRESETS, ROLLING_SHUTTER_DIRECTIONS, TRAFFIC_KINDS, SyntheticConfig, get_preset,
)  # fmt: skip
from idsplat_ns.data.synthetic.generate import generate_sequence
from idsplat_ns.errors import run_cli


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="idsplat-synth",
        description="Render the built-in synthetic driving street (3 cameras, 64-beam lidar, ground truth) "
        "in the PandaSet on-disk layout.",
    )
    p.add_argument("--preset", choices=sorted(PRESETS), default="small", help="size of the sequence (default: small)")
    p.add_argument("--out", type=Path, required=True, help="folder that receives synth_<preset>_<seed>/")
    p.add_argument("--seed", type=int, default=0, help="random seed of the street layout and sensor noise")
    p.add_argument("--overwrite", action="store_true", help="replace an existing sequence made with other settings")
    p.add_argument(
        "--workers", type=int, default=None, help="processes rendering frames (default: 2 for 20+ frames, else 1)"
    )
    p.add_argument(
        "--pedestrians", type=int, default=None,
        help="walking pedestrians, the first crossing the road (default: the preset's; tiny 0, small 3, bench 4)",
    )
    p.add_argument(
        "--cyclists", type=int, default=None, help="cyclists in the lanes (default: the preset's; tiny 0, small 1, bench 2)"
    )
    p.add_argument(
        "--rolling-shutter-ms", type=float, default=0.0,
        help="rolling-shutter readout of the cameras, first to last line, milliseconds (default 0: global shutter)",
    )
    p.add_argument(
        "--rolling-shutter-direction", choices=ROLLING_SHUTTER_DIRECTIONS, default="top_to_bottom",
        help="readout direction of the rolling shutter (default: top_to_bottom)",
    )
    p.add_argument(
        "--exposure-drift", type=float, default=0.0,
        help="auto-exposure drift: each image scaled by 1 + DRIFT * sin(...), once up and down over the drive, "
             "its own phase per camera (default 0: none; 0.3: gains 0.7-1.3)",
    )
    p.add_argument(
        "--calibration-error-deg", type=float, nargs=2, default=(0.0, 0.0), metavar=("YAW", "PITCH"),
        help="write the front-left camera's pose turned by YAW about its vertical and PITCH about its horizontal "
             "axis, degrees, in every frame, while rendering it from the true pose (default 0 0: a perfect rig)",
    )
    p.add_argument(
        "--pose-noise", type=float, nargs=2, default=(0.0, 0.0), metavar=("DEGREES", "METRES"),
        help="write every camera pose of a frame with one ego-pose error that wanders smoothly over the drive, up "
             "to DEGREES about and METRES along each ego axis, while rendering from the true poses; the lidar's "
             "poses stay exact (default 0 0: exact poses)",
    )
    p.add_argument(
        "--traffic", choices=TRAFFIC_KINDS, default=None,
        help="moving vehicles: fixed (the same five manoeuvres on every seed), varied (0-15 drawn per seed) or "
             "hard (close passes, long vehicles, completed turns, cut-in, stop-and-go, U-turn); default: the "
             "preset's (varied and hard presets; fixed otherwise)",
    )  # fmt: skip
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    return p


_DIRECTION_CODES = {"top_to_bottom": "", "bottom_to_top": "bt", "left_to_right": "lr", "right_to_left": "rl"}


def config_from_args(preset: str, pedestrians: int | None, cyclists: int | None, rolling_shutter_ms: float = 0.0,
                     rolling_shutter_direction: str = "top_to_bottom", traffic: str | None = None,
                     exposure_drift: float = 0.0, calibration_error_deg: tuple = (0.0, 0.0),
                     pose_noise: tuple = (0.0, 0.0)) -> SyntheticConfig:
    """The preset, with the counts of people, the rolling shutter, the rig's defects (exposure drift,
    calibration error, pose noise) and the traffic replaced where given; a changed preset gets its own
    name (`small_p5c0`, `small_rs40`, `small_rs40lr`, `small_ex0.3`, `small_cal1x0.5`,
    `small_pn0.5x0.1`, `bench_hard`), so that its folder does not collide with the preset's."""
    config = get_preset(preset)
    if traffic is not None and traffic != config.traffic:
        config = dataclasses.replace(config, name=f"{config.name}_{traffic}", traffic=traffic)
    counts = {
        "num_pedestrians": config.num_pedestrians if pedestrians is None else pedestrians,
        "num_cyclists": config.num_cyclists if cyclists is None else cyclists,
    }
    name = config.name
    if counts["num_pedestrians"] != config.num_pedestrians or counts["num_cyclists"] != config.num_cyclists:
        name = f"{name}_p{counts['num_pedestrians']}c{counts['num_cyclists']}"
    cameras = config.cameras
    if rolling_shutter_ms != 0:
        cameras = dataclasses.replace(cameras, rolling_shutter_seconds=rolling_shutter_ms / 1e3,
                                      rolling_shutter_direction=rolling_shutter_direction)
        name = f"{name}_rs{rolling_shutter_ms:g}{_DIRECTION_CODES.get(rolling_shutter_direction, '')}"
    if exposure_drift != 0:
        cameras = dataclasses.replace(cameras, exposure_drift=exposure_drift)
        name = f"{name}_ex{exposure_drift:g}"
    if any(calibration_error_deg):
        cameras = dataclasses.replace(cameras, calibration_error_deg=tuple(float(v) for v in calibration_error_deg))
        name = f"{name}_cal{calibration_error_deg[0]:g}x{calibration_error_deg[1]:g}"
    if any(pose_noise):
        cameras = dataclasses.replace(cameras, pose_noise=tuple(float(v) for v in pose_noise))
        name = f"{name}_pn{pose_noise[0]:g}x{pose_noise[1]:g}"
    if name == config.name:
        return get_preset(config)
    return get_preset(dataclasses.replace(config, name=name, cameras=cameras, **counts))


def _main() -> None:
    args = _parser().parse_args()
    start = time.perf_counter()
    config = config_from_args(args.preset, args.pedestrians, args.cyclists, args.rolling_shutter_ms,
                              args.rolling_shutter_direction, args.traffic, args.exposure_drift, args.calibration_error_deg,
                              args.pose_noise)
    path = generate_sequence(
        args.out, config, args.seed, overwrite=args.overwrite, workers=args.workers, progress=not args.quiet
    )
    print(f"wrote {path} in {time.perf_counter() - start:.1f} s")


def main() -> None:
    """Console entry point (errors from bad options end in one line)."""
    run_cli(_main)


if __name__ == "__main__":
    main()
