"""Range checks of every numeric setting of a training run.

tyro only checks types: ``--pipeline.datamanager.dataparser.downscale-factor 0`` parses fine and
ends in a ZeroDivisionError deep in the data loading, a negative learning rate in a ValueError from
torch. :func:`validate_settings` walks the whole config (method, datamanager, dataparser,
preprocessing, model, optimizers) and raises :class:`IDSplatError` with one line naming the option.
Each of the project's settings declares its range beside its field
(:func:`idsplat_ns.ranges.bounded`); nerfstudio's own settings, which cannot, are listed in
:data:`NERFSTUDIO_RULES` by their exact option path. Any other number must be finite and
non-negative (:data:`~idsplat_ns.ranges.NON_NEGATIVE`).
"""

from __future__ import annotations

import dataclasses
from fnmatch import fnmatchcase
from pathlib import Path
from typing import Any, Iterator, Optional

from idsplat_ns.errors import IDSplatError
from idsplat_ns.ranges import ANY, AT_LEAST_ONE, NON_NEGATIVE, POSITIVE, Range, field_range
from idsplat_ns.render.compositor import triton_installed
from idsplat_ns.render.gsplat_backend import gsplat_available


def check_camera_backend(backend: str, device_type: str) -> None:
    """Refuse a camera backend the training device cannot run (``--machine.device-type``)."""
    if backend != "gsplat":
        return

    if device_type != "cuda" or not gsplat_available():
        raise IDSplatError(f"--pipeline.model.camera-backend gsplat needs a CUDA device and the gsplat package "
                           f"(training on {device_type}); use auto or torch")  # fmt: skip


def check_lidar_compositor(compositor: str, device_type: str) -> None:
    """Refuse a lidar compositor the training device cannot run (``--machine.device-type``)."""
    option = "--pipeline.model.lidar.compositor"
    if compositor == "triton" and (device_type != "cuda" or not triton_installed()):
        raise IDSplatError(f"{option} triton needs a CUDA device and Triton (training on {device_type}); use auto or torch")
    if compositor == "compiled" and device_type != "cpu":
        raise IDSplatError(f"{option} compiled runs on the CPU (training on {device_type}); use auto or torch")


NERFSTUDIO_RULES: tuple[tuple[str, Range], ...] = (
    # Optimisers: a zero or negative step size or epsilon is never meant (torch raises on < 0).
    ("optimizers.*.optimizer.lr", POSITIVE),
    ("optimizers.*.optimizer.eps", POSITIVE),
    ("optimizers.*.scheduler.lr_final", POSITIVE),
    ("optimizers.*.scheduler.lr_pre_warmup", POSITIVE),
    ("optimizers.*.scheduler.max_steps", AT_LEAST_ONE),
    # Run length, the machine and the viewer.
    ("max_num_iterations", AT_LEAST_ONE),
    ("machine.num_devices", AT_LEAST_ONE),
    ("machine.num_machines", AT_LEAST_ONE),
    ("machine.seed", ANY),
    ("logging.steps_per_log", AT_LEAST_ONE),
    ("viewer.websocket_port_default", Range(1, 65535, integer=True)),
    ("viewer.jpeg_quality", Range(1, 100, integer=True)),
    ("viewer.camera_frustum_scale", POSITIVE),
    ("viewer.num_rays_per_chunk", AT_LEAST_ONE),
    # The datamanager's and model's base classes.
    ("pipeline.datamanager.camera_res_scale_factor", POSITIVE),
    ("pipeline.datamanager.eval_num_images_to_sample_from", Range(-1, integer=True)),  # -1: all images
    ("pipeline.datamanager.eval_num_times_to_repeat_images", Range(-1, integer=True)),
    ("pipeline.datamanager.fps_reset_every", AT_LEAST_ONE),
    ("pipeline.model.eval_num_rays_per_chunk", AT_LEAST_ONE),
    ("pipeline.model.collider_params.*", ANY),  # unused by a splatting model
)
"""nerfstudio's settings by option path (first match wins); the project's own carry their range."""

