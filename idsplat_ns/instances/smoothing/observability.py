"""Which directions of a frame's position its registration measures (ours, not in the paper).

Registration aligns surfaces. Along a direction that no surface of the frame's points faces, the
fit is flat: the points slide along their own face at no cost, and whatever translation RANSAC or
ICP ends on there is not a measurement. A car seen only from its side measures nothing along its
length (nor up); seen from its side and front, everything but up. On the synthetic street (seed
7), a turning car's six far frames (19-79 points of its right side) registered 1-2.5 m along its
track, consistently enough for the smoother to follow them as a slowing car.

The point-to-plane information of a frame in direction ``u`` is the share of its points whose
surface faces ``u``: ``u^T A u`` with ``A = mean(n n^T)`` over its points (unit surface normals,
zero where the neighbourhood is not a surface). A direction is not measured when its information
is below ``degenerate_ratio`` of the frame's strongest direction's (the degeneracy test of Zhang
et al., ICRA 2016, on normalised eigenvalues) and fewer than ``min_facing_points`` points face
it. Where other frames measure it, the smoother gives it ``degenerate_sigma`` instead of the
paper's measurement sigma, and the CT motion model carries the position there.
"""

from __future__ import annotations

import numpy as np

from idsplat_ns.instances.registration import frame_surface_normals


def frame_information(
    points: np.ndarray,  # [N, 3] canonical points of an instance
    point_frames: np.ndarray,  # [N] the frame each point was seen in
    num_frames: int,
    k: int = 12,
) -> np.ndarray:  # -> [F, 3, 3]
    """``A_f = mean(n n^T)`` over frame ``f``'s points, in the canonical frame (zero for frames
    without points). The normals come from each frame's own points: the merged points of many
    frames are no surface at that scale (a rear face registered a few centimetres apart in each
    frame is a slab, whose neighbourhoods gave 41% of a followed car's points a sideways normal
    where its own points gave 99% a rearward one)."""
    out = np.zeros((num_frames, 3, 3))
    frames = np.asarray(point_frames, np.int64)
    normals = frame_surface_normals(points, frames, k)
    for f in np.unique(frames):
        if 0 <= f < num_frames:
            own = normals[frames == f]
            out[f] = own.T @ own / len(own)
    return out


def measured_axes(
    information: np.ndarray,  # [3, 3] a frame's A
    degenerate_ratio: float,
    num_points: int = 0,
    min_facing_points: float = np.inf,
) -> tuple[np.ndarray, np.ndarray]:  # -> [3, 3] axes as columns, [3] bool measured
    """Principal axes of ``information`` and which of them the registration measures: those with
    at least ``degenerate_ratio`` of the strongest axis's information, or with at least
    ``min_facing_points`` of the frame's ``num_points`` points facing them (a near side view
    has its wheel arches, mirrors and corners). A frame without any surface keeps every axis
    (nothing is known about its geometry: the paper's isotropic measurement)."""
    values, axes = np.linalg.eigh(information)
    strongest = float(values[-1])
    if strongest <= 1e-9:
        return np.eye(3), np.ones(3, bool)
    return axes, (values >= degenerate_ratio * strongest) | (values * num_points >= min_facing_points)


def translation_covariances(
    points: np.ndarray,  # [N, 3] canonical points of an instance
    point_frames: np.ndarray,  # [N] the frame each point was seen in
    num_frames: int,
    sigma: float,
    degenerate_ratio: float,
    degenerate_sigma: float,
    min_anchor_frames: int = 2,
    min_frame_points: int = 24,
    min_facing_points: float = 10.0,
) -> np.ndarray:  # -> [F, 3, 3] canonical frame
    """Covariance of each frame's registered translation: ``sigma`` along the directions its
    surfaces measure, ``degenerate_sigma`` along those it does not but at least
    ``min_anchor_frames`` other frames do (the canonical frame is shared, so their directions
    compare). A direction nothing measures (a car followed from behind shows its rear in every
    frame: nothing measures it sideways) keeps ``sigma``: the motion model would have nothing to
    carry it by, and the feature matches on the rear's texture did place it. Frames with fewer
    than ``min_frame_points`` points measure no direction and anchor nothing: their
    neighbourhoods are the whole view, not its surfaces (14 points of a car's front "measured"
    every direction), and their registration slides most.

    The unmeasured directions of a frame form a subspace (a side view measures neither along nor
    up) whose eigenvectors are arbitrary within it; the anchored ones are found inside it, from
    how many other frames measure each direction there (a frame measuring it counts 1)."""
    out = np.tile(np.eye(3) * sigma**2, (num_frames, 1, 1))
    frames = np.asarray(point_frames, np.int64)
    information = frame_information(np.asarray(points, np.float64), frames, num_frames)
    numbers = np.bincount(frames[(frames >= 0) & (frames < num_frames)], minlength=num_frames)
    seen = [int(f) for f in np.flatnonzero(numbers > 0)]
    projectors = {}
    for f in seen:
        if numbers[f] < max(min_frame_points, 3):
            projectors[f] = (np.zeros((3, 3)), np.eye(3))
            continue
        axes, measured = measured_axes(information[f], degenerate_ratio, int(numbers[f]), min_facing_points)
        projectors[f] = (axes[:, measured] @ axes[:, measured].T, axes[:, ~measured])
    total = sum((measured for measured, _ in projectors.values()), np.zeros((3, 3)))  # [3, 3]
    for f in seen:
        unmeasured = projectors[f][1]  # [3, K]
        if unmeasured.shape[1] == 0:
            continue
        others = total - projectors[f][0]
        counts, within = np.linalg.eigh(unmeasured.T @ others @ unmeasured)  # [K], [K, K]
        directions = unmeasured @ within  # [3, K]
        anchored = directions[:, counts >= min_anchor_frames - 1e-6]
        out[f] += (degenerate_sigma**2 - sigma**2) * anchored @ anchored.T
    return out
