"""Iterative robust coordinated-turn smoothing of one instance trajectory (GTSAM, Levenberg-Marquardt).

Pass 1 runs ``first_pass_iterations`` LM iterations with every measurement (Huber loss) and flags
the measurements whose whitened error exceeds the outlier threshold; pass 2 re-optimises from
pass 1's estimate without them for at most ``final_iterations`` iterations.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Callable

import gtsam
import numpy as np

from idsplat_ns.instances.smoothing import factors as F
from idsplat_ns.instances.smoothing.config import SmoothingConfig
from idsplat_ns.data.geometry import invert_pose, rot_z, wrap_angle, yaw_of
from idsplat_ns.instances.smoothing.ct_model import ct_delta_pose, ct_propagate, shared_rotation_pose

# Half-width (in measurements) of the running median used for the initial guess.
_INIT_MEDIAN_HALF_WIDTH = 2
# |curvature| bound of the initial guess [1/m] (about a 2 m turning radius).
_INIT_MAX_CURVATURE = 0.5


@dataclass
class SmoothedTrajectory:
    """Result of :func:`smooth_trajectory`. Poses map the instance's canonical frame to world."""

    times: np.ndarray  # [T] seconds, strictly increasing
    poses: np.ndarray  # [T, 4, 4] smoothed poses at every step
    speeds: np.ndarray  # [T] signed speed along the motion frame's x [m/s]
    curvatures: np.ndarray  # [T] curvature [1/m] (positive: turning left)
    shared_rotation: np.ndarray  # [3, 3] canonical frame -> motion frame (x forward) rotation
    inliers: np.ndarray  # [T] bool: measurement existed and was kept in the final pass
    whitened_errors: np.ndarray  # [T] first-pass whitened measurement errors (NaN where none)
    outlier_threshold: float  # the whitened-error threshold that was applied
    span: tuple[float, float]  # first and last time with a measurement near the result (config.span_max_distance): the instance exists in between

    def pose_at(self, time: float, margin: float = 0.0) -> np.ndarray | None:
        """Pose [4, 4] at ``time`` [s], or None outside ``span`` widened by ``margin`` seconds at
        both ends (the instance is absent there).

        CT propagation from the nearest earlier state with that state's speed and curvature; the
        small mismatch between the prediction and the next state (the motion factor is soft) is
        spread linearly over the interval on SE(3), so the result is continuous and equals the
        states at their own times. Beyond the first or last state (within ``margin``), the CT
        model of that state is propagated forwards or backwards.
        """
        t0, t1 = self.span
        if math.isnan(time) or not (t0 - margin <= time <= t1 + margin):
            return None
        if time < self.times[0] or time > self.times[-1]:
            k = 0 if time < self.times[0] else len(self.times) - 1
            return ct_propagate(self.poses[k], self.shared_rotation, self.speeds[k], self.curvatures[k],
                                float(time - self.times[k]))
        k = int(np.searchsorted(self.times, time, side="right")) - 1
        k = min(max(k, 0), len(self.times) - 1)
        if k == len(self.times) - 1 or time == self.times[k]:
            return self.poses[k].copy()
        dt_full = float(self.times[k + 1] - self.times[k])
        dt = float(time - self.times[k])
        S = shared_rotation_pose(self.shared_rotation)
        M_k = self.poses[k] @ S
        M_next = self.poses[k + 1] @ S
        predicted_next = M_k @ ct_delta_pose(self.speeds[k], self.curvatures[k], dt_full)
        mismatch = gtsam.Pose3.Logmap(gtsam.Pose3(invert_pose(predicted_next) @ M_next))
        M_t = M_k @ ct_delta_pose(self.speeds[k], self.curvatures[k], dt)
        M_t = M_t @ gtsam.Pose3.Expmap((dt / dt_full) * mismatch).matrix()
        return M_t @ S.T  # S is a rotation: its inverse is its transpose

    def poses_at(self, query_times: np.ndarray) -> tuple[np.ndarray, np.ndarray]:  # query_times: [N]
        """Poses [N, 4, 4] at many times and a mask [N] of those inside the span (others identity)."""
        query_times = np.asarray(query_times, dtype=np.float64)
        poses = np.tile(np.eye(4), (len(query_times), 1, 1))
        present = np.zeros(len(query_times), dtype=bool)
        for n, t in enumerate(query_times):
            pose = self.pose_at(float(t))
            if pose is not None:
                poses[n] = pose
                present[n] = True
        return poses, present


