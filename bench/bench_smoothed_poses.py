"""Pose accuracy of the CT smoother's variants on the synthetic street: every registered instance
that follows an annotated box is smoothed with each variant, and its poses at the training frames
are compared with the box (after the constant canonical-to-box offset that fits best: the
canonical frame is arbitrary). Prints the mean 3D, height and tilt errors per variant.

    .venv/bin/python bench/bench_smoothed_poses.py --preset small --seeds 0 1 2 --work /tmp/trk

Registrations come from the same preprocessing as ``ns-train idsplat`` up to smoothing: the moving
instances after the parked ones are converted (cached in ``--work``, the same layout as
``bench_tracking.py``). Variants: ``default`` (``SmoothingConfig()``), ``paper``
(the paper's isotropic motion sigmas), ``tilt-only`` (the tilt sigma without the vertical one) and
``two-sided`` (without ``degenerate_one_sided``).
"""

from __future__ import annotations


import numpy as np
from scipy.spatial.transform import Rotation
from tqdm import tqdm

from idsplat_ns.instances.amodal_centre import AmodalCentreConfig
from idsplat_ns.instances.modes import builtin_mask_stand_in
from idsplat_ns.instances.runner import PreprocessConfig, measurement_covariances, run_preprocessing
from idsplat_ns.instances.smoothing import SmoothingConfig, smooth_trajectory
from idsplat_ns.instances.tracks import InstanceTrack, InstanceTracks

from _streets import street_arguments, training_streets  # bench/ is on the path when run as a script

VARIANTS = {
    "default": SmoothingConfig(),
    "paper": SmoothingConfig(motion_vertical_sigma=None, motion_tilt_sigma=None),
    "tilt-only": SmoothingConfig(motion_vertical_sigma=None),
    "two-sided": SmoothingConfig(degenerate_one_sided=False),
}


def _matching_box_poses(inst: InstanceTrack, scene, tracks: InstanceTracks) -> list | None:
    """Per step the pose [4, 4] (or None) of the annotated box nearest the instance at its middle
    registered step, if within 4 m."""
    good = np.flatnonzero(inst.valid)
    k = good[len(good) // 2]
    best = None
    for box in scene.tracks:
        pose = box.pose_at_frame(int(tracks.frame_indices[k]))
        if pose is not None:
            d = float(np.linalg.norm(pose[:3, 3] - inst.poses[k, :3, 3]))
            if best is None or d < best[0]:
                best = (d, box)
    if best is None or best[0] > 4.0:
        return None
    return [best[1].pose_at_frame(int(f)) for f in tracks.frame_indices]


def _errors(poses: dict, boxes: list) -> tuple[float, float, float]:  # poses: step -> [4, 4]
    """Mean 3D [m], height [m] and tilt [deg] error after the best constant offset."""
    offsets = [np.linalg.inv(P) @ boxes[k] for k, P in poses.items()]
    C = np.eye(4)
    C[:3, 3] = np.mean([o[:3, 3] for o in offsets], axis=0)
    C[:3, :3] = Rotation.from_matrix(np.stack([o[:3, :3] for o in offsets])).mean().as_matrix()
    e3, ez, et = [], [], []
    for k, P in poses.items():
        X, B = P @ C, boxes[k]
        local = B[:3, :3].T @ (X[:3, 3] - B[:3, 3])
        tilt = Rotation.from_matrix(B[:3, :3].T @ X[:3, :3]).as_rotvec()[:2]
        e3.append(np.linalg.norm(local))
        ez.append(abs(local[2]))
        et.append(np.degrees(np.linalg.norm(tilt)))
    return float(np.mean(e3)), float(np.mean(ez)), float(np.mean(et))


def _smoothed_poses(inst: InstanceTrack, times: np.ndarray, config: SmoothingConfig) -> dict:
    """Smoothed poses at the registered training frames (within the smoothed span)."""
    covariances = measurement_covariances(inst, len(times), config)
    sm = smooth_trajectory(inst.measurement_times(times), inst.poses, inst.valid, config, covariances)
    out = {}
    for k in np.flatnonzero(inst.valid):
        pose = sm.pose_at(float(times[k]), margin=0.1)
        if pose is not None:
            out[int(k)] = pose
    return out


def main() -> None:
    args = street_arguments(__doc__.splitlines()[0]).parse_args()
    results: dict[str, list] = {name: [] for name in VARIANTS}
    for seed, scene, train, cache in tqdm(training_streets(args, "idsplat_poses_"), total=len(args.seeds), desc="streets"):
        # The smoother's input: registered, parked ones converted, no smoothing, origins as registered.
        config = builtin_mask_stand_in(scene, PreprocessConfig(smoothing=None, amodal=AmodalCentreConfig(enabled=False)))
        registered = run_preprocessing(scene.subset(train), config, cache, progress=False,
                                       verbose=False).tracks
        times = np.asarray(registered.frame_times, np.float64)
        for inst in registered.instances:
            if inst.num_valid < 3 or inst.point_frames is None:
                continue
            boxes = _matching_box_poses(inst, scene, registered)
            if boxes is None:
                continue
            per_variant = {}
            for name, config in VARIANTS.items():
                poses = {k: P for k, P in _smoothed_poses(inst, times, config).items() if boxes[k] is not None}
                per_variant[name] = _errors(poses, boxes) if len(poses) >= 3 else None
            if all(v is not None for v in per_variant.values()):  # the same instances in every row
                for name, v in per_variant.items():
                    results[name].append(v)
    print("\n| variant | instances | mean 3D error m | median 3D error m | mean height error m | mean tilt error deg |")
    print("|---|---|---|---|---|---|")
    for name, rows in results.items():
        a = np.array(rows)
        print(f"| {name} | {len(a)} | {a[:, 0].mean():.3f} | {np.median(a[:, 0]):.3f} | {a[:, 1].mean():.3f} | {a[:, 2].mean():.2f} |")


if __name__ == "__main__":
    main()
