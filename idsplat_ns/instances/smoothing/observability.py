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
    frames = np.asarray(point_frames, np.int64)
    return _information(frame_surface_normals(points, frames, k), frames, num_frames)


def _information(
    normals: np.ndarray,  # [N, 3] unit surface normals (zero rows: no surface)
    frames: np.ndarray,  # [N] int
    num_frames: int,
) -> np.ndarray:  # -> [F, 3, 3]
    out = np.zeros((num_frames, 3, 3))
    for f in np.unique(frames):
        if 0 <= f < num_frames:
            own = normals[frames == f]
            out[f] = own.T @ own / len(own)
    return out


def one_sided_directions(
    points: np.ndarray,  # [N, 3] canonical points of an instance
    point_frames: np.ndarray,  # [N] int
    normals: np.ndarray,  # [N, 3] each frame's own surface normals
    num_frames: int,
    min_frame_points: int = 24,
    min_facing_points: float = 10.0,
    min_anchor_frames: int = 2,
) -> list[list[np.ndarray]]:  # -> per frame, unit directions [3] in the canonical frame
    """Per frame, the instance axes it measures only through faces that the frames measuring them
    elsewhere never see together with its own.

    Along an axis of the instance (its faces' principal directions: a car's length, width and
    height), a frame measures through the faces on one side of the middle or the other (a car's
    front or its rear). When no frame sees both, nothing in the registrations ties the two faces
    together: a car seen first from the front and side, then from the rear and side, was merged
    through its side, along which it slides, and the two groups of frames disagree by how far it
    slid (seed 9: the front frames 0.6 m ahead of the rear ones, the merged car 0.4 m short). The
    smaller group is then left to the motion along that axis, where the larger one (at least
    ``min_anchor_frames`` frames) measures it. A frame sees a side when its points facing the axis
    there weigh ``min_facing_points`` (each point counts ``(n . u)^2``); frames under
    ``min_frame_points`` points see nothing."""
    points = np.asarray(points, np.float64)
    frames = np.asarray(point_frames, np.int64)
    inside = (frames >= 0) & (frames < num_frames)
    out: list[list[np.ndarray]] = [[] for _ in range(num_frames)]
    if not inside.any():
        return out
    points, frames, normals = points[inside], frames[inside], normals[inside]
    usable = np.bincount(frames, minlength=num_frames) >= max(min_frame_points, 3)
    _, axes = np.linalg.eigh(normals.T @ normals)
    for u in axes.T:
        along = points @ u
        middle = float(np.median(along))
        weight = (normals @ u) ** 2
        high = usable & (np.bincount(frames, weight * (along >= middle), num_frames) >= min_facing_points)
        low = usable & (np.bincount(frames, weight * (along < middle), num_frames) >= min_facing_points)
        only_high, only_low = np.flatnonzero(high & ~low), np.flatnonzero(low & ~high)
        if (high & low).any() or len(only_high) == len(only_low) or min(len(only_high), len(only_low)) == 0:
            continue  # one side, the two tied by a frame, or no majority to follow
        minority, majority = sorted((only_high, only_low), key=len)
        if len(majority) < min_anchor_frames:
            continue
        for f in minority:
            out[int(f)].append(u.copy())
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
    one_sided_faces: bool = True,
    vertical_sigma: float | None = None,
    sparse_frame_points: int | None = None,
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
    how many other frames measure each direction there (a frame measuring it counts 1).

    With ``one_sided_faces``, a frame's :func:`one_sided_directions` get ``degenerate_sigma`` too
    (what it measures there is tied to the other frames through nothing but a slide).

    With ``vertical_sigma``, a frame's variance along the canonical vertical is capped at its
    square (information is added along z where a slide left it larger).

    With ``sparse_frame_points``, a frame of fewer points (but at least ``min_frame_points``)
    leaves all its unmeasured directions free, anchored or not: for instances whose heading and
    height other factors carry (the smoother's heading prior and ground)."""
    out = np.tile(np.eye(3) * sigma**2, (num_frames, 1, 1))
    points = np.asarray(points, np.float64)
    frames = np.asarray(point_frames, np.int64)
    normals = frame_surface_normals(points, frames, 12)
    information = _information(normals, frames, num_frames)
    one_sided = (one_sided_directions(points, frames, normals, num_frames, min_frame_points, min_facing_points,
                                      min_anchor_frames) if one_sided_faces else [[] for _ in range(num_frames)])
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
        free = np.zeros((3, 0))
        if unmeasured.shape[1] > 0:
            others = total - projectors[f][0]
            counts, within = np.linalg.eigh(unmeasured.T @ others @ unmeasured)  # [K], [K, K]
            anchored = counts >= min_anchor_frames - 1e-6
            if sparse_frame_points is not None and numbers[f] < sparse_frame_points:
                anchored[:] = True  # a sparse far view slides: the motion carries it, anchored or not
            free = (unmeasured @ within)[:, anchored]  # [3, K'] orthonormal
        for u in one_sided[f]:
            rest = u - free @ (free.T @ u)  # the part of u not yet free
            if np.linalg.norm(rest) > 0.7:
                free = np.concatenate([free, (rest / np.linalg.norm(rest))[:, None]], 1)
        out[f] += (degenerate_sigma**2 - sigma**2) * free @ free.T
        if vertical_sigma is not None:
            out[f] = cap_vertical_variance(out[f], vertical_sigma)
    return out


def cap_vertical_variance(covariance: np.ndarray, sigma: float) -> np.ndarray:  # [3, 3] -> [3, 3]
    """``covariance`` with information added along z so that its z variance is at most
    ``sigma**2`` (Sherman-Morrison: adding ``a e e^T`` to the information turns a variance ``c``
    along ``e`` into ``c / (1 + a c)``); unchanged where it already is."""
    c = float(covariance[2, 2])
    if c <= sigma**2:
        return covariance
    e = np.array([0.0, 0.0, 1.0])
    a = 1.0 / sigma**2 - 1.0 / c
    Ce = covariance @ e
    return covariance - a * np.outer(Ce, Ce) / (1.0 + a * c)
