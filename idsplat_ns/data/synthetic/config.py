"""Configuration of the built-in synthetic street: sensor rig, sequence length and the presets.

Every field has a default; the presets `tiny`, `small` and `bench` change only sizes, so the three
show the same kind of street; `varied` and `hard` are `small`'s sensors with traffic drawn per seed;
`segment` is the hard street at a real segment's size (200 frames, five cameras, 64 x 2,650 lidar).
All lengths are metres, angles degrees, times seconds.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial.transform import Rotation

from idsplat_ns.errors import IDSplatError

TRAFFIC_KINDS = ("fixed", "varied", "hard")
"""Values of ``SyntheticConfig.traffic``."""

CAMERA_NAMES: tuple[str, ...] = ("front_camera", "front_left_camera", "front_right_camera")
"""PandaSet names of the three front cameras every rig has, in the order they are rendered."""
SIDE_CAMERA_NAMES: tuple[str, ...] = ("left_camera", "right_camera")
"""PandaSet names of the two side cameras a five-camera rig adds (``CameraRigConfig.side_cameras``)."""
SIDE_CAMERA_YAWS_DEG: tuple[float, float] = (110.0, -110.0)
"""Mounting yaws of the side cameras: 20 deg of overlap with the front-left and front-right ones."""


@dataclass(frozen=True)
class CameraRigConfig:
    """Three pinhole cameras rigidly mounted on the ego vehicle (global shutter unless
    ``rolling_shutter_seconds`` > 0)."""

    image_width: int = 320
    """Image width in pixels."""
    image_height: int = 192
    """Image height in pixels."""
    horizontal_fov_deg: float = 75.0
    """Horizontal field of view of each camera; with yaws of +/-55 deg neighbours overlap by 20 deg."""
    yaws_deg: tuple[float, float, float] = (0.0, 55.0, -55.0)
    """Mounting yaw of front, front-left, front-right (positive turns left, about the ego's up axis)."""
    pitch_deg: float = -4.0
    """Mounting pitch (negative looks down) shared by the three cameras."""
    time_offsets: tuple[float, float, float] = (0.004, 0.011, -0.007)
    """Image time minus frame time, per camera (fixed trigger delays of the rig)."""
    color_gains: tuple[tuple[float, float, float], ...] = (
        (1.0, 1.0, 1.0),
        (1.04, 1.0, 0.95),
        (0.95, 0.98, 1.04),
    )
    """Per-camera RGB gain (exposure and white balance differ between real cameras)."""
    supersample: int = 1
    """Rays per pixel along each image axis (2 means 2x2 rays averaged): anti-aliasing."""
    shadows: bool = True
    """Cast sun shadows (one shadow ray per lit surface sample)."""
    jpeg_quality: int = 93
    """JPEG quality of the written images."""
    rolling_shutter_seconds: float = 0.0
    """Rolling-shutter readout: seconds from the first to the last line's mid-exposure (0: global
    shutter). Each line is rendered at its own time, from the camera pose at that time, with the
    road users where they are then; the image time is the centre line's."""
    rolling_shutter_direction: str = "top_to_bottom"
    """Readout direction: ``top_to_bottom``, ``bottom_to_top``, ``left_to_right`` or ``right_to_left``."""
    exposure_drift: float = 0.0
    """Auto-exposure as real drives show it: each image is scaled by a gain ``1 + drift * sin(...)``
    that goes once up and down over the drive, its own phase per camera (0: every image as rendered;
    0.3: gains 0.7 to 1.3)."""
    calibration_error_deg: tuple[float, float] = (0.0, 0.0)
    """A miscalibrated camera, as real rigs have: the written pose of the front-left camera is turned
    by (about its vertical axis, about its horizontal axis) degrees in every frame, while its images
    are rendered from the true pose (0, 0: a perfect rig)."""
    pose_noise: tuple[float, float] = (0.0, 0.0)
    """Camera poses that carry a localisation error, as PandaSet's do: the written poses of all cameras
    of a frame carry one error of the ego pose that wanders smoothly over the drive, up to (degrees
    about, metres along) each ego axis, while the images come from the true poses and the lidar's
    poses stay exact (0, 0: exact poses; see :func:`pose_noise`)."""
    side_cameras: bool = False
    """Also the two side cameras (``SIDE_CAMERA_NAMES``, yaws +/-110 deg): five cameras around the
    front half, as a Waymo rig has."""


def camera_names(rig: CameraRigConfig) -> tuple[str, ...]:
    """The names of the rig's cameras, in the order they are rendered."""
    return CAMERA_NAMES + (SIDE_CAMERA_NAMES if rig.side_cameras else ())


@dataclass(frozen=True)
class LidarConfig:
    """A spinning 64-beam lidar (Pandar64-like) on the ego roof."""

    azimuth_steps: int = 1024
    """Firings per rotation (columns of the range image); the real Pandar64 has 1800 at 10 Hz."""
    elevation_min_deg: float = -25.0
    """Lowest beam elevation."""
    elevation_max_deg: float = 15.0
    """Highest beam elevation."""
    max_range: float = 100.0
    """Returns beyond this range are dropped (no return)."""
    range_noise_std: float = 0.02
    """Standard deviation of the Gaussian range noise, metres."""
    dropout_prob: float = 0.03
    """Probability that a ray that hit a surface returns nothing anyway (random drop-out)."""
    glass_dropout_prob: float = 0.35
    """Drop-out probability on glass (windows), which reflects the beam away."""
    mount_height: float = 1.9
    """Height of the sensor above the ground."""


@dataclass(frozen=True)
class SyntheticConfig:
    """One synthetic sequence: how long, how fast, which sensors and where on Earth."""

    name: str = "small"
    """Preset name; also names the sequence folder (`synth_<name>_<seed>`)."""
    num_frames: int = 40
    """Number of frames (lidar sweeps and camera triggers)."""
    frame_rate: float = 10.0
    """Frames per second (= lidar rotation rate)."""
    ego_speed: float = 8.0
    """Speed of the ego vehicle along the street, m/s."""
    cameras: CameraRigConfig = field(default_factory=CameraRigConfig)
    """The camera rig."""
    lidar: LidarConfig = field(default_factory=LidarConfig)
    """The spinning lidar."""
    world_offset: tuple[float, float, float] = (452_130.0, 5_612_270.0, 31.5)
    """World position of the street's local origin (UTM-like, exercises the parser's recentring)."""
    world_yaw_deg: float = 21.0
    """Rotation of the street about world z (so that the road is not axis aligned in world)."""
    start_time: float = 1_557_540_000.0
    """Unix time of frame 0."""
    num_pedestrians: int = 3
    """Walking pedestrians (label "Pedestrian"): the first crosses the road on the zebra crossing, the
    others walk along the sidewalks. Legs and arms swing with the gait (non-rigid in their cuboid)."""
    num_cyclists: int = 1
    """Cyclists riding in the traffic lanes (label "Bicycle", one cuboid for rider and bicycle). Legs,
    cranks and wheels turn with the pedalling (non-rigid in their cuboid)."""
    traffic: str = "fixed"
    """Vehicles and the ego's lane (:mod:`idsplat_ns.data.synthetic.traffic`): ``fixed`` (the same
    five manoeuvres on every seed), ``varied`` (0-15 movers drawn per seed from a catalogue of
    manoeuvres and classes, parked rows that vary) or ``hard`` (the close passes, long vehicles,
    completed turns, cut-in, stop-and-go and U-turn of that catalogue in one street)."""

    @property
    def duration(self) -> float:
        """Time from the first to the last frame, seconds."""
        return (self.num_frames - 1) / self.frame_rate


PRESETS: dict[str, SyntheticConfig] = {
    # Tests: seconds to make on 2 cores; still 64 beams and three cameras; vehicles only.
    "tiny": SyntheticConfig(
        name="tiny",
        num_frames=10,
        num_pedestrians=0,
        num_cyclists=0,
        cameras=CameraRigConfig(image_width=128, image_height=80, supersample=1),
        lidar=LidarConfig(azimuth_steps=256),
    ),
    # The demo: trains on 2 CPU cores.
    "small": SyntheticConfig(name="small"),
    # Development and reports on traffic that changes with the seed (the `small` street's sensors).
    "varied": SyntheticConfig(name="varied", traffic="varied"),
    "hard": SyntheticConfig(name="hard", traffic="hard", num_cyclists=2),
    # Benchmarks: closer to real sensor sizes.
    "bench": SyntheticConfig(
        name="bench",
        num_frames=60,
        num_pedestrians=4,
        num_cyclists=2,
        cameras=CameraRigConfig(image_width=640, image_height=384),
        lidar=LidarConfig(azimuth_steps=1800),
    ),
    # A real segment's size, for timing preprocessing (issue 43): Waymo's 200 frames, five cameras
    # and 64 beams x 2,650 columns; the hard street's traffic over 20 s; the small street's images.
    "segment": SyntheticConfig(
        name="segment",
        num_frames=200,
        traffic="hard",
        num_cyclists=2,
        cameras=CameraRigConfig(side_cameras=True),
        lidar=LidarConfig(azimuth_steps=2650),
    ),
}


MAX_PEDESTRIANS = 12
"""Most pedestrians a street holds (beyond this, free places along the sidewalks run short)."""
MAX_CYCLISTS = 6
"""Most cyclists a street holds (the lanes also carry the vehicles)."""
MAX_CALIBRATION_ERROR_DEG = 10.0
MAX_POSE_NOISE = (5.0, 2.0)
"""Largest pose noise the generator makes: degrees, metres."""
"""Largest calibration error a street is written with: a rig further off is mounted wrong, not miscalibrated."""


def get_preset(preset: str | SyntheticConfig) -> SyntheticConfig:
    """The configuration for a preset name, or `preset` itself if it already is a configuration."""
    if isinstance(preset, SyntheticConfig):
        check_config(preset)
        return preset
    if preset not in PRESETS:
        raise IDSplatError(
            f"unknown synthetic preset {preset!r}: choose one of {', '.join(sorted(PRESETS))}"
        )
    return PRESETS[preset]


ROLLING_SHUTTER_DIRECTIONS = ("top_to_bottom", "bottom_to_top", "left_to_right", "right_to_left")
"""Readout directions the generator can render."""
_ROLLING_SHUTTER_FIELDS = ("rolling_shutter_seconds", "rolling_shutter_direction")


def check_config(config: SyntheticConfig) -> None:
    """Range checks of the options a user sets (counts of road users, rolling shutter)."""
    rig = config.cameras
    period = 1.0 / config.frame_rate
    if not 0.0 <= rig.rolling_shutter_seconds < period:
        raise IDSplatError(f"rolling shutter readout {rig.rolling_shutter_seconds * 1e3:g} ms: choose 0 (global) to less "
                           f"than one frame period, {period * 1e3:g} ms (--rolling-shutter-ms)")
    if rig.rolling_shutter_direction not in ROLLING_SHUTTER_DIRECTIONS:
        raise IDSplatError(f"rolling shutter direction {rig.rolling_shutter_direction!r}: choose one of "
                           f"{', '.join(ROLLING_SHUTTER_DIRECTIONS)} (--rolling-shutter-direction)")
    if not 0 <= config.num_pedestrians <= MAX_PEDESTRIANS:
        raise IDSplatError(f"num_pedestrians={config.num_pedestrians}: choose 0 to {MAX_PEDESTRIANS} (--pedestrians)")
    if not 0 <= config.num_cyclists <= MAX_CYCLISTS:
        raise IDSplatError(f"num_cyclists={config.num_cyclists}: choose 0 to {MAX_CYCLISTS} (--cyclists)")
    if not 0.0 <= rig.exposure_drift < 1.0:
        raise IDSplatError(f"exposure drift {rig.exposure_drift:g}: choose 0 (none) to less than 1 (--exposure-drift)")
    if not all(math.isfinite(v) and abs(v) <= MAX_CALIBRATION_ERROR_DEG for v in rig.calibration_error_deg):
        raise IDSplatError(f"calibration error {' '.join(f'{v:g}' for v in rig.calibration_error_deg)} degrees: choose "
                           f"values from -{MAX_CALIBRATION_ERROR_DEG:g} to {MAX_CALIBRATION_ERROR_DEG:g} (--calibration-error-deg)")
    if not all(math.isfinite(v) and 0.0 <= v <= top for v, top in zip(rig.pose_noise, MAX_POSE_NOISE)):
        raise IDSplatError(f"pose noise {' '.join(f'{v:g}' for v in rig.pose_noise)}: choose 0 to {MAX_POSE_NOISE[0]:g} "
                           f"degrees and 0 to {MAX_POSE_NOISE[1]:g} metres (--pose-noise)")
    if config.traffic not in TRAFFIC_KINDS:
        raise IDSplatError(f"traffic={config.traffic!r}: choose one of {', '.join(TRAFFIC_KINDS)} (--traffic)")


def config_to_dict(config: SyntheticConfig) -> dict:
    """The configuration as plain JSON-able data (written to `generator.json`). The rolling-shutter
    fields are left out while the shutter is global, so streets made before the option existed
    keep their `generator.json` byte for byte (and stay cache hits)."""
    out = dataclasses.asdict(config)
    if config.traffic == "fixed":  # as before the option existed
        out.pop("traffic")
    if config.cameras.rolling_shutter_seconds == 0:
        for key in _ROLLING_SHUTTER_FIELDS:
            out["cameras"].pop(key)
    if config.cameras.exposure_drift == 0:
        out["cameras"].pop("exposure_drift")
    if not any(config.cameras.calibration_error_deg):
        out["cameras"].pop("calibration_error_deg")
    if not any(config.cameras.pose_noise):
        out["cameras"].pop("pose_noise")
    if not config.cameras.side_cameras:
        out["cameras"].pop("side_cameras")
    return out


def exposure_gain(rig: CameraRigConfig, camera: int, time: float, duration: float) -> float:
    """The gain of camera ``camera`` (its index in the rig) at ``time`` seconds of a ``duration``-second
    drive (see ``CameraRigConfig.exposure_drift``)."""
    phase = 2.0 * np.pi * camera / len(camera_names(rig))
    return 1.0 + rig.exposure_drift * float(np.sin(2.0 * np.pi * time / max(duration, 1e-9) + phase))



# Cycles over the drive and phases of the six components of the pose noise (rotation about, then
# translation along, the ego's x, y, z): incommensurate, so that no two components move together.
_POSE_NOISE_CYCLES = np.array([1.3, 1.9, 2.6, 1.6, 2.2, 2.9])
_POSE_NOISE_PHASES = np.array([0.0, 1.1, 2.3, 3.7, 4.4, 5.2])


def pose_noise(rig: CameraRigConfig, time: float, duration: float) -> tuple[np.ndarray, np.ndarray]:
    """The ego-frame error ``(R [3, 3], t [3])`` that the cameras' written poses carry at ``time``
    seconds of a ``duration``-second drive: a written camera-to-ego pose is ``(R, t)`` after the true
    one. Each component is a sinusoid of its own frequency (1.3-2.9 cycles over the drive) and phase,
    of amplitude ``rig.pose_noise`` (degrees for the rotation vector, metres for the translation)."""
    s = np.sin(2.0 * np.pi * _POSE_NOISE_CYCLES * time / max(duration, 1e-9) + _POSE_NOISE_PHASES)
    degrees, metres = rig.pose_noise
    return Rotation.from_rotvec(np.radians(degrees) * s[:3]).as_matrix(), metres * s[3:]


MISCALIBRATED_CAMERA = 1
"""Index of the camera whose calibration ``calibration_error_deg`` turns (front-left)."""


def calibration_error(rig: CameraRigConfig) -> np.ndarray:
    """[3, 3] rotation in the camera frame (OpenCV axes: y down, x right) that the written pose of
    the miscalibrated camera carries: about the vertical axis, then the horizontal one."""
    yaw, pitch = np.radians(rig.calibration_error_deg)
    ry = np.array([[np.cos(yaw), 0.0, np.sin(yaw)], [0.0, 1.0, 0.0], [-np.sin(yaw), 0.0, np.cos(yaw)]])
    rx = np.array([[1.0, 0.0, 0.0], [0.0, np.cos(pitch), -np.sin(pitch)], [0.0, np.sin(pitch), np.cos(pitch)]])
    return ry @ rx