def _validate(times: np.ndarray, poses: np.ndarray, valid: np.ndarray) -> None:
    if times.ndim != 1 or len(times) == 0:
        raise ValueError("smooth_trajectory: `times` must be a non-empty 1-D array of seconds")
    if poses.shape != (len(times), 4, 4):
        raise ValueError(f"smooth_trajectory: `poses` must have shape ({len(times)}, 4, 4), got {poses.shape}")
    if valid.shape != times.shape:
        raise ValueError(f"smooth_trajectory: `valid` must have shape {times.shape}, got {valid.shape}")
    if not np.all(np.isfinite(times)) or np.any(np.diff(times) <= 0.0):
        raise ValueError("smooth_trajectory: `times` must be finite and strictly increasing; merge duplicate timestamps first")
    if not valid.any():
        raise ValueError("smooth_trajectory: no valid measurement; an instance needs at least one pose")
    if not np.all(np.isfinite(poses[valid])):
        raise ValueError("smooth_trajectory: a valid pose has NaN/inf entries; mark it invalid")


def _running_median(values: np.ndarray, half_width: int) -> np.ndarray:  # values: [M] or [M, D]
    out = np.empty_like(values)
    for i in range(len(values)):
        lo, hi = max(0, i - half_width), min(len(values), i + half_width + 1)
        out[i] = np.median(values[lo:hi], axis=0)
    return out


def local_line_positions(
    times: np.ndarray,  # [T] seconds of the states
    positions: np.ndarray,  # [T, D] measured positions (rows where ~use are ignored)
    use: np.ndarray,  # [T] bool
    window: int = 5,
) -> np.ndarray:  # -> [T, D]
    """Each state's position on a straight line through the ``window`` measurements nearest in
    time (Theil-Sen: median of pairwise slopes, so one wrong measurement of five does not move
    it). Unlike a running median, it does not pull a track's ends inwards (by up to a step)."""
    idx = np.flatnonzero(use)
    t_meas, p_meas = times[idx], positions[idx]
    out = np.empty((len(times), positions.shape[1]))
    for k, t in enumerate(times):
        near = np.sort(np.argsort(np.abs(t_meas - t), kind="stable")[:window])
        tn, pn = t_meas[near], p_meas[near]
        if len(near) == 1:
            out[k] = pn[0]
            continue
        i, j = np.triu_indices(len(near), 1)
        slope = np.median((pn[j] - pn[i]) / (tn[j] - tn[i])[:, None], axis=0)
        out[k] = np.median(pn - slope * tn[:, None], axis=0) + slope * t
    return out


@dataclass
class _InitialGuess:
    poses: np.ndarray  # [T, 4, 4]
    speeds: np.ndarray  # [T]
    curvatures: np.ndarray  # [T]
    shared: np.ndarray  # [3, 3]


def gross_yaw_outliers(
    poses: np.ndarray,  # [T, 4, 4]
    valid: np.ndarray,  # [T] bool
    max_deviation: float,
    neighbours: int = 2,
) -> np.ndarray:
    """[T] bool: valid measurements whose yaw is more than ``max_deviation`` (rad) from the
    circular mean of up to ``neighbours`` valid measurements on each side (itself left out)."""
    idx = np.flatnonzero(valid)
    yaw = yaw_of(poses[idx])
    out = np.zeros(len(poses), bool)
    for j, i in enumerate(idx):
        near = np.r_[yaw[max(0, j - neighbours) : j], yaw[j + 1 : j + 1 + neighbours]]
        if len(near) == 0:
            continue
        ref = math.atan2(float(np.sin(near).sum()), float(np.cos(near).sum()))
        out[i] = abs(wrap_angle(yaw[j] - ref)) > max_deviation
    return out


def _median_yaws(poses: np.ndarray, valid: np.ndarray) -> np.ndarray:  # poses: [T, 4, 4], valid: [T] -> [M]
    """Running median of the valid measurements' unwrapped yaws (robust to a single wrong one)."""
    return _running_median(np.unwrap(yaw_of(poses[np.flatnonzero(valid)])), _INIT_MEDIAN_HALF_WIDTH)