# Pairs that must be ordered (low option, high option): each alone is in range, together not.
ORDERED: tuple[tuple[str, str], ...] = (
    ("pipeline.datamanager.dataparser.start_frame", "pipeline.datamanager.dataparser.end_frame"),
    ("pipeline.model.mcmc.refine_start_iter", "pipeline.model.mcmc.refine_stop_iter"),
    ("pipeline.model.lidar.near_plane", "pipeline.model.lidar.far_plane"),
    ("pipeline.datamanager.preprocess.masks.lidar_motion.min_height", "pipeline.datamanager.preprocess.masks.lidar_motion.max_height"),
)


DATAPARSER = "pipeline.datamanager.dataparser."


def option_name(path: str, config: Any = None) -> str:
    """The command-line spelling of a config path (tyro turns underscores into dashes)."""
    if path.startswith(DATAPARSER):
        parser = _get(config, DATAPARSER[:-1]) if config is not None else None
        # The dataparser is a tyro subcommand: its options are spelled after its name, bare.
        subcommand = getattr(type(parser), "subcommand", "the dataparser subcommand")
        return f"{subcommand} --{path[len(DATAPARSER):].replace('_', '-')}"
    return "--" + path.replace("_", "-")


def numeric_settings(config: Any, prefix: str = "",
                     declared: Optional[Range] = None) -> Iterator[tuple[str, float, Optional[Range]]]:
    """(dotted path, value, the range declared beside its field or None) of every number in a
    nested config, tuples element by element."""
    if dataclasses.is_dataclass(config) and not isinstance(config, type):
        for f in dataclasses.fields(config):
            if not f.name.startswith("_"):
                yield from numeric_settings(getattr(config, f.name), f"{prefix}{f.name}.", field_range(f))
    elif isinstance(config, dict):
        for key, value in config.items():
            yield from numeric_settings(value, f"{prefix}{key}.")
    elif isinstance(config, (tuple, list)):
        for value in config:
            if isinstance(value, (int, float)) and not isinstance(value, bool):
                yield prefix[:-1], value, declared
    elif isinstance(config, (int, float)) and not isinstance(config, bool):
        yield prefix[:-1], config, declared


def rule_for(path: str, declared: Optional[Range] = None) -> Range:
    """The check of the setting at ``path``: its field's, else nerfstudio's rule, else non-negative."""
    if declared is not None:
        return declared
    return next((check for pattern, check in NERFSTUDIO_RULES if fnmatchcase(path, pattern)), NON_NEGATIVE)


def validate_settings(config: Any) -> None:
    """Raise :class:`IDSplatError` (one line naming the option) for the first setting out of range."""
    values: dict[str, float] = {}
    for path, value, declared in numeric_settings(config):
        check = rule_for(path, declared)
        if not check.ok(float(value)):
            raise IDSplatError(f"{option_name(path, config)} {value}: must be {check.text()}; fix the option")
        values.setdefault(path, value)
    for low, high in ORDERED:
        if low in values and high in values and not values[low] < values[high]:
            raise IDSplatError(
                f"{option_name(low, config)} {values[low]} must be below {option_name(high, config)} {values[high]}; fix one of them"
            )
    schedule = _get(config, "pipeline.model.resolution_schedule")
    if schedule is not None and list(schedule) != sorted(schedule):
        raise IDSplatError(f"{option_name('pipeline.model.resolution_schedule')} {tuple(schedule)}: steps must increase")
    tracks = _get(config, "pipeline.datamanager.import_tracks")
    if tracks is not None and not Path(tracks).is_file():
        raise IDSplatError(f"{option_name('pipeline.datamanager.import_tracks')} {tracks}: no such file")


def _get(config: Any, path: str) -> Any:
    for part in path.split("."):
        config = getattr(config, part, None)
        if config is None:
            return None
    return config
