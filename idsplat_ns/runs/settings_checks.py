"""Range checks of every numeric setting of a training run, from one table.

tyro only checks types: ``--pipeline.datamanager.dataparser.downscale-factor 0`` parses fine and
ends in a ZeroDivisionError deep in the data loading, a negative learning rate in a ValueError from
torch. :func:`validate_settings` walks the whole config (method, datamanager, dataparser,
preprocessing, model, optimizers), matches each numeric value's option path against
:data:`RULES` (first match wins) and raises :class:`IDSplatError` with one line naming the option.
A value that no rule names must be finite and non-negative: no count, size, rate, weight or
threshold of this project is meaningfully negative, and the few that are get their own rule.
"""

from __future__ import annotations

import dataclasses
import math
from fnmatch import fnmatchcase
from pathlib import Path
from typing import Any, Iterator, Optional

from idsplat_ns.errors import IDSplatError
from idsplat_ns.render.compositor import triton_installed
from idsplat_ns.render.gsplat_backend import gsplat_available


@dataclasses.dataclass(frozen=True)
class Range:
    """An interval check; ``None`` is an open end. ``integer`` requires a whole number."""

    low: Optional[float] = None
    high: Optional[float] = None
    low_open: bool = False
    high_open: bool = False
    integer: bool = False

    def ok(self, v: float) -> bool:
        if not math.isfinite(v) or (self.integer and v != int(v)):
            return False
        if self.low is not None and (v <= self.low if self.low_open else v < self.low):
            return False
        return not (self.high is not None and (v >= self.high if self.high_open else v > self.high))

    def text(self) -> str:
        lo = "-inf" if self.low is None else f"{self.low:g}"
        hi = "inf" if self.high is None else f"{self.high:g}"
        kind = "a whole number" if self.integer else "a number"
        return f"{kind} in {'(' if self.low_open or self.low is None else '['}{lo}, {hi}{')' if self.high_open or self.high is None else ']'}"


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


POSITIVE = Range(0, low_open=True)
NON_NEGATIVE = Range(0)
AT_LEAST_ONE = Range(1, integer=True)
UNIT = Range(0, 1)
FRACTION = Range(0, 1, low_open=True)
ANY = Range()