def _initial_guess(times: np.ndarray, poses: np.ndarray, valid: np.ndarray) -> _InitialGuess:
    """Robust start: running medians of measured positions and yaws, interpolated over gaps; the
    shared rotation from the direction of travel; speeds and curvatures by finite differences."""
    idx = np.flatnonzero(valid)
    t_meas = times[idx]
    pos = _running_median(poses[idx, :3, 3], _INIT_MEDIAN_HALF_WIDTH)
    yaws = _median_yaws(poses, valid)
    T = len(times)
    positions = np.stack([np.interp(times, t_meas, pos[:, a]) for a in range(3)], axis=1)
    yaw = np.interp(times, t_meas, yaws)
    init_poses = np.tile(np.eye(4), (T, 1, 1))
    for t in range(T):
        init_poses[t, :3, :3] = rot_z(yaw[t])
        init_poses[t, :3, 3] = positions[t]

    shared_yaw = 0.0
    speeds = np.zeros(T)
    curvatures = np.zeros(T)
    if T >= 2:
        disp = np.diff(positions, axis=0)  # [T-1, 3]
        dts = np.diff(times)
        step_len = np.linalg.norm(disp[:, :2], axis=1)
        if step_len.sum() > 1e-6:
            # Direction of travel in world minus the object's yaw: the shared yaw, averaged on the circle.
            rel = np.arctan2(disp[:, 1], disp[:, 0]) - yaw[:-1]
            shared_yaw = math.atan2(float(np.sum(step_len * np.sin(rel))), float(np.sum(step_len * np.cos(rel))))
        heading = yaw[:-1] + shared_yaw
        fwd = disp[:, 0] * np.cos(heading) + disp[:, 1] * np.sin(heading)
        v = fwd / dts
        speeds[:-1] = v
        speeds[-1] = v[-1]
        dyaw = np.diff(yaw)
        arc = v * dts
        moving = np.abs(arc) > 0.05
        kappa = np.zeros(T - 1)
        kappa[moving] = dyaw[moving] / arc[moving]
        curvatures[:-1] = np.clip(kappa, -_INIT_MAX_CURVATURE, _INIT_MAX_CURVATURE)
        curvatures[-1] = curvatures[-2]
    return _InitialGuess(init_poses, speeds, curvatures, rot_z(shared_yaw))


def _build_graph(
    times: np.ndarray,
    measured: np.ndarray,
    use: np.ndarray,
    init: _InitialGuess,
    config: SmoothingConfig,
    covariances: list[np.ndarray | None],  # per step: [3, 3] translation covariance, or None (config's)
    heading: np.ndarray | None = None,  # [3] the vehicle's box axis in the canonical frame
    ground_heights: np.ndarray | None = None,  # [T] ground height under each step (NaN: unknown)
) -> gtsam.NonlinearFactorGraph:
    graph = gtsam.NonlinearFactorGraph()
    for t in np.flatnonzero(use):
        graph.add(F.measurement_factor(int(t), measured[t], config, covariances[t]))
    for t in range(len(times)):
        graph.add(F.tilt_factor(t, config))
        graph.add(F.curvature_prior_factor(t, config))
    for t in range(len(times) - 1):
        dt = float(times[t + 1] - times[t])
        graph.add(F.motion_factor(t, dt, config))
        graph.add(F.speed_walk_factor(t, dt, config))
        graph.add(F.curvature_walk_factor(t, dt, config))
        if ground_heights is not None and np.isfinite(ground_heights[t : t + 2]).all():
            sigma = F.random_walk_sigma(config.ground_height_walk_rate, dt, config)
            graph.add(F.ground_height_factor(t, float(ground_heights[t + 1] - ground_heights[t]), sigma))
    graph.add(F.weak_speed_prior_factor(float(init.speeds[0]), config))
    graph.add(F.weak_shared_rotation_prior_factor(init.shared, config))
    if heading is not None and config.heading_prior_sigma is not None:
        graph.add(F.heading_prior_factor(heading_yaw_near(heading, init.shared), config))
    return graph


def heading_yaw_near(heading: np.ndarray, shared: np.ndarray) -> float:  # heading: [3], shared: [3, 3]
    """Yaw [rad] of the box axis ``heading`` (canonical frame), flipped by 180 degrees if that
    brings it nearer the shared rotation's x axis (an axis has two directions; the travel
    direction picks one: a car reversing keeps its box)."""
    yaw = math.atan2(float(heading[1]), float(heading[0]))
    travel = math.atan2(float(shared[1, 0]), float(shared[0, 0]))
    return yaw if abs(float(wrap_angle(yaw - travel))) <= 0.5 * math.pi else float(wrap_angle(yaw + math.pi))


def measured_heading_change(poses: np.ndarray, valid: np.ndarray) -> float:  # poses: [T, 4, 4], valid: [T]
    """Radians between the smallest and largest heading of the running median of the measured yaws
    (unwrapped): how far the registrations say the vehicle turns (a single wrong yaw does not count)."""
    if np.count_nonzero(valid) < 2:
        return 0.0
    yaws = _median_yaws(poses, valid)
    return float(np.max(yaws) - np.min(yaws))


