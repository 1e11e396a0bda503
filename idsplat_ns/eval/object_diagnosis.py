"""Which annotated object a method lost, when and how close to the ego: one record per moving road
user, frame by frame, from the same matching as the CLEAR-MOT metrics (``ns-eval``'s
``objects`` list, its summary and the ``objects_timeline.png`` plot).

A frame counts for an object where the *observed* protocol counts it (in a camera image, within the
lidar range instances are lifted from, at least 10 lidar points: :class:`ObservedFilter`). It is
*tracked* there when a prediction is matched to it at the threshold (2 m, the headline), *lost*
otherwise. The distance to the ego is from the box centre to the frame's lidar. An object's DPSNR is
the PSNR of its own pixels over the held-out images (errors pooled over all its pixels), where the
caller has measured them.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Optional

import numpy as np
import torch
import torch.nn.functional as F
from torch import Tensor

from idsplat_ns.data.scene import Scene
from idsplat_ns.data.tracks import ROAD_USER_CLASSES
from idsplat_ns.eval.tracking import object_matches
from idsplat_ns.eval.trajectory_eval import ObservedFilter, predicted_positions, scene_annotations

NEAR_EGO = 10.0
"""Metres: an object closer than this to the ego's lidar is *near* (the passes that matter most)."""


@dataclass
class ObjectRecord:
    """One annotated moving road user over the frames the observed protocol counts."""

    track_id: str
    name: str  # the dataset's name of the object where it has one (the built-in street's manoeuvre), else its label
    label: str
    group: str  # vehicle, pedestrian, cyclist
    frames: list[int] = field(default_factory=list)  # counted frames, in order
    tracked: list[bool] = field(default_factory=list)  # matched at the threshold, per counted frame
    distance_to_ego: list[float] = field(default_factory=list)  # metres, per counted frame
    error: list[float] = field(default_factory=list)  # metres to the matched prediction (NaN where lost)
    # metres of that error along the object's heading (signed, ahead > 0; NaN where lost): a view of
    # its side alone fixes nothing along it, so a pass beside the ego slides there
    along_error: list[float] = field(default_factory=list)
    predictions: list = field(default_factory=list)  # matched prediction id per counted frame (None where lost)
    dpsnr: Optional[float] = None  # PSNR of its pixels over the held-out images (dB)
    pixels: int = 0  # its pixels in the held-out images

    @property
    def frames_lost(self) -> int:
        return sum(not t for t in self.tracked)

    @property
    def frames_lost_near(self) -> int:
        """Lost frames closer than :data:`NEAR_EGO` to the ego."""
        return sum(not t and d < NEAR_EGO for t, d in zip(self.tracked, self.distance_to_ego))

    @property
    def frames_near(self) -> int:
        return sum(d < NEAR_EGO for d in self.distance_to_ego)

    @property
    def longest_lost(self) -> int:
        """The longest run of consecutive counted frames where it is lost."""
        best = run = 0
        for t in self.tracked:
            run = 0 if t else run + 1
            best = max(best, run)
        return best

    @property
    def fragments(self) -> int:
        """Distinct predictions matched to it (1: one track throughout; more: it was split)."""
        return len({p for p in self.predictions if p is not None})

    def as_dict(self) -> dict:
        """The JSON record (ns-eval's ``objects`` list)."""
        near = self.distance_to_ego
        return {
            "track_id": self.track_id, "name": self.name, "label": self.label, "class": self.group,
            "frames": len(self.frames), "frames_tracked": len(self.frames) - self.frames_lost,
            "frames_lost": self.frames_lost, "frames_near": self.frames_near, "frames_lost_near": self.frames_lost_near,
            "longest_lost": self.longest_lost, "fragments": self.fragments,
            "min_distance_to_ego": round(min(near), 2) if near else None,
            "mean_error": _mean(self.error), "mean_along_error": _mean(np.abs(self.along_error)), "dpsnr": None if self.dpsnr is None else round(self.dpsnr, 2),
            "lost_frames": [f for f, t in zip(self.frames, self.tracked) if not t],
        }  # fmt: skip


def _mean(values: list[float]) -> Optional[float]:
    v = np.asarray(values, dtype=np.float64)
    v = v[np.isfinite(v)]
    return round(float(v.mean()), 3) if v.size else None


def object_names(scene: Scene) -> dict[str, str]:
    """``{track_id: name}`` from the dataset's instance file where it names its objects (the
    built-in street names each road user by its manoeuvre)."""
    out = {}
    for info in (scene.metadata.get("gt_instances") or {}).values():
        if info.get("uuid") and info.get("name"):
            out[str(info["uuid"])] = str(info["name"])
    return out


