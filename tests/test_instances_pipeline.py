"""End to end on the synthetic street (tiny preset): noisy ground-truth masks -> lifting -> DAISY
features -> registration, against the ground-truth tracks; the runner's caches."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from idsplat_ns.data.pandaset import load_sequence
from idsplat_ns.data.synthetic import generate_sequence
from idsplat_ns.instances.cache import TMP_MARK, atomic_path, remove_stale_temporaries
from idsplat_ns.instances.features.config import FeatureConfig
from idsplat_ns.instances.masks.config import MaskConfig
from idsplat_ns.instances.masks.perturb import MaskNoiseConfig
from idsplat_ns.instances.masks.precomputed import PrecomputedMasksConfig
from idsplat_ns.instances.runner import PreprocessConfig, run_preprocessing
from idsplat_ns.eval.instance_pose_errors import summarise_errors
from idsplat_ns.instances.tracks import InstanceTracks
from idsplat_ns.instances.trajectory_config import TrajectoryConfig


@pytest.fixture(scope="module")
def street(tmp_path_factory):
    root = generate_sequence(tmp_path_factory.mktemp("synth"), preset="tiny", seed=0, progress=False)
    return root, load_sequence(root)


def _config(root: Path, **kw) -> PreprocessConfig:
    extras = root / "idsplat_extras"
    masks = MaskConfig(kind="precomputed", precomputed=PrecomputedMasksConfig(extras / "instance_masks", extras / "instances.json"))
    return PreprocessConfig(masks=masks, mask_noise=MaskNoiseConfig(seed=0), features=FeatureConfig(kind="daisy"), **kw)


def test_noisy_masks_recover_moving_vehicle_poses(street, tmp_path):
    root, scene = street
    result = run_preprocessing(scene, _config(root, smoothing=None), tmp_path / "cache", progress=False, verbose=False)
    s = summarise_errors(scene, result.tracks, min_points=50)
    print(f"median translation {s.median_translation:.3f} m, rotation {s.median_rotation_deg:.2f} deg over "
          f"{s.frames_evaluated} frames; matched {s.matched_tracks}/{s.moving_vehicle_tracks} moving vehicles")
    assert s.frames_evaluated >= 5 and s.matched_tracks >= 2
    assert s.median_translation < 0.2
    assert s.median_rotation_deg < 2.0
    assert result.feature_extractor == "daisy" and result.tracks.metadata["features"] == "daisy"
    # every dynamic instance moved at least 1 m; the parked cars went to the background
    assert all(i.displacement() >= 1.0 for i in result.tracks.instances)
    assert any(i.label == "car" for i in result.tracks.static_instances)
    for inst in result.tracks.instances:
        assert inst.canonical_colors is not None and len(inst.canonical_colors) == len(inst.canonical_points)


def test_centroid_ablation_through_the_runner(street, tmp_path):
    root, scene = street
    cfg = _config(root, smoothing=None, trajectory=TrajectoryConfig(method="centroid"))
    result = run_preprocessing(scene, cfg, tmp_path / "cache", progress=False, verbose=False)
    assert result.feature_extractor is None
    assert [t.name for t in result.timings] == ["mask generation", "point painting", "registration", "static conversion",
                                                "smoothing", "amodal centres"]
    s = summarise_errors(scene, result.tracks, min_points=50)
    assert s.frames_evaluated >= 5 and np.isfinite(s.median_translation)


def test_second_run_reuses_every_cache_and_smooths(street, tmp_path, capsys):
    root, scene = street
    cfg = _config(root)
    out = tmp_path / "tracks.npz"
    first = run_preprocessing(scene, cfg, tmp_path / "cache", out, progress=False)
    table = capsys.readouterr().out
    assert "mask generation" in table and "registration" in table and "total" in table
    second = run_preprocessing(scene, cfg, tmp_path / "cache", out, progress=False, verbose=False)
    cached = {t.name: t.cached for t in second.timings}
    assert cached["mask generation"] and cached["point painting"] and cached["features"] and cached["registration"]
    assert not any(t.cached for t in first.timings if t.name in ("point painting", "features", "registration"))
    smoothing = next(t for t in second.timings if t.name == "smoothing")
    loaded = InstanceTracks.load(out)
    assert [i.instance_id for i in loaded.instances] == [i.instance_id for i in first.tracks.instances]
    for a, b in zip(loaded.instances, first.tracks.instances):
        np.testing.assert_allclose(a.poses, b.poses)
    assert smoothing.cached and loaded.metadata.get("smoothed")
    for inst in loaded.instances:
        # the span runs between measurements (those far from the smoothed result do not extend it)
        assert inst.measured_valid is not None and inst.valid.any()
        span = np.flatnonzero(inst.valid)
        measured = np.flatnonzero(inst.measured_valid)
        assert np.all(np.diff(span) == 1) and span[0] >= measured[0] and span[-1] <= measured[-1]
        assert inst.measured_valid[span[0]] and inst.measured_valid[span[-1]]
        # canonical points remember their frame, and come only from measurements (outliers dropped)
        assert inst.point_frames is not None and len(inst.point_frames) == len(inst.canonical_points)
        assert np.all(inst.measured_valid[inst.point_frames])
    # a changed setting invalidates only the stages after it
    third = run_preprocessing(scene, _config(root, smoothing=None, trajectory=TrajectoryConfig(min_points=11)),
                              tmp_path / "cache", progress=False, verbose=False)
    cached = {t.name: t.cached for t in third.timings}
    assert cached["features"] and not cached["registration"]


def test_keep_points_of_frames():
    from idsplat_ns.instances.tracks import InstanceTrack

    pts = np.arange(30, dtype=float).reshape(10, 3)
    inst = InstanceTrack(1, "car", pts, np.zeros((10, 3), np.uint8), np.tile(np.eye(4), (3, 1, 1)),
                         np.ones(3, bool), np.full(3, 5), np.ones(3), 0, point_frames=np.repeat([0, 1, 2], [4, 3, 3]))
    kept = inst.keep_points_of_frames(np.array([True, False, True]), min_points=3)
    np.testing.assert_array_equal(kept.canonical_points, pts[[0, 1, 2, 3, 7, 8, 9]])
    assert len(kept.canonical_colors) == 7 and list(kept.point_frames) == [0, 0, 0, 0, 2, 2, 2]
    # too few would remain, or origins unknown: unchanged
    assert inst.keep_points_of_frames(np.array([False, True, False]), min_points=4) is inst
    no_frames = InstanceTrack(1, "car", pts, None, inst.poses, inst.valid, inst.point_counts, inst.fitness, 0)
    assert no_frames.keep_points_of_frames(np.array([True, False, False])) is no_frames


def test_interrupted_write_leaves_no_cache_entry(tmp_path):
    final = tmp_path / "stage-abc.npz"
    with pytest.raises(RuntimeError):
        with atomic_path(final) as tmp:
            tmp.write_bytes(b"half")
            raise RuntimeError("killed")
    assert not final.exists() and list(tmp_path.iterdir()) == []
    # A process killed (SIGKILL) while writing leaves only a temporary, removed by the next run.
    code = ("import sys, time; from pathlib import Path; from idsplat_ns.instances.cache import atomic_path\n"
            "with atomic_path(Path(sys.argv[1])) as tmp:\n"
            "    tmp.write_bytes(b'partial'); print('writing', flush=True); time.sleep(60)\n")
    proc = subprocess.Popen([sys.executable, "-c", code, str(final)], stdout=subprocess.PIPE, text=True,
                            cwd=Path(__file__).resolve().parents[1])
    assert proc.stdout.readline().strip() == "writing"
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait(timeout=10)
    assert not final.exists()
    assert any(TMP_MARK in p.name for p in tmp_path.iterdir())
    assert remove_stale_temporaries(tmp_path) == 1 and list(tmp_path.iterdir()) == []
