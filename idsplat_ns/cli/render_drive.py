"""``idsplat-render-drive``: a video of the recorded drive re-rendered from a trained run.

One camera of the rig is rendered at every recorded image of that camera (training and held-out
images together, in time order), each at its own pose and time, so that moving instances are
where the trained trajectories put them. ``--shift-left`` / ``--shift-up`` move the camera in its
own frame for a novel-view drive (a lane change of the ego); ``--with-ground-truth`` stacks the
recorded image above the render where the camera was not moved. The video goes through mediapy
and the ffmpeg of :mod:`idsplat_ns._compat.ffmpeg`; an output path without ``.mp4`` gets PNG frames.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import torch

from idsplat_ns._compat.ffmpeg import ensure_ffmpeg_on_path
from idsplat_ns.atomic import check_writable
from idsplat_ns.cli.command_failures import explain_checkpoint_load
from idsplat_ns.errors import IDSplatError, run_cli
from idsplat_ns.runs.run_folder import check_run


def shifted_camera_to_world(
    c2w: np.ndarray,  # [3, 4] nerfstudio camera-to-world (OpenGL axes: x right, y up, z back)
    left: float,
    up: float,
) -> np.ndarray:  # -> [3, 4]
    """The same camera moved ``left`` metres to its left and ``up`` metres up, in its own frame."""
    out = np.array(c2w, dtype=np.float64, copy=True)
    out[:, 3] += -left * out[:, 0] + up * out[:, 1]
    return out


def drive_order(camera_idx: np.ndarray, times: np.ndarray, camera: int) -> np.ndarray:
    """Indices of the images of ``camera`` ([N] sensor index per image) in time order ([N] seconds)."""
    mine = np.flatnonzero(np.asarray(camera_idx).reshape(-1) == camera)
    return mine[np.argsort(np.asarray(times, dtype=np.float64).reshape(-1)[mine], kind="stable")]


def recorded_frame_rate(times: np.ndarray) -> float:
    """Frames per second of a recording from its image times [N] (median spacing; 10 if unknown)."""
    gaps = np.diff(np.sort(np.asarray(times, dtype=np.float64)))
    gaps = gaps[gaps > 1e-6]
    return float(1.0 / np.median(gaps)) if gaps.size else 10.0


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(
        prog="idsplat-render-drive",
        description="Render the recorded drive of one camera from a trained run (moving instances on their "
                    "trained trajectories) as an mp4 video or PNG frames.")
    parser.add_argument("--load-config", type=Path, required=True, help="config.yml of a trained (or edited) run")
    parser.add_argument("--output", type=Path, required=True,
                        help="a .mp4 file, or a folder for PNG frames (any other path)")
    parser.add_argument("--camera", default=None, help="camera name (default: the first camera of the rig)")
    parser.add_argument("--shift-left", type=float, default=0.0, help="move the camera this many metres to its left")
    parser.add_argument("--shift-up", type=float, default=0.0, help="move the camera this many metres up")
    parser.add_argument("--downscale", type=int, default=1, help="render at 1/N of the image resolution")
    parser.add_argument("--fps", type=float, default=None, help="frame rate of the video (default: the recording's)")
    parser.add_argument("--with-ground-truth", action="store_true",
                        help="stack the recorded image above each render (only without a shift)")
    parser.add_argument("--max-frames", type=int, default=None, help="render only the first N images of the drive")
    return parser.parse_args(argv)


def _check_args(args: argparse.Namespace) -> None:
    if args.downscale < 1:
        raise IDSplatError(f"--downscale must be 1 or more, got {args.downscale}")
    if args.fps is not None and args.fps <= 0:
        raise IDSplatError(f"--fps must be positive, got {args.fps}")
    if args.max_frames is not None and args.max_frames < 1:
        raise IDSplatError(f"--max-frames must be 1 or more, got {args.max_frames}")
    if args.with_ground_truth and (args.shift_left or args.shift_up):
        raise IDSplatError("--with-ground-truth needs the recorded viewpoint: drop --shift-left/--shift-up")
    if not args.load_config.is_file():
        raise IDSplatError(f"--load-config {args.load_config}: no such file; give a run's config.yml")
    check_writable(args.output, "--output", folder=args.output.suffix.lower() != ".mp4")


def _datasets(pipeline) -> list:
    dm = pipeline.datamanager
    return [ds for ds in (dm.train_dataset, getattr(dm, "eval_dataset", None)) if ds is not None]


def render_drive(pipeline, camera_name: str | None, shift: tuple[float, float], downscale: int,
                 with_ground_truth: bool, max_frames: int | None, progress=None) -> tuple[list[np.ndarray], float]:
    """Frames [H, W, 3] uint8 of the drive of ``camera_name`` and the recording's frame rate
    (``pipeline`` as ``eval_setup`` returns it, in eval mode)."""
    names = list(pipeline.model.camera_names)
    name = camera_name if camera_name is not None else names[0]
    if name not in names:
        raise IDSplatError(f"--camera {name}: not a camera of this run; it has {', '.join(names)}")
    entries = []  # (time, dataset, image index)
    for ds in _datasets(pipeline):
        meta = ds.cameras.metadata
        order = drive_order(meta["sensor_idx"].numpy(), meta["time_seconds"].numpy(), names.index(name))
        entries += [(float(meta["time_seconds"][i, 0]), ds, int(i)) for i in order]
    entries.sort(key=lambda e: e[0])
    if not entries:
        raise IDSplatError(f"--camera {name}: the run has no images of this camera")
    rate = recorded_frame_rate(np.array([e[0] for e in entries]))
    entries = entries[:max_frames] if max_frames is not None else entries
    frames = []
    for time, ds, i in entries:
        camera = ds.cameras[i : i + 1]
        if shift != (0.0, 0.0):
            c2w = shifted_camera_to_world(camera.camera_to_worlds[0].double().numpy(), *shift)
            camera.camera_to_worlds = torch.as_tensor(c2w, dtype=camera.camera_to_worlds.dtype)[None]
        if downscale > 1:
            camera.rescale_output_resolution(1.0 / downscale)
        with torch.no_grad():
            rgb = pipeline.model.get_outputs_for_camera(camera)["rgb"]
        frame = (rgb.clamp(0, 1).cpu().numpy() * 255).round().astype(np.uint8)
        if with_ground_truth:
            gt = ds.get_image_float32(i).numpy()
            gt = (torch.nn.functional.interpolate(torch.as_tensor(gt).permute(2, 0, 1)[None, :3], size=frame.shape[:2],
                                                  mode="area")[0].permute(1, 2, 0).numpy() * 255).round().astype(np.uint8)
            frame = np.concatenate([gt, frame], 0)
        frames.append(frame)
        if progress is not None:
            progress()
    return frames, rate


def write_frames(frames: list[np.ndarray], output: Path, fps: float) -> Path:
    """An mp4 (H.264 through ffmpeg) for a ``.mp4`` path, else numbered PNGs in the folder ``output``."""
    if output.suffix.lower() == ".mp4":
        import mediapy

        ensure_ffmpeg_on_path()
        output.parent.mkdir(parents=True, exist_ok=True)
        # H.264 wants even sizes: pad by one black row/column where needed.
        h, w = frames[0].shape[:2]
        frames = [np.pad(f, ((0, h % 2), (0, w % 2), (0, 0))) for f in frames]
        tmp = output.with_name(f".{output.stem}.tmp.mp4")
        mediapy.write_video(tmp, frames, fps=fps)
        tmp.replace(output)
        return output
    from PIL import Image

    output.mkdir(parents=True, exist_ok=True)
    for k, frame in enumerate(frames):
        Image.fromarray(frame).save(output / f"frame_{k:05d}.png")
    return output


def run(args: argparse.Namespace) -> Path:
    _check_args(args)
    from nerfstudio.utils.eval_utils import eval_setup

    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    check_run(args.load_config)  # another method's run, no checkpoint: one line before the pipeline is built
    try:
        _, pipeline, _, _ = eval_setup(args.load_config, test_mode="test")
    except Exception as err:  # noqa: BLE001 - a checkpoint that does not load, in nerfstudio's loader
        line = explain_checkpoint_load(type(err), err, err.__traceback__)
        if line is None:
            raise
        raise IDSplatError(line) from None
    with Progress(TextColumn("[progress.description]{task.description}"), BarColumn(), MofNCompleteColumn(),
                  TimeElapsedColumn(), transient=True) as bar:
        task = bar.add_task("[green]Rendering the drive...", total=None)
        frames, rate = render_drive(pipeline, args.camera, (args.shift_left, args.shift_up), args.downscale,
                                    args.with_ground_truth, args.max_frames, lambda: bar.advance(task))
    out = write_frames(frames, args.output, args.fps or rate)
    print(f"wrote {out} ({len(frames)} frames, {args.fps or rate:.1f} fps)")
    return out


def main(argv: list[str] | None = None) -> None:
    args = parse_args(argv)
    run_cli(lambda: run(args))


if __name__ == "__main__":
    main()
