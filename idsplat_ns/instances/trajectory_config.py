"""How instance poses are estimated from their lidar points: the settings of registration and of
each pass of the track builder (:mod:`idsplat_ns.instances.trajectory_passes`)."""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Literal, Optional

from idsplat_ns.data.tracks import label_group
from idsplat_ns.instances.heading_flips import HeadingFlipConfig
from idsplat_ns.instances.registration import RegistrationConfig
from idsplat_ns.instances.segment_linking import SegmentLinkConfig
from idsplat_ns.ranges import UNIT, bounded


@dataclass(frozen=True)
class TrajectoryConfig:
    """How instance poses are estimated from their lidar points."""

    method: Literal["registration", "centroid"] = "registration"
    """``registration`` (the paper) or ``centroid`` (ablation c: translation from point centroids)."""
    people_method: Optional[Literal["registration", "centroid"]] = None
    """Ours: the method for instances whose class is a pedestrian (None: ``method``). A walker is
    not rigid: its swinging limbs change the cluster's shape from sweep to sweep, and registration
    can slide metres off where the centroid stays on the person."""
    registration: RegistrationConfig = field(default_factory=RegistrationConfig)
    """RANSAC settings."""
    min_points: int = 10
    """Instances never seen with at least this many points are dropped."""
    min_segment_frames: int = 3
    """Ours: observations of a mask instance that no registration reached form a new instance of
    their own when at least this many of them register together (a turning car seen from the
    front, then only from behind, shares no surface between the two views). The paper keeps one
    instance per mask ID and drops them. 0 disables."""
    chain_neighbours: int = 3
    """Ours: a frame that fails against the whole canonical set is registered again against the
    canonical points of only its (up to) this many nearest registered frames in time, outwards
    from the registered ones. A turning car shows other faces than in its dense frames, so the
    whole set scores below the fitness threshold while its neighbours' view matches. 0: the
    paper's single pass."""
    chain_max_gap: float = 1.0
    """Seconds: neighbours further away in time are not used by the chained registration."""
    chain_max_deviation: float = 1.0
    """Metres: a chained registration is accepted only this close to the constant-velocity
    prediction from the two nearest registered frames."""
    chain_centroid_velocity: bool = True
    """Ours, with the chain only: beside the only registered frame, predict with the velocity of
    the observations' centroids (least squares over a second either side) instead of none. The
    densest view of a car passing the ego is its nearest; its neighbours, 2 m away at 10 m/s and
    0.2 s, never fell within ``chain_max_deviation`` of a zero-velocity prediction."""
    chain_gate_grows: bool = True
    """Ours, with the chain only: a prediction extrapolated from two registered frames close in
    time may be off by more than ``chain_max_deviation``: the gate grows by the velocity error
    that that deviation in either frame makes over their baseline, times the time extrapolated
    (motion_prior.prediction_gate). Two frames 0.2 s apart, one slid 1.1 m along a car's flat
    side, put the frame before them 1.7 m from the prediction."""
    first_pass_min_seen_fraction: Optional[float] = bounded(0.9, UNIT)
    """Ours, with the chain only: the first pass leaves to the chain the observations of which the
    cameras see less than this share of the instance's lidar points (known for lidar-motion
    instances; the rest has no pixel and is not kept). A bus passing beside the ego is cut by the
    cameras' field of view to 15 % of its length; registered whole-set first, the cut slid along
    its flat side by the length cut off at fitness 1.0, while the chain places it from the
    motion's prediction. Cut views the chain cannot place are registered against the whole set
    after it (a car overtaking the ego shows a sliver at first). None: every observation in the
    first pass (the paper)."""
    cut_view_min_vehicle_length: float = 7.0
    """Metres: ``first_pass_min_seen_fraction`` applies to instances whose class is at least this
    long (trucks, buses: ``amodal_centre.DEFAULT_CLASS_SIZES``). A cut view slides by about the
    length cut off; a car's slide stays under its length and the smoother takes most of it out,
    while the chain's constant-velocity prediction misplaces a car finishing a turn."""
    motion_outliers: bool = True
    """Ours, with the chain only: before chaining, first-pass registrations further than
    ``chain_max_deviation`` from the constant-velocity prediction of their two nearest registered
    frames are dropped (worst first, one at a time) and left to the chained registration, which
    starts from the motion. A car entering the view showed only its front, which registered onto
    the rear of the canonical set 3.5 m ahead of itself at fitness 1.0."""
    coast_frames: int = 1
    """Ours, with the chain only: up to this many observed frames just past either end of the
    registered frames that no registration reached take the constant-velocity prediction as their
    pose when their points fit it (the registration fitness against the nearest registered frames'
    canonical points). Their points do not join the canonical set. A car leaving the camera's view
    is lifted cut at the image border; registration slides that cut onto the car's real end,
    metres from where it is, and the instance ended a frame early while the images still show it.
    0 disables."""
    out_of_view_frames: int = 0
    """Ours, with the chain only: up to this many frames past either end of a vehicle's track where
    the lidar-motion source saw it and no camera did are posed from the lidar alone: the
    nearest posed frame's pose moved by the shift of the cluster's centroid, refined by ICP onto
    it, while that stays within ``chain_max_deviation`` of the prediction and fits
    (instances/out_of_view.py). A car overtaking from behind was placed only from its 12th frame,
    and one passing the other way ended at 4 m beside the ego, while the held-out frame after it
    still showed its side. 20 gains 0.07-0.72 dB DPSNR on four unseen `hard` streets but loses
    0.2-0.5 dB on `small` ones, where an overtaking car's carried frames inherit the error of its
    first, sliver views (docs/reports/2026-11-29-people-and-carrying.md), so it is off (0) by
    default."""
    heading_flips: HeadingFlipConfig = field(default_factory=HeadingFlipConfig)
    """Registrations whose heading disagrees with the direction of travel (front/back flips,
    quarter turns), turned back (ours; see instances/heading_flips.py)."""
    link_segments: SegmentLinkConfig = field(default_factory=SegmentLinkConfig)
    """Split segments joined back to their instance through the vehicle's box (ours; see
    instances/segment_linking.py). Needs the sensor positions (lidar sweeps)."""


def config_for_label(config: TrajectoryConfig, label: str) -> TrajectoryConfig:
    """``config`` for an instance of class ``label``: ``people_method`` for a pedestrian."""
    if config.people_method is None or config.people_method == config.method or label_group(label) != "pedestrian":
        return config
    return replace(config, method=config.people_method)
