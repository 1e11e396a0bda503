"""What a preprocessing run is worth: tracking of the moving vehicles (the observed protocol of
``eval/trajectory_eval.py``) and their box-corner errors at the training frames, with the seconds of
each stage (``bench_rule_ablation.py``, ``bench_preprocessing_scale.py``)."""

from __future__ import annotations

import time
from dataclasses import asdict
from pathlib import Path

import numpy as np

from idsplat_ns.eval.instance_pose_errors import match_instance
from idsplat_ns.eval.trajectory_eval import flatten_metrics, tracking_summary
from idsplat_ns.instances.modes import ground_truth_masks
from idsplat_ns.instances.runner import PreprocessConfig, run_preprocessing
from idsplat_ns.model.trajectories import InstanceTrajectories

from bench.box_errors import matching_box_poses, pose_errors


def moving_vehicle_pose_errors(tracks, train_scene) -> list[dict]:
    """Per dynamic instance that follows a moving annotated vehicle (``match_instance``): its mean
    box-corner, 3D and yaw errors at the training frames (``bench_smoothed_poses._errors``: after
    the constant canonical-to-box offset that fits best)."""
    out = []
    for inst in tracks.instances:
        if inst.num_valid < 3 or len(inst.canonical_points) == 0:
            continue
        index = match_instance(train_scene, inst)
        if index is None:
            continue
        box = train_scene.tracks[index]
        if not (box.moving and box.group == "vehicle"):
            continue
        boxes, size = matching_box_poses(inst, train_scene, tracks)
        poses = {int(k): inst.poses[k] for k in np.flatnonzero(inst.valid) if boxes[k] is not None}
        if len(poses) < 3:
            continue
        e3, _, _, ey, ec = pose_errors(poses, boxes, size)
        out.append({"instance": int(inst.instance_id), "object": str(box.track_id), "frames": len(poses),
                    "corner": ec, "error_3d": e3, "yaw_deg": ey})
    return out


def evaluate(scene, train: set[int], config: PreprocessConfig, cache: Path) -> dict:
    """Preprocess the ``train`` frames of one street with ``config`` (as ``instance_tracks_for_mode``
    does; stages cached in ``cache``) and measure the result: tracking of the whole street (MOTA@2m,
    MOTP@2m and the rest in ``metrics``), the moving vehicles' mean box-corner error, the instance
    counts and the seconds of each stage."""
    train_scene = scene.subset(train)
    t0 = time.perf_counter()
    result = run_preprocessing(train_scene, ground_truth_masks(scene, config), cache, progress=False, verbose=False)
    seconds = time.perf_counter() - t0
    tracks = result.tracks
    summary = tracking_summary(scene, InstanceTrajectories.from_instance_tracks(tracks).positions_at)
    flat = flatten_metrics(summary)
    errors = moving_vehicle_pose_errors(tracks, train_scene)
    return {
        "mota": flat.get("mota@2m", float("nan")), "motp": flat.get("motp@2m", float("nan")), "metrics": flat,
        "summary": {f"{th:g}": asdict(m) for th, m in summary.items()},
        "corner": float(np.mean([e["corner"] for e in errors])) if errors else float("nan"),
        "instances": errors, "dynamic": len(tracks.instances), "static": len(tracks.static_instances),
        "seconds": seconds, "stages": [[t.name, t.seconds, t.cached] for t in result.timings],
    }