def turn_config(config: SmoothingConfig, heading_change: float) -> SmoothingConfig:
    """``config`` with the turning curvature settings where the registrations turn at least
    ``config.turning_min_heading_change`` radians, else ``config`` itself."""
    if config.turning_curvature_sigma is None or heading_change < config.turning_min_heading_change:
        return config
    return replace(config, curvature_sigma=config.turning_curvature_sigma,
                   curvature_walk_rate=config.turning_curvature_walk_rate)


def _values_from(init: _InitialGuess) -> gtsam.Values:
    values = gtsam.Values()
    for t in range(len(init.speeds)):
        values.insert(F.pose_key(t), gtsam.Pose3(init.poses[t]))
        values.insert(F.speed_key(t), float(init.speeds[t]))
        values.insert(F.curvature_key(t), float(init.curvatures[t]))
    values.insert(F.SHARED_KEY, gtsam.Rot3(init.shared))
    return values


def _optimize(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values, iterations: int) -> gtsam.Values:
    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(iterations)
    return gtsam.LevenbergMarquardtOptimizer(graph, values, params).optimize()


def _outlier_threshold(errors: np.ndarray, config: SmoothingConfig) -> float:  # errors: [M]
    """The paper's threshold, widened to the sequence's own noise level when that is larger."""
    if not config.outlier_scale_adaptive:
        return config.outlier_threshold
    return max(config.outlier_threshold, config.adaptive_outlier_factor * float(np.median(errors)))


def _flag_outliers(
    measured: np.ndarray,  # [T, 4, 4] recentred measurements
    valid: np.ndarray,  # [T] bool
    values: gtsam.Values,
    config: SmoothingConfig,
    covariances: list[np.ndarray | None],  # per step: [3, 3] or None
) -> tuple[np.ndarray, float, np.ndarray]:
    """Whitened measurement errors [T] (NaN where none) of ``values``, the outlier threshold and
    the inlier mask [T]."""
    errors = np.full(len(measured), np.nan)
    for t in np.flatnonzero(valid):
        errors[t] = F.whitened_measurement_error(measured[t], values.atPose3(F.pose_key(int(t))), config, covariances[t])
    threshold = _outlier_threshold(errors[valid], config)
    return errors, threshold, valid & (errors <= threshold)


