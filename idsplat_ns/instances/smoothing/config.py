"""Settings of the coordinated-turn (CT) trajectory smoother; defaults are the paper's (supplementary,
"Trajectory smoothing")."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Optional

from idsplat_ns.errors import IDSplatError
from idsplat_ns.instances.ground import GroundConfig
from idsplat_ns.ranges import POSITIVE, UNIT, bounded


@dataclass(frozen=True)
class SmoothingConfig:
    """Noise levels, robust loss and iteration counts of the CT smoother."""

    measurement_rot_sigma: float = bounded(0.1, POSITIVE)
    """Std of the pose measurement factors, rotation part [rad] (each axis)."""
    measurement_trans_sigma: float = bounded(0.2, POSITIVE)
    """Std of the pose measurement factors, translation part [m] (each axis)."""
    huber_threshold: float = 1.0
    """Huber threshold (whitened units) of the measurement factors."""
    motion_rot_sigma: float = bounded(0.1, POSITIVE)
    """Std of the CT motion factor between successive states, rotation part [rad]."""
    motion_trans_sigma: float = bounded(0.2, POSITIVE)
    """Std of the CT motion factor between successive states, translation part [m]."""
    motion_vertical_sigma: Optional[float] = bounded(0.02, POSITIVE)
    """Ours: std [m] of the CT motion factor's vertical (motion-frame z) translation per step. A car
    follows the road: in its own pitched frame it does not move up or down, beyond its suspension.
    None: the isotropic ``motion_trans_sigma`` (the paper's)."""
    motion_tilt_sigma: Optional[float] = bounded(0.01, POSITIVE)
    """Ours: std [rad] of the CT motion factor's roll and pitch change per step (0.6 degrees).
    With the paper's 0.1 rad, the registrations' 1-5 degree pitch noise made the smoothed car climb
    and sink: the CT model moves it along its pitched x axis (measured on the synthetic street:
    a followed car 0.1 m up and down where its registrations were within 0.05 m, about 1.5 px at
    its distance; docs/smoothing.md). None: the isotropic ``motion_rot_sigma`` (the paper's)."""
    speed_walk_rate: float = 0.5
    """Random walk on speed: std over a step of dt seconds is sqrt(speed_walk_rate * dt) [m/s]."""
    curvature_walk_rate: float = 1e-5
    """Random walk on curvature: std over a step is sqrt(curvature_walk_rate * dt) [1/m]."""
    roll_pitch_sigma: float = bounded(0.4, POSITIVE)
    """Std of the roll and pitch prior of each pose in the motion frame (after the shared rotation)."""
    curvature_sigma: float = bounded(0.01, POSITIVE)
    """Std of the zero-mean curvature prior applied at every step [1/m]."""
    turning_curvature_sigma: Optional[float] = bounded(1.0, POSITIVE)
    """Ours: for a vehicle whose registrations turn by ``turning_min_heading_change`` or more, the
    curvature prior's std [1/m] (and ``turning_curvature_walk_rate`` its random walk), so that the
    curvature state carries the turn. With the paper's prior (0.01, a 100 m radius) and walk
    (curvature all but constant), a turn is carried by the motion factor's rotation slack alone,
    and the heading lags into the turn and overshoots out of it: on the synthetic street a pickup
    turning 90 degrees in 2 s was up to 4.8 degrees off entering and 7.5 leaving it (seed 10, at
    its training frames; at most 1.8 with these settings). Straight drivers keep the paper's
    prior: freed, the curvature of a far bus with three kept measurements bent its path 12
    degrees (seed 7). None: the paper's prior for every vehicle."""
    turning_curvature_walk_rate: float = 0.05
    """Random-walk rate of the curvature of a turning vehicle [1/m^2/s]: 0.07 1/m per 0.1 s step,
    a radius of 7 m reached within 0.2-0.5 s of entering a turn."""
    turning_min_heading_change: float = math.radians(30.0)
    """Radians of measured heading change (running median of the registrations'
    yaws, smallest to largest) from which a vehicle counts as turning."""
    outlier_threshold: float = 1.345
    """Measurements whose whitened error (after the first pass) exceeds this are dropped."""
    outlier_scale_adaptive: bool = False
    """False (default): ``outlier_threshold`` alone, as the paper states. True raises the threshold
    to ``adaptive_outlier_factor`` x the median whitened error when that is larger, so that
    registration noise well beyond the configured sigmas (e.g. 0.5 m) does not flag most
    measurements as outliers (measured in docs/smoothing.md)."""
    adaptive_outlier_factor: float = 2.5
    """Multiple of the median whitened error used by ``outlier_scale_adaptive``."""
    first_pass_iterations: int = 1
    """Levenberg-Marquardt iterations of the first (outlier-detection) pass."""
    final_iterations: int = 10
    """Maximum Levenberg-Marquardt iterations of the final pass, without the outliers."""
    reconverge_below_inlier_fraction: float = bounded(0.5, UNIT)
    """When the single-iteration first pass keeps fewer than this fraction of the measurements,
    it has not converged (the initial guess was poor), and flagging from it would discard good
    measurements: the first pass is then iterated up to ``final_iterations`` and the outliers
    flagged again. Measured on the synthetic street (docs/smoothing.md): a moving pickup with 3
    gross outliers among 10 measurements kept 1 and was smoothed to a constant pose; reconverged,
    it keeps the 6 good ones. 0 always uses the paper's single iteration."""
    heading_prior_sigma: Optional[float] = bounded(0.02, POSITIVE)
    """Ours: std [rad] of a prior that the motion frame's x axis (the direction of travel) lies
    along the vehicle's own box axis, found from its canonical points' vertical faces
    (``amodal_centre.box_heading``): vehicles do not drive sideways. Without it the shared rotation
    is set by the positions alone, and registrations that slide along faces nothing measures made
    the synthetic street's far bus (seed 10) travel 5.3 degrees off its axis and climb 4.2 degrees,
    0.4-0.5 m off at the ends of its track. Only the heading about the canonical vertical is
    constrained. None: the paper's smoother (no such prior)."""
    heading_prior_min_points: int = 100
    """The heading prior needs at least this many registered points: the box axis of a few dozen
    points of a far car came out 22-29 degrees off on the synthetic street (100 points and more:
    within 2.1 degrees)."""
    ground_height_walk_rate: Optional[float] = 0.001
    """Ours: random-walk rate [m^2/s] of a vehicle's height above the road under it, measured
    from the lidar (``instances/ground.py``): between two steps dt apart its height changes by the
    ground's rise within sqrt(rate * dt) metres (0.01 m per 0.1 s). Registrations of far vehicles
    drift vertically as the lidar lines sweep over them: the synthetic street's far bus (seed 12)
    rose 1.2 m over 1.8 s on a level road, and neither the motion model nor the tilt prior stops
    a slow climb. Applied where the scene has lidar ground near the vehicle. None: off (the
    paper's smoother)."""
    ground: GroundConfig = field(default_factory=GroundConfig)
    """How the ground under a vehicle is measured from the lidar points."""
    span_max_distance: Optional[float] = 1.0
    """Metres: a measurement farther than this from the smoothed position does not extend the
    instance's span (it exists between its first and last measurement that does). A gross
    outlier at the end of a track would otherwise keep the instance alive where the CT model only
    extrapolates (measured: 8-13 m from the truth on the synthetic street). None: every
    measurement extends the span."""
    gross_yaw_deviation: Optional[float] = 1.5707963267948966
    """Ours: measurements whose yaw is more than this (rad) from the circular mean of their two
    neighbours on each side are outliers from the start. A half-turned registration among the
    measurements of a turning car made the CT states loop through it (and flag the good
    measurements instead). A vehicle turns far less than 90° between a measurement and its
    neighbours. None: the paper's Huber first pass alone."""
    drop_outlier_points: bool = False
    """Ours, off by default: the canonical points of a measurement flagged as an outlier leave the instance's point
    set (a wrong registration put them in the wrong place of the canonical frame, where they would
    seed misplaced Gaussians and skew the amodal centre). False keeps every registered point, as
    the paper's pipeline does. Off by default: on ten streets it was not made for, keeping the points gave a higher MOTA@2m on six and a lower one on one (mean 0.887 against 0.875), with the same box-corner error (docs/reports/2026-11-27-rule-ablation.md)."""
    measurement_times: bool = True
    """Ours: a registration is placed at its points' mean lidar ray time instead of the frame time
    (where ray times are known). The rays that hit a car are fired up to half a sweep (0.05 s)
    from the frame time: on the synthetic street a car at 12.5 m/s was registered 0.05-0.32 m
    ahead of where it was at the frame time, differently at every frame. False: frame times."""
    repose_points: bool = True
    """Ours: each kept canonical point is re-derived with the smoothed pose at its own ray time
    (it keeps the world position the lidar saw). This undoes the car's motion during the sweep,
    which stretched or squashed a car's lidar view by up to 0.33 m, and makes the points agree
    with the smoothed poses the model renders with. False keeps the registered points."""
    min_noise_dt: float = 1e-3
    """Time steps shorter than this [s] use this value in the random-walk sigmas, so that
    nearly coincident timestamps do not make the random walks infinitely stiff."""
    weak_speed_sigma: float = bounded(100.0, POSITIVE)
    """Std [m/s] of a weak prior on the first speed; it only fixes the speed when no two
    measurements exist (a single measurement). Negligible otherwise."""
    weak_shared_rotation_sigma: float = bounded(3.0, POSITIVE)
    """Std [rad] of a weak prior that keeps the shared rotation at its initial value when the
    motion does not determine it (a stopped object). Negligible otherwise."""
    degenerate_directions: bool = True
    """Ours: a registration does not measure the directions its points show no surface facing
    (a car seen only from its side slides along its length; see observability.py): there its
    translation sigma is ``degenerate_sigma``, and such a slide neither flags the measurement as
    an outlier nor ends the span. Needs the instance's per-frame points. False: the paper's
    isotropic ``measurement_trans_sigma``."""
    degenerate_ratio: float = 0.2
    """A direction is not measured when its point-to-plane information is below this fraction of
    the frame's strongest direction's (0 measures every direction)."""
    degenerate_sigma: float = bounded(3.0, POSITIVE)
    """Std [m] of a registration's translation along a direction it does not measure (about a
    car's half length: where a slide along a face can end)."""
    degenerate_min_facing_points: float = 10.0
    """A direction is also measured when at least this many of the frame's points face it (a
    near side view has wheel arches, mirrors and corners)."""
    degenerate_min_anchor_frames: int = 2
    """An unmeasured direction is left to the motion only where at least this many other frames
    measure it; elsewhere (a car followed from behind is never measured sideways) it keeps
    ``measurement_trans_sigma``."""
    degenerate_min_frame_points: int = 24
    """Frames with fewer points measure no direction and anchor none (their neighbourhoods are
    the whole view, not its surfaces)."""
    degenerate_vertical_sigma: Optional[float] = bounded(0.3, POSITIVE)
    """Ours: metres; a registration's position is never left freer than this vertically, even
    where its points show no surface facing up or down (a side or rear view). A car's points span
    its visible height, and the image features placed them: on the synthetic street such views
    registered within 0.2 m of the true height, but left free, a passing car's height followed the
    motion frame's pitch 0.25 m above and below the truth at the ends of its track (seed 10). None:
    ``degenerate_sigma`` in every direction."""
    degenerate_sparse_frame_points: Optional[int] = 100
    """Ours: a frame of fewer points than this (a far view) leaves every direction its surfaces do
    not measure to the motion, even one no other frame measures, where the instance has a box
    axis for the heading prior: the travel direction then comes from that axis and the height
    from the ground, and the sparse views' sideways slide does not steer the track. A bus seen
    from behind at 50-70 m (25-77 points a frame) registered 0.4-0.6 m to either side of its
    lane across its track on every synthetic street; with the ground in place, this took its
    box-corner error from 0.27 m to 0.12 m on average over seeds 0-12, and no instance got worse
    by 5 mm (docs/reports/2026-11-27-smoothed-poses.md). Dense views keep ``measurement_trans_sigma`` there (a car
    followed from behind, whose rear's texture places it sideways). None: only anchored
    directions."""
    degenerate_one_sided: bool = True
    """Ours: along an axis that some frames measure only through faces on one side of the car (its
    front) and the others only through the opposite side (its rear), with no frame seeing both,
    the smaller group is left to the motion there too: the registrations tie the two faces
    together through nothing but a slide (observability.one_sided_directions; seed 9's car that
    overtakes close: front frames 0.6 m off, 0.13 -> 0.05 m mean error)."""

    def __post_init__(self) -> None:
        for name in ("motion_vertical_sigma", "motion_tilt_sigma"):
            value = getattr(self, name)
            if value is not None and not value > 0.0:
                raise IDSplatError(f"smoothing.{name.replace('_', '-')} must be > 0 or None, got {value}")
        if self.degenerate_vertical_sigma is not None and not self.degenerate_vertical_sigma > 0.0:
            raise IDSplatError(f"smoothing.degenerate-vertical-sigma must be > 0 or None, got {self.degenerate_vertical_sigma}")
        if self.degenerate_sparse_frame_points is not None and self.degenerate_sparse_frame_points < 0:
            raise IDSplatError("smoothing.degenerate-sparse-frame-points must be >= 0 or None, "
                               f"got {self.degenerate_sparse_frame_points}")
        if self.turning_curvature_sigma is not None and not self.turning_curvature_sigma > 0.0:
            raise IDSplatError(f"smoothing.turning-curvature-sigma must be > 0 or None, got {self.turning_curvature_sigma}")
        if not self.turning_curvature_walk_rate > 0.0:
            raise IDSplatError(f"smoothing.turning-curvature-walk-rate must be > 0, got {self.turning_curvature_walk_rate}")
        if self.ground_height_walk_rate is not None and not self.ground_height_walk_rate > 0.0:
            raise IDSplatError(f"smoothing.ground-height-walk-rate must be > 0 or None, got {self.ground_height_walk_rate}")
        if self.heading_prior_sigma is not None and not self.heading_prior_sigma > 0.0:
            raise IDSplatError(f"smoothing.heading-prior-sigma must be > 0 or None, got {self.heading_prior_sigma}")
        if not 0.0 <= self.degenerate_ratio <= 1.0:
            raise IDSplatError(f"smoothing.degenerate-ratio must be within [0, 1], got {self.degenerate_ratio}")
        if not self.degenerate_sigma > 0.0:
            raise IDSplatError(f"smoothing.degenerate-sigma must be > 0 metres, got {self.degenerate_sigma}")
        if min(self.degenerate_min_facing_points, self.degenerate_min_anchor_frames, self.degenerate_min_frame_points) < 0:
            raise IDSplatError("smoothing.degenerate-min-facing-points, -min-anchor-frames and -min-frame-points "
                               f"must be >= 0; got {self.degenerate_min_facing_points}, "
                               f"{self.degenerate_min_anchor_frames}, {self.degenerate_min_frame_points}")
