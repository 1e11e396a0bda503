"""What a scene is modelled with, and why: cameras, lidar, instances moving and static, Gaussians
and parameters per group. Printed once before training and written as ``scene_summary.json`` in
the run folder, beside ``nerfstudio_models/`` (:mod:`idsplat_ns.nerfstudio.model`).

The rules it reports (the model follows them; this module only describes):

* a camera with training images gets a sensor embedding (and a time offset when instances move);
  one without gets neither;
* lidar sweeps in the training frames give a lidar head and the lidar losses; none, neither;
* an instance that moves gets a trajectory; one that does not (parked, stopped all sequence,
  seen in one frame) is static background with no trajectory; no moving instance, no trajectory
  parameters and no camera time offsets.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Optional

import torch
from torch import nn

from idsplat_ns.atomic import atomic_path
from idsplat_ns.instances.static_conversion import StaticConversionConfig, static_reason
from idsplat_ns.instances.tracks import InstanceTracks

FILE_NAME = "scene_summary.json"


@dataclass
class StaticInstance:
    instance_id: int
    label: str
    reason: str  # why it has no trajectory


@dataclass
class SceneSummary:
    """The JSON's content (``asdict``)."""

    cameras_used: list[str]
    cameras_unused: list[str]  # no training image: no embedding, no time offset
    lidar_training_sweeps: int
    lidar_head: bool
    instance_mode: str
    moving_instances: list[int]  # with a trajectory
    static_instances: list[StaticInstance]  # without one: static Gaussians
    gaussians: dict[str, int]  # "total", "static", "instance <id>"
    parameters: dict[str, int]  # per optimiser group
    trajectory_parameters: int  # learnt (0 when trajectories are frozen)
    lidar_head_parameters: int
    embedding_parameters: int
    camera_time_offset_parameters: int
    step: Optional[int] = None  # training step of the counts (None: before training)
    deformable_instances: list[int] = field(default_factory=list)  # moving and non-rigid (model/deformation.py)
    notes: list[str] = field(default_factory=list)


def parameter_counts(groups: dict[str, list[nn.Parameter]]) -> dict[str, int]:
    """Number of values per optimiser group."""
    return {name: int(sum(p.numel() for p in params)) for name, params in groups.items()}


def gaussian_counts(instance_ids: torch.Tensor) -> dict[str, int]:  # instance_ids: [N] int
    """``{"total", "static", "instance <id>"...}`` from the Gaussians' instance IDs."""
    ids, counts = torch.unique(instance_ids.detach().cpu(), return_counts=True)
    per = dict(zip(ids.tolist(), counts.tolist()))
    out = {"total": int(instance_ids.numel()), "static": int(per.pop(0, 0))}
    out.update({f"instance {i}": int(c) for i, c in sorted(per.items())})
    return out


def static_instances(tracks: Optional[InstanceTracks], config: StaticConversionConfig) -> list[StaticInstance]:
    """The instances of ``tracks`` that are modelled as static Gaussians, with the reason."""
    if tracks is None:
        return []
    return [StaticInstance(int(i.instance_id), str(i.label), static_reason(i, config, tracks.metadata))
            for i in tracks.static_instances]  # fmt: skip