RULES: tuple[tuple[str, Range], ...] = (
    # Optimisers: a zero or negative step size or epsilon is never meant (torch raises on < 0).
    ("optimizers.*.optimizer.lr", POSITIVE),
    ("optimizers.*.optimizer.eps", POSITIVE),
    ("optimizers.*.scheduler.lr_final", POSITIVE),
    ("optimizers.*.scheduler.lr_pre_warmup", POSITIVE),
    ("optimizers.*.scheduler.max_steps", AT_LEAST_ONE),
    # Run length and the machine.
    ("max_num_iterations", AT_LEAST_ONE),
    ("machine.num_devices", AT_LEAST_ONE),
    ("machine.num_machines", AT_LEAST_ONE),
    ("logging.steps_per_log", AT_LEAST_ONE),
    ("viewer.websocket_port_default", Range(1, 65535, integer=True)),
    ("viewer.jpeg_quality", Range(1, 100, integer=True)),
    ("viewer.camera_frustum_scale", POSITIVE),
    ("*num_rays_per_chunk", AT_LEAST_ONE),
    # Data selection: divisors and fractions.
    ("*.downscale_factor", POSITIVE),
    ("*.camera_res_scale_factor", POSITIVE),
    ("*.train_fraction", FRACTION),
    ("*.eval_every", Range(2, integer=True)),
    ("*.start_frame", Range(0, integer=True)),
    ("*.end_frame", AT_LEAST_ONE),
    ("*.eval_num_images_to_sample_from", Range(-1, integer=True)),  # -1: all images (nerfstudio)
    ("*.eval_num_times_to_repeat_images", Range(-1, integer=True)),
    ("*.lidar_sensors", Range(0, 1, integer=True)),  # PandaSet d: 0 Pandar64, 1 PandarGT
    ("*.fps_reset_every", AT_LEAST_ONE),
    # Preprocessing: offsets in time may be negative; probabilities and fractions are in [0, 1].
    ("*.evidence_offsets_s", ANY),
    ("*.confidence", Range(0, 1, low_open=True, high_open=True)),
    ("*fraction", UNIT),
    ("*.box_threshold", UNIT),
    ("*.text_threshold", UNIT),
    ("*.nms_iou", UNIT),
    ("*.track_iou", UNIT),
    ("*.moving_score", UNIT),
    ("*.similarity_threshold", Range(-1, 1)),  # a cosine similarity
    ("*.fitness_threshold", UNIT),
    ("*.min_kept_area", UNIT),
    ("*.merge_overlap", UNIT),
    ("*.min_agreement", UNIT),
    ("*.trim", Range(0, 0.5, high_open=True)),
    ("*sigma*", POSITIVE),  # standard deviations divide residuals
    ("*_eps", POSITIVE),  # DBSCAN neighbourhood radii
    ("*radius", POSITIVE),
    ("*.cell_size", POSITIVE),
    ("*.ground_cell", POSITIVE),
    ("*.min_samples", AT_LEAST_ONE),
    ("*cluster_min_samples", AT_LEAST_ONE),
    ("*.patch_size", AT_LEAST_ONE),
    ("*.short_side", AT_LEAST_ONE),
    ("*.max_side", AT_LEAST_ONE),
    ("*.max_text_len", AT_LEAST_ONE),
    ("*.rings", AT_LEAST_ONE),
    ("*.ring_histograms", AT_LEAST_ONE),
    ("*.orientations", AT_LEAST_ONE),
    ("*.batch_size", AT_LEAST_ONE),
    ("*.max_iterations", AT_LEAST_ONE),
    ("*.max_points", AT_LEAST_ONE),
    ("*.max_neighbours", AT_LEAST_ONE),
    ("*.min_correspondences", Range(3, integer=True)),  # a rigid fit needs three points
    # Model.
    ("pipeline.model.ssim_lambda", UNIT),
    ("pipeline.model.background_color", UNIT),
    ("pipeline.model.mcmc.cap_max", AT_LEAST_ONE),
    ("pipeline.model.mcmc.refine_every", AT_LEAST_ONE),
    ("pipeline.model.mcmc.min_opacity", Range(0, 1, high_open=True)),
    ("pipeline.model.mcmc.noise_gate_opacity", UNIT),
    ("pipeline.model.cap_factor", POSITIVE),
    ("pipeline.model.camera_refinement_prior", POSITIVE),  # its sizes divide
    ("pipeline.model.decoder.feature_dim", AT_LEAST_ONE),
    ("pipeline.model.decoder.hidden", AT_LEAST_ONE),
    ("pipeline.model.decoder.kernel", AT_LEAST_ONE),
    ("pipeline.model.decoder.blocks", AT_LEAST_ONE),
    ("pipeline.model.lidar.rays_per_step", AT_LEAST_ONE),
    ("pipeline.model.lidar.every_n_steps", AT_LEAST_ONE),
    ("pipeline.model.lidar.num_time_bins", AT_LEAST_ONE),
    ("pipeline.model.lidar.head_hidden", AT_LEAST_ONE),
    ("pipeline.model.lidar.*_resolution_deg", POSITIVE),
    ("pipeline.model.lidar.far_plane", POSITIVE),
    ("pipeline.model.lidar.drop_threshold", Range(0, 1, low_open=True, high_open=True)),
    ("pipeline.model.lidar.losses.depth_quantile", FRACTION),
    ("pipeline.model.collider_params.*", ANY),  # nerfstudio's, unused by a splatting model
    ("machine.seed", ANY),
    # Everything else: finite and non-negative (counts, sizes, rates, weights, thresholds, seeds).
    ("*", NON_NEGATIVE),
)

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


def numeric_settings(config: Any, prefix: str = "") -> Iterator[tuple[str, float]]:
    """(dotted path, value) of every number in a nested config, tuples element by element."""
    if dataclasses.is_dataclass(config) and not isinstance(config, type):
        for f in dataclasses.fields(config):
            if not f.name.startswith("_"):
                yield from numeric_settings(getattr(config, f.name), f"{prefix}{f.name}.")
    elif isinstance(config, dict):
        for key, value in config.items():
            yield from numeric_settings(value, f"{prefix}{key}.")
    elif isinstance(config, (tuple, list)):
        for value in config:
            if isinstance(value, (int, float)) and not isinstance(value, bool):
                yield prefix[:-1], value
    elif isinstance(config, (int, float)) and not isinstance(config, bool):
        yield prefix[:-1], config


def rule_for(path: str) -> Range:
    return next(check for pattern, check in RULES if fnmatchcase(path, pattern))


def validate_settings(config: Any) -> None:
    """Raise :class:`IDSplatError` (one line naming the option) for the first setting out of range."""
    values: dict[str, float] = {}
    for path, value in numeric_settings(config):
        check = rule_for(path)
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