def smooth_trajectory(
    times: np.ndarray,  # [T] seconds, strictly increasing
    poses: np.ndarray,  # [T, 4, 4] measured poses (canonical -> world); rows where ~valid are ignored
    valid: np.ndarray,  # [T] bool, which measurements exist
    config: SmoothingConfig | None = None,
    translation_covariances: np.ndarray | None = None,  # [T, 3, 3] per measurement, its own frame (observability.py)
    heading: np.ndarray | None = None,  # [3] the vehicle's box axis in the canonical frame (amodal_centre.box_heading)
    ground: Callable[[np.ndarray], np.ndarray] | None = None,  # world xy [M, 2] -> ground height [M] (NaN: unknown)
) -> SmoothedTrajectory:
    """Robust coordinated-turn smoothing of one instance's measured poses.

    Returns smoothed poses at every step (also where measurements are missing, extrapolated by the
    motion model before the first and after the last measurement), speeds, curvatures, the shared
    rotation, the mask of measurements kept as inliers, and ``pose_at`` for any time in the span
    of the measurements. ``translation_covariances`` replace ``config.measurement_trans_sigma``
    per measurement (its translation is uncertain along directions its points do not measure).
    ``heading``, with ``config.heading_prior_sigma``, ties the direction of travel to the box axis.
    ``ground`` (e.g. ``GroundSurface.heights_at``), with ``config.ground_height_walk_rate``, ties
    each step's height change to the ground's under it (at positions from the measurements,
    ``local_line_positions``).
    Raises ValueError on malformed input (a programming error, not user input).
    """
    config = config or SmoothingConfig()
    times = np.asarray(times, dtype=np.float64)
    poses = np.asarray(poses, dtype=np.float64)
    valid = np.asarray(valid, dtype=bool)
    _validate(times, poses, valid)
    covariances: list[np.ndarray | None] = [None] * len(times)
    if translation_covariances is not None:
        if np.shape(translation_covariances) != (len(times), 3, 3):
            raise ValueError(f"smooth_trajectory: `translation_covariances` must have shape ({len(times)}, 3, 3), "
                             f"got {np.shape(translation_covariances)}")
        for t in np.flatnonzero(valid):
            covariances[t] = np.asarray(translation_covariances[t], np.float64)

    # Recentre (huge map coordinates): the factors see positions relative to the first valid one.
    origin = poses[np.flatnonzero(valid)[0], :3, 3].copy()
    measured = poses.copy()
    measured[:, :3, 3] -= origin
    measured[~valid] = np.eye(4)
    for t in np.flatnonzero(valid):  # re-orthonormalise: float noise in the inputs breaks Rot3
        u, _, vt = np.linalg.svd(measured[t, :3, :3])
        measured[t, :3, :3] = u @ np.diag([1.0, 1.0, np.linalg.det(u @ vt)]) @ vt

    usable = valid.copy()
    if config.gross_yaw_deviation is not None and valid.sum() >= 3:
        # Half-turn registration errors pull the CT states into loops that Huber cannot undo.
        usable &= ~gross_yaw_outliers(measured, valid, config.gross_yaw_deviation)
    init = _initial_guess(times, measured, usable)
    config = turn_config(config, measured_heading_change(measured, usable))
    ground_heights = None
    if ground is not None and config.ground_height_walk_rate is not None:
        xy = local_line_positions(times, measured[:, :2, 3], usable) + origin[:2]
        ground_heights = np.asarray(ground(xy), np.float64) - origin[2]
        # Where the ground says how the height changes, a registration's height only places the
        # vehicle above it: its vertical counts as unmeasured, so that a far view's vertical
        # drift neither bends the track nor gets the measurement (and its along-track
        # information) flagged as an outlier.
        for t in np.flatnonzero(valid & np.isfinite(ground_heights)):
            up = measured[t, :3, :3][2, :]  # world vertical in the measurement's own frame
            base = covariances[t] if covariances[t] is not None else config.measurement_trans_sigma ** 2 * np.eye(3)
            covariances[t] = base + config.degenerate_sigma ** 2 * np.outer(up, up)
    # Maps a measurement's translation error to metres at the configured sigma (identity when isotropic).
    to_measured = np.tile(np.eye(3), (len(times), 1, 1))  # [T, 3, 3]
    for t in np.flatnonzero(valid):
        if covariances[t] is not None:
            to_measured[t] = config.measurement_trans_sigma * np.linalg.inv(np.linalg.cholesky(covariances[t]))
    values = _values_from(init)

    def graph_of(use: np.ndarray) -> gtsam.NonlinearFactorGraph:
        return _build_graph(times, measured, use, init, config, covariances, heading, ground_heights)

    first = _optimize(graph_of(usable), values, config.first_pass_iterations)

    errors, threshold, inliers = _flag_outliers(measured, valid, first, config, covariances)
    inliers &= usable
    if inliers.sum() < config.reconverge_below_inlier_fraction * usable.sum():
        # The single first iteration did not converge: iterate it before trusting its residuals.
        first = _optimize(graph_of(usable), first, config.final_iterations)
        errors, threshold, inliers = _flag_outliers(measured, valid, first, config, covariances)
        inliers &= usable
    if not inliers.any():
        # Everything looks wrong: keep the measurement that agrees best rather than none.
        inliers[int(np.nanargmin(errors))] = True

    final = _optimize(graph_of(inliers), first, config.final_iterations)

    T = len(times)
    out_poses = np.empty((T, 4, 4))
    for t in range(T):
        out_poses[t] = final.atPose3(F.pose_key(t)).matrix()
    spanning = valid.copy()
    if config.span_max_distance is not None:
        # In each measurement's own frame, scaled by its certainty (a slide along a face it does
        # not measure counts for little).
        local = np.einsum("tji,tj->ti", measured[:, :3, :3], out_poses[:, :3, 3] - measured[:, :3, 3])
        gap = np.linalg.norm(np.einsum("tij,tj->ti", to_measured, local), axis=1)
        spanning &= gap <= config.span_max_distance
        if not spanning.any():
            spanning = inliers
    out_poses[:, :3, 3] += origin
    return SmoothedTrajectory(
        times=times.copy(),
        poses=out_poses,
        speeds=np.array([final.atDouble(F.speed_key(t)) for t in range(T)]),
        curvatures=np.array([final.atDouble(F.curvature_key(t)) for t in range(T)]),
        shared_rotation=final.atRot3(F.SHARED_KEY).matrix(),
        inliers=inliers,
        whitened_errors=errors,
        outlier_threshold=threshold,
        span=(float(times[spanning][0]), float(times[spanning][-1])),
    )
