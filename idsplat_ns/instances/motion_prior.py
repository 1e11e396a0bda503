"""Where an instance should be at a frame, from its motion: the constant-velocity prediction from
its registered frames, the velocity of its observations' centroids where only one frame is
registered, and a prediction refined by ICP. Pure functions of poses, times and points."""

from __future__ import annotations

from typing import Optional

import numpy as np

from idsplat_ns.instances.lifting import InstanceObservation
from idsplat_ns.instances.registration import RegistrationConfig, icp_point_to_plane


def centroid_velocity(
    observations: list[InstanceObservation],
    times: np.ndarray,  # [F] seconds
    frame: int,
    window: float = 1.0,  # seconds either side of the frame
) -> tuple[Optional[np.ndarray], float]:  # -> [3] m/s, seconds
    """Least-squares velocity of the observations' point centroids within ``window`` of ``frame``
    and the time span it was fitted over (None, 0 with fewer than two times there). Biased where
    the seen part of the object changes (its centroid slides over the body), but it needs no
    registration: the prediction of a frame beside the only registered one."""
    near = [o for o in observations if abs(times[o.frame] - times[frame]) <= window and len(o.points)]
    t = np.array([times[o.frame] for o in near], dtype=np.float64)
    if len(near) < 2 or np.ptp(t) <= 0:
        return None, 0.0
    c = np.stack([o.points.mean(0) for o in near])
    tc = t - t.mean()
    return (tc[:, None] * (c - c.mean(0))).sum(0) / (tc * tc).sum(), float(np.ptp(t))


def predicted_pose(
    poses: np.ndarray,  # [F, 4, 4] canonical -> world
    registered: list[int],  # frames with a pose
    times: np.ndarray,  # [F] seconds
    frame: int,
    single_frame_velocity: Optional[np.ndarray] = None,  # [3] m/s
) -> np.ndarray:
    """Constant-velocity prediction of the pose at ``frame`` from the two registered frames
    nearest to it in time (the nearest one's rotation). With a single registered frame the
    velocity is ``single_frame_velocity`` (e.g. :func:`centroid_velocity`), else zero: the
    densest view of a car passing the ego is its nearest, and its neighbours, 2 m away at
    10 m/s and 0.2 s, never fell within a metre of a zero-velocity prediction."""
    order = sorted(registered, key=lambda f: (abs(times[f] - times[frame]), f))
    out = poses[order[0]].copy()
    if len(order) >= 2 and times[order[1]] != times[order[0]]:
        a, b = order[0], order[1]
        velocity = (poses[a, :3, 3] - poses[b, :3, 3]) / (times[a] - times[b])
        out[:3, 3] += velocity * (times[frame] - times[a])
    elif len(order) == 1 and single_frame_velocity is not None:
        out[:3, 3] += single_frame_velocity * (times[frame] - times[order[0]])
    return out


def prediction_gate(
    registered: list[int],  # frames with a pose
    times: np.ndarray,  # [F] seconds
    frame: int,
    base: float,  # metres: how far a registered pose may be off (the gate of a well-founded prediction)
    single_frame_span: Optional[float] = None,  # seconds the single-frame velocity was fitted over
) -> float:
    """How far (metres) a pose at ``frame`` may lie from :func:`predicted_pose`'s prediction while
    the motion rests on at most two registered frames: ``base``, plus what extrapolating their
    velocity adds when each may be ``base`` off (``sqrt(2) base / baseline`` m/s, times the time to
    extrapolate). Two registered frames 0.2 s apart beside the densest view of a passing car, one
    slid 1.1 m along the car's flat side, put the frame before them 1.7 m from the prediction,
    outside a fixed 1 m gate. With three or more, ``base``: the track is known, and a registration
    that slid 2 m along a car leaving the camera's view must stay out."""
    order = sorted(registered, key=lambda f: (abs(times[f] - times[frame]), f))
    dt = abs(float(times[frame] - times[order[0]]))
    if len(order) == 2 and times[order[1]] != times[order[0]]:
        return base * (1.0 + np.sqrt(2.0) * dt / abs(float(times[order[0]] - times[order[1]])))
    if len(order) == 1 and single_frame_span:
        return base * (1.0 + np.sqrt(2.0) * dt / single_frame_span)
    return base


def motion_outliers(
    poses: np.ndarray,  # [F, 4, 4] canonical -> world
    registered: list[int],  # frames with a pose, the reference (the densest view) first
    times: np.ndarray,  # [F] seconds
    max_deviation: float,
) -> list[int]:
    """Frames whose position is further than ``max_deviation`` (metres) from the constant-velocity
    prediction of their two nearest other registered frames, found worst first and one at a time
    (a misplaced frame also spoils the prediction of its neighbours). Needs 4 registered frames:
    with 3, each prediction leans on the misplaced one and any of them could be it. The reference
    frame may be one: the densest view of a car passing the ego shows its flat side, which the
    views before it, registered consistently among themselves, put 1.1 m along the car."""
    kept = list(registered)
    out = []
    while len(kept) >= 4:
        deviation = {f: float(np.linalg.norm(poses[f, :3, 3] - predicted_pose(poses, [g for g in kept if g != f], times, f)[:3, 3]))
                     for f in kept}
        worst = max(deviation, key=lambda f: (deviation[f], -f))
        if deviation[worst] <= max_deviation:
            break
        out.append(worst)
        kept.remove(worst)
    return out


def motion_prior_pose(
    prediction: np.ndarray,  # [4, 4] canonical -> world predicted for the frame
    source: np.ndarray,  # [N, 3] canonical points
    target: np.ndarray,  # [M, 3] world points at the frame to register
    config: RegistrationConfig,
    radii: tuple[float, ...] = (0.5,),
) -> np.ndarray:
    """The prediction refined by point-to-plane ICP with shrinking pair distances (small ones:
    a wide radius lets a box slide along its own flat faces)."""
    T = prediction.copy()
    for radius in radii + (config.icp_distance,):
        T = icp_point_to_plane(T, source, target, max(config.icp_iterations, 10), radius)
    return T