def diagnose_objects(
    scene: Scene,
    positions_at: Callable[[float], dict],
    threshold: float = 2.0,
    observed: ObservedFilter = ObservedFilter(),
    object_errors: Optional[Mapping[str, tuple[float, int]]] = None,
) -> list[ObjectRecord]:
    """A record per annotated moving road user that some frame counts (every class), matched at
    ``threshold`` against the predicted instance positions ``positions_at(t)``. ``object_errors``
    ``{track_id: (summed squared error, pixel count)}`` over the held-out images gives each its
    DPSNR (RGB in [0, 1]; the squared error summed over pixels and channels)."""
    annotations = [a for a in scene_annotations(scene, observed) if a.observed and a.track.moving and a.track.group in ROAD_USER_CLASSES]
    gt: dict = {int(f): {} for f in scene.frame_indices}
    for a in annotations:
        gt[a.frame][a.track.track_id] = a.pose[:3, 3].copy()
    pred = predicted_positions(scene, positions_at)
    matches = object_matches(gt, pred, threshold)
    # The frame's lidar where it has one, else its ego pose.
    ego = {int(f): scene.ego_poses[i, :3, 3] for i, f in enumerate(scene.frame_indices)}
    ego.update({int(s.frame_index): s.sensor_to_world[:3, 3] for s in scene.lidar})
    names = object_names(scene)
    records: dict[str, ObjectRecord] = {}
    for a in sorted(annotations, key=lambda a: a.frame):
        tid = a.track.track_id
        rec = records.setdefault(tid, ObjectRecord(tid, names.get(tid, a.track.label), a.track.label, a.track.group))
        hit = matches.get((a.frame, tid))
        rec.frames.append(a.frame)
        rec.tracked.append(hit is not None)
        rec.predictions.append(None if hit is None else hit[0])
        rec.error.append(float("nan") if hit is None else hit[1])
        offset = np.full(3, np.nan) if hit is None else np.asarray(pred[a.frame][hit[0]], np.float64) - a.pose[:3, 3]
        rec.along_error.append(float(offset @ a.pose[:3, 0]))
        rec.distance_to_ego.append(float(np.linalg.norm(a.pose[:3, 3] - ego[a.frame])))
    for tid, (sse, count) in (object_errors or {}).items():
        if tid in records and count > 0:
            mse = sse / (3 * count)
            records[tid].dpsnr = float(10 * np.log10(1.0 / max(mse, 1e-12)))
            records[tid].pixels = int(count)
    return sorted(records.values(), key=lambda r: (r.group != "vehicle", -r.frames_lost, r.track_id))


def diagnosis_summary(records: list[ObjectRecord], min_gap: int = 3) -> dict:
    """Headline numbers of the records (vehicles): frames lost near the ego, stretches longer than
    ``min_gap`` frames, split objects."""
    vehicles = [r for r in records if r.group == "vehicle"]
    frames = sum(len(r.frames) for r in vehicles)
    near = sum(r.frames_near for r in vehicles)
    return {
        "objects_vehicles": len(vehicles),
        "objects_frames_lost": sum(r.frames_lost for r in vehicles),
        "objects_frames": frames,
        "objects_frames_lost_near": sum(r.frames_lost_near for r in vehicles),
        "objects_frames_near": near,
        f"objects_lost_over_{min_gap}_frames": sum(r.longest_lost > min_gap for r in vehicles),
        "objects_split": sum(r.fragments > 1 for r in vehicles),
    }


def object_pixel_errors(
    pred: Tensor,  # [H, W, 3] rendered image in [0, 1]
    gt: Tensor,  # [H, W, 3] recorded image
    object_map: Tensor,  # [h, w] index into object_ids, -1 where no annotated mover
    object_ids: list,
) -> dict:
    """``{track_id: (squared error summed over its pixels and channels, pixel count)}`` of each
    annotated moving road user in an evaluation image; the map follows the render's size (nearest
    pixel) where they differ."""
    sq = (pred - gt).square().sum(-1)  # [H, W]
    index = object_map.to(sq.device).long()
    if index.shape != sq.shape:
        index = F.interpolate(index[None, None].float(), size=sq.shape, mode="nearest")[0, 0].long()
    hit = index >= 0
    sse = torch.zeros(len(object_ids), device=sq.device).index_add_(0, index[hit], sq[hit])
    count = torch.bincount(index[hit], minlength=len(object_ids))
    return {object_ids[k]: (float(sse[k]), int(count[k])) for k in range(len(object_ids)) if int(count[k]) > 0}
