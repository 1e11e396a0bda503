"""Issue 7 end to end on the tiny street (CPU): instances beat the static baseline in dynamic
regions, trajectory refinement moves poses towards the truth, ns-eval reports tracking."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

pytest.importorskip("nerfstudio")

# At 300 steps the gain over static was 0.4-1.2 dB across training seeds (the tiny street's 6
# held-out images); at 600 it was 1.7 dB on both seeds tried.
STEPS = 400
# One thread: with two, CPU reductions are summed in a varying order and MCMC amplifies the
# difference (static DPSNR 20.98 and 22.36 dB in two runs of the same seed). With one, repeated runs
# are equal to the bit: static 20.93, self-supervised 23.45 dB at 400 steps. On a later fresh
# install (same engine, dependencies installed anew) the same seed gave 22.42 and 23.30 dB (600
# steps: 22.53 and 23.17): the static baseline's DPSNR moves by more than 1 dB with small numeric
# changes, so the bar is a DPSNR gain of 0.5 dB (and a PSNR no more than 0.5 dB lower).
TRAIN_THREADS = 1


def _train(data: Path, out: Path, mode: str, steps: int = STEPS, perturb: float = 0.0):
    from nerfstudio.scripts.train import _set_random_seed

    from method_configs.idsplat import make_trainer_config

    cfg = make_trainer_config("idsplat-fast", steps, (steps // 6, steps // 3), fast=True)
    cfg.pipeline.datamanager.dataparser.data = data
    cfg.pipeline.datamanager.instance_mode = mode
    # tiny has 10 frames: 8 train so that moving cars keep enough lidar points over time
    cfg.pipeline.datamanager.dataparser.train_fraction = 0.8
    cfg.pipeline.model.max_lidar_points = 12_000
    cfg.pipeline.model.num_random_points = 3_000
    cfg.pipeline.model.mcmc = type(cfg.pipeline.model.mcmc)(refine_start_iter=steps // 3, refine_every=50)
    cfg.vis = "tensorboard"
    cfg.output_dir = out
    cfg.experiment_name = mode
    cfg.steps_per_eval_image = 10**9
    cfg.set_timestamp()
    cfg.save_config()
    _set_random_seed(cfg.machine.seed)  # as ns-train does: the result must not depend on the tests before
    trainer = cfg.setup(local_rank=0, world_size=1)
    trainer.setup()
    initial = None
    traj = trainer.pipeline.model.scene_model.trajectories
    if traj is not None:
        if perturb:  # registration errors of this size are what refinement is for (paper, ablation g)
            gen = torch.Generator().manual_seed(0)
            with torch.no_grad():
                traj.positions.add_(perturb * torch.randn(traj.positions.shape, generator=gen))
        initial = _trajectory_errors(trainer.pipeline.datamanager.scene, traj)
    threads = torch.get_num_threads()
    torch.set_num_threads(TRAIN_THREADS)
    try:
        trainer.train()
        metrics = trainer.pipeline.get_average_eval_image_metrics(step=steps)
    finally:
        torch.set_num_threads(threads)
    return trainer, metrics, initial


def _trajectory_errors(scene, traj) -> list[float]:
    """Per instance: aligned position RMSE (see aligned_position_rmse) against the moving GT box
    nearest to it, over the frames where the instance is present."""
    from idsplat_ns.eval.trajectory_eval import aligned_position_rmse, ground_truth_positions

    gt = ground_truth_positions(scene)
    errors = []
    for k, iid in enumerate(traj.instance_ids.tolist()):
        poses, centres, owner = [], [], None
        for f, t in zip(scene.frame_indices, scene.frame_times):
            T, present = traj.pose_matrices_at(float(t))
            if not bool(present[k]) or not gt[int(f)]:
                continue
            ids, boxes = list(gt[int(f)]), np.array(list(gt[int(f)].values()))
            if owner is None:
                owner = ids[int(np.argmin(np.linalg.norm(boxes - T[k, :3, 3].detach().numpy(), axis=1)))]
            if owner in gt[int(f)]:
                poses.append(T[k].detach().double().numpy())
                centres.append(gt[int(f)][owner])
        if len(poses) >= 3:
            errors.append(aligned_position_rmse(np.array(poses), np.array(centres)))
    return errors


@pytest.mark.slow
def test_self_supervised_beats_static_in_dynamic_regions(tiny_street, tmp_path):
    _, static, _ = _train(tiny_street, tmp_path, "static")
    trainer, inst, initial = _train(tiny_street, tmp_path, "self-supervised", perturb=0.1)
    print(f"DPSNR static {static['dpsnr']:.2f} dB, self-supervised {inst['dpsnr']:.2f} dB; "
          f"PSNR {static['psnr']:.2f} / {inst['psnr']:.2f} dB; MOTA@2m {inst.get('mota@2m', float('nan')):.2f}")
    assert inst["dpsnr"] > static["dpsnr"] + 0.5
    assert inst["psnr"] > static["psnr"] - 0.5
    assert "mota@2m" in inst and "render_mpix_per_s" in inst
    final = _trajectory_errors(trainer.pipeline.datamanager.scene, trainer.pipeline.model.scene_model.trajectories)
    print(f"aligned trajectory RMSE per instance: initial {np.round(initial, 3)} m, optimised {np.round(final, 3)} m")
    assert len(final) == len(initial) >= 1
    assert np.mean(final) < np.mean(initial)  # joint optimisation moves trajectories towards the truth
