"""Learnable instance trajectories: interpolation, presence over time, gradients, freezing."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from torch.func import functional_call

from idsplat_ns.data.geometry import make_pose, rot_z
from idsplat_ns.instances.tracks import InstanceTrack, InstanceTracks
from idsplat_ns.model.checkpoint_shapes import trajectories_like
from idsplat_ns.model.trajectories import InstanceTrajectories

TIMES = np.arange(10) * 0.1 + 0.05  # 10 steps, 0.1 s apart


def _instance_poses(yaws: np.ndarray, positions: np.ndarray) -> np.ndarray:  # -> [F, 4, 4]
    return make_pose(rot_z(yaws), positions)


def _two_instances(span_margin=0.0, refine=True, dtype=torch.float64):
    """Instance 3: valid steps 2..6 with a gap at 4, turning and moving along x.
    Instance 7: valid at step 5 only."""
    F = len(TIMES)
    yaws = 0.2 * np.arange(F)
    pos = np.stack([2.0 * np.arange(F), np.zeros(F), np.ones(F)], 1)
    p_a = _instance_poses(yaws, pos)
    v_a = np.zeros(F, bool)
    v_a[[2, 3, 5, 6]] = True
    p_a[~v_a] = np.eye(4) * 7  # garbage where invalid: must never be used
    p_b = np.repeat(_instance_poses(np.array([1.0]), np.array([[5.0, 5.0, 0.0]])), F, 0)
    v_b = np.zeros(F, bool)
    v_b[5] = True
    traj = InstanceTrajectories(TIMES, np.array([3, 7]), np.stack([p_a, p_b]), np.stack([v_a, v_b]),
                                refine=refine, span_margin=span_margin, dtype=dtype)
    return traj, yaws, pos


def test_poses_at_step_times_equal_the_steps():
    traj, yaws, pos = _two_instances()
    for k in (2, 3, 5, 6):
        R, t, present = traj.poses_at(float(TIMES[k]))
        assert present[0]
        assert torch.allclose(R[0], torch.from_numpy(rot_z(yaws[k])), atol=1e-12)
        assert torch.allclose(t[0], torch.from_numpy(pos[k]), atol=1e-12)


def test_interpolation_between_steps_is_linear_and_geodesic():
    traj, yaws, pos = _two_instances()
    t = TIMES[2] + 0.03  # 30% of the way from step 2 to step 3
    R, trans, _ = traj.poses_at(t)
    assert torch.allclose(R[0], torch.from_numpy(rot_z(yaws[2] + 0.3 * (yaws[3] - yaws[2]))), atol=1e-10)
    assert torch.allclose(trans[0], torch.from_numpy(pos[2] + 0.3 * (pos[3] - pos[2])), atol=1e-10)


def test_presence_before_inside_gap_and_after_span():
    traj, yaws, pos = _two_instances(span_margin=0.0)
    present = lambda t: traj.present_at(t).tolist()
    assert present(TIMES[1]) == [False, False]  # before instance 3's span
    assert present(TIMES[2] - 1e-6) == [False, False]
    assert present(TIMES[2]) == [True, False]
    assert present(TIMES[5]) == [True, True]  # instance 7 exists at its single step only
    assert present(TIMES[5] + 0.01) == [True, False]
    assert present(TIMES[6]) == [True, False]
    assert present(TIMES[6] + 1e-6) == [False, False]  # after the span
    assert traj.ids_present_at(TIMES[5]).tolist() == [3, 7]
    assert traj.ids_present_at(TIMES[0]).tolist() == []
    # The gap at step 4 is inside the span: present, pose interpolated from its valid neighbours.
    assert present(TIMES[4]) == [True, False]
    R, trans, _ = traj.poses_at(TIMES[4])
    assert torch.allclose(trans[0], torch.from_numpy(pos[4]), atol=1e-10)  # midway between 3 and 5
    assert torch.allclose(R[0], torch.from_numpy(rot_z(yaws[4])), atol=1e-10)


def test_span_margin_extrapolates_at_constant_velocity():
    traj, yaws, pos = _two_instances(span_margin=None)  # default: half the step (0.05 s)
    assert traj.span_margin == pytest.approx(0.05)
    t = TIMES[2] - 0.04
    assert traj.present_at(t)[0] and not traj.present_at(TIMES[2] - 0.06)[0]
    R, trans, _ = traj.poses_at(t)
    assert torch.allclose(trans[0], torch.from_numpy(pos[2] - 0.4 * (pos[3] - pos[2])), atol=1e-10)
    assert torch.allclose(R[0], torch.from_numpy(rot_z(yaws[2] - 0.4 * (yaws[3] - yaws[2]))), atol=1e-10)
    R, trans, _ = traj.poses_at(TIMES[5] + 0.02)  # single-step instance: constant pose
    assert torch.allclose(trans[1], torch.tensor([5.0, 5.0, 0.0], dtype=torch.float64))


def test_gradcheck_poses_wrt_parameters_and_time():
    traj, _, _ = _two_instances()
    with torch.no_grad():  # a non-trivial correction, so the check is not only at delta = 0
        traj.rotation_deltas.normal_(0.0, 0.05, generator=torch.Generator().manual_seed(0))
    positions = traj.positions.detach().clone().requires_grad_(True)
    deltas = traj.rotation_deltas.detach().clone().requires_grad_(True)

    def poses(p, d, t):
        R, trans, _ = functional_call(traj, {"positions": p, "rotation_deltas": d}, (t,))
        return R, trans

    for t_value in (TIMES[2] + 0.037, TIMES[4] + 0.051):  # inside a segment, in the gap
        t = torch.tensor(t_value, dtype=torch.float64, requires_grad=True)
        assert torch.autograd.gradcheck(poses, (positions, deltas, t))
    # At a step time the pose has a kink in t (one-sided derivatives): check the parameters only.
    t_step = torch.tensor(TIMES[3], dtype=torch.float64)
    assert torch.autograd.gradcheck(lambda p, d: poses(p, d, t_step), (positions, deltas))


def test_refine_false_freezes_parameters():
    frozen, yaws, pos = _two_instances(refine=False)
    assert frozen.position_parameters() == [] and frozen.rotation_parameters() == []
    assert not any(p.requires_grad for p in frozen.parameters())
    R, trans, _ = frozen.poses_at(TIMES[3])
    assert not R.requires_grad and not trans.requires_grad
    live, _, _ = _two_instances(refine=True)
    assert live.position_parameters() == [live.positions]
    assert live.rotation_parameters() == [live.rotation_deltas]
    opt = torch.optim.Adam(live.position_parameters() + live.rotation_parameters(), lr=1e-2)
    R, trans, _ = live.poses_at(TIMES[3] + 0.05)
    (trans.sum() + R[:, 0, 1].sum()).backward()
    opt.step()
    assert not torch.allclose(live.step_poses(), frozen.step_poses())
    assert torch.allclose(frozen.step_poses()[0, 3], torch.from_numpy(_instance_poses(yaws, pos)[3]))


def test_from_instance_tracks_keeps_ids_and_float32_default():
    F = len(TIMES)
    poses = np.repeat(np.eye(4)[None], F, 0)
    insts = [
        InstanceTrack(instance_id=i, label="car", canonical_points=np.zeros((5, 3)), canonical_colors=None,
                      poses=poses, valid=np.arange(F) >= s, point_counts=np.ones(F, int), fitness=np.ones(F),
                      canonical_frame=s)
        for i, s in ((2, 0), (5, 4))
    ]
    tracks = InstanceTracks(np.arange(F), TIMES, insts)
    traj = InstanceTrajectories.from_instance_tracks(tracks)
    assert traj.instance_ids.tolist() == [2, 5] and traj.positions.dtype == torch.float32
    assert traj.ids_present_at(TIMES[1]).tolist() == [2]
    assert traj.ids_present_at(TIMES[4]).tolist() == [2, 5]
    empty = InstanceTrajectories.from_instance_tracks(InstanceTracks(np.arange(F), TIMES, []))
    R, trans, present = empty.poses_at(0.3)
    assert R.shape == (0, 3, 3) and trans.shape == (0, 3) and present.shape == (0,)


def test_a_checkpoint_defines_the_trajectories_not_todays_preprocessing():
    """ns-eval re-runs preprocessing; code or settings that changed since training find other
    instances (seed 5 of the small street: 6 instead of 8). Loading the checkpoint rebuilds the
    trajectories in its shape, and they then pose and show instances exactly as trained."""
    trained, _, _ = _two_instances(span_margin=None, dtype=torch.float32)
    with torch.no_grad():
        trained.positions.add_(0.3)  # "optimised"
        trained.rotation_deltas.add_(0.01)
    state = {f"scene_model.trajectories.{k}": v for k, v in trained.state_dict().items()}
    state["scene_model.camera_time_offset"] = torch.tensor([0.01, -0.02])
    today = InstanceTrajectories(TIMES[:4], np.array([1]), np.tile(np.eye(4), (1, 4, 1, 1)), np.ones((1, 4), bool))
    scene_model = torch.nn.Module()
    scene_model.trajectories = today
    scene_model.camera_time_offset = None
    assert trajectories_like(scene_model, state, refine=True, device="cpu")
    scene_model.load_state_dict({k.removeprefix("scene_model."): v for k, v in state.items()})
    loaded = scene_model.trajectories
    loaded.reset_span_margin()
    assert loaded.span_margin == pytest.approx(trained.span_margin)
    assert loaded.instance_ids.tolist() == [3, 7]
    for t in np.linspace(0.0, 1.1, 23):
        R0, t0, p0 = trained.poses_at(float(t))
        R1, t1, p1 = loaded.poses_at(float(t))
        assert torch.equal(p0, p1)
        torch.testing.assert_close(R1[p1], R0[p0])
        torch.testing.assert_close(t1[p1], t0[p0])
    # Same shape and IDs: nothing is rebuilt. No trajectories in the checkpoint: none here either.
    assert not trajectories_like(scene_model, state, refine=True, device="cpu")
    assert not trajectories_like(scene_model, {"scene_model.gaussians.means": torch.zeros(1, 3)}, refine=True, device="cpu")
    assert scene_model.trajectories is None and scene_model.camera_time_offset is None