def summarise(
    *,
    camera_names: list[str],
    used_cameras: set[str],
    lidar_sweeps: int,
    lidar_head: Optional[nn.Module],
    instance_mode: str,
    tracks: Optional[InstanceTracks],
    trajectories: Optional[nn.Module],
    static_config: StaticConversionConfig,
    instance_ids: torch.Tensor,  # [N] the Gaussians' instance IDs
    groups: dict[str, list[nn.Parameter]],
    embedding: nn.Module,
    camera_time_offset: Optional[nn.Parameter],
    step: Optional[int] = None,
    deformation: Optional[nn.Module] = None,
) -> SceneSummary:
    """Collect the summary from the parts of a built model (see :mod:`idsplat_ns.nerfstudio.model`)."""
    moving = [] if trajectories is None else [int(i) for i in trajectories.instance_ids.tolist()]
    # Learnt values only: --pipeline.model.refine-trajectories False freezes them (0 here).
    traj = 0 if trajectories is None else sum(p.numel() for p in trajectories.parameters() if p.requires_grad)
    notes = []
    if tracks is not None and tracks.metadata.get("source") == "oracle_ground_truth_boxes" and tracks.metadata.get("moving_only"):
        notes.append("oracle: annotated objects not flagged as moving are background, not instances")
    return SceneSummary(
        cameras_used=[c for c in camera_names if c in used_cameras],
        cameras_unused=[c for c in camera_names if c not in used_cameras],
        lidar_training_sweeps=int(lidar_sweeps),
        lidar_head=lidar_head is not None,
        instance_mode=instance_mode,
        moving_instances=moving,
        static_instances=static_instances(tracks, static_config),
        gaussians=gaussian_counts(instance_ids),
        parameters=parameter_counts(groups),
        trajectory_parameters=int(traj),
        lidar_head_parameters=0 if lidar_head is None else int(sum(p.numel() for p in lidar_head.parameters())),
        embedding_parameters=int(sum(p.numel() for p in embedding.parameters())),
        camera_time_offset_parameters=0 if camera_time_offset is None else int(camera_time_offset.numel()),
        step=step,
        deformable_instances=[] if deformation is None else [int(i) for i in deformation.instance_ids.tolist()],
        notes=notes,
    )


def _ids(ids: list[int]) -> str:
    return ", ".join(str(i) for i in ids) if ids else "none"


def summary_lines(s: SceneSummary) -> list[str]:
    """The printed form: one line per part, each with what is modelled and why."""
    emb = s.embedding_parameters // max(len(s.cameras_used), 1)
    cams = f"cameras: {len(s.cameras_used)} with training images ({', '.join(s.cameras_used)}), each with a sensor embedding of {emb}"
    if s.cameras_unused:
        cams += f"; {len(s.cameras_unused)} without ({', '.join(s.cameras_unused)}): no embedding"
    if s.lidar_head:
        lidar = f"lidar: {s.lidar_training_sweeps} training sweeps -> lidar head ({s.lidar_head_parameters} parameters) and lidar losses"
    else:
        lidar = "lidar: no training sweep (none loaded, or --pipeline.model.lidar.enabled False) -> no lidar head, no lidar losses"
    if s.moving_instances:
        inst = (f"instances ({s.instance_mode}): {len(s.moving_instances)} moving with trajectories ({_ids(s.moving_instances)}; "
                f"{s.trajectory_parameters} parameters"
                + (f", camera time offsets {s.camera_time_offset_parameters}" if s.camera_time_offset_parameters else "") + ")")
    else:
        inst = f"instances ({s.instance_mode}): none moving -> no trajectory parameters, no camera time offsets"
    lines = [cams, lidar, inst]
    if s.deformable_instances:
        lines.append(f"  non-rigid: {_ids(s.deformable_instances)} deform over time "
                     f"({s.parameters.get('deformation', 0)} parameters, --pipeline.model.deformation)")
    for st in s.static_instances:
        lines.append(f"  instance {st.instance_id} ({st.label}) static, no trajectory: {st.reason}")
    lines += [f"  note: {n}" for n in s.notes]
    on_instances = s.gaussians["total"] - s.gaussians["static"]
    lines.append(f"Gaussians: {s.gaussians['total']} ({s.gaussians['static']} static, {on_instances} on instances)")
    lines.append("parameters: " + ", ".join(f"{k} {v}" for k, v in s.parameters.items()))
    return lines


def write_summary(s: SceneSummary, folder: Path) -> Path:
    """``folder/scene_summary.json``, written atomically."""
    path = Path(folder) / FILE_NAME
    with atomic_path(path) as tmp:
        tmp.write_text(json.dumps(asdict(s), indent=2) + "\n")
    return path
