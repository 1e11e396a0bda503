"""Metrics only where the data supports them: the lidar ray-drop accuracy needs rays marked as
returning nothing (Waymo range images, the built-in street's extension), PandaSet layout has none;
without them (and LPIPS without weights) the metric is absent and the report says why in one line."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from idsplat_ns.data.lidar import LidarSweep
from idsplat_ns.model.lidar_render import sample_rays
from idsplat_ns.eval.lidar_evaluation import RAYDROP_NOTE, has_drop_labels, held_out_lidar_metrics
from idsplat_ns.model.lidar_supervision import SweepRender

WAYMO_FRAME = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "waymo" / "pvps_data_one_frame.tfrecord"


def _render(drop_prob: float, range_error: float = 0.0):
    """A stand-in for the model's sweep render: the measured ranges (plus ``range_error``) and
    intensities, the same ray-drop probability for every ray."""
    def render(sweep: LidarSweep) -> SweepRender:
        rays = sample_rays(sweep, sweep.num_rays)
        n = sweep.num_rays
        rng = rays.ranges.numpy().astype(np.float64) + range_error
        keep = np.full(n, drop_prob < 0.5)
        pts = (rays.origins.numpy() + rays.directions.numpy() * rng[:, None])[keep]
        return SweepRender(range=rng, range_normalised=rng, median_range=rng, intensity=rays.intensities.numpy(),
                           ray_drop_prob=np.full(n, drop_prob), alpha=np.ones(n), points=pts, rays=rays)
    return render


def _pandaset_layout(root: Path, noreturn: bool):
    from test_pandaset import write_sequence

    from idsplat_ns.data.pandaset import load_sequence

    write_sequence(root)
    if noreturn:  # the built-in street's extension: rays that returned nothing, per sweep
        folder = root / "idsplat_extras" / "lidar_noreturn"
        folder.mkdir(parents=True)
        rng = np.random.default_rng(0)
        stamps = json.loads((root / "lidar" / "timestamps.json").read_text())
        for f, stamp in enumerate(stamps):
            d = rng.normal(size=(30, 3))
            np.savez(folder / f"{f:02d}.npz", origins=np.zeros((30, 3)), directions=d / np.linalg.norm(d, axis=1, keepdims=True),
                     t=np.full(30, stamp), d=np.zeros(30, int))
    return load_sequence(root)


def test_pandaset_layout_has_no_drop_labels_and_no_raydrop_metric(tmp_path):
    scene = _pandaset_layout(tmp_path / "001", noreturn=False)
    assert scene.has_lidar and not has_drop_labels(scene.lidar)
    for drop_prob in (0.1, 0.9):  # whatever the model predicts, nothing is measured
        metrics, note = held_out_lidar_metrics(scene, scene.lidar[1:], _render(drop_prob), 0.5)
        assert "lidar_raydrop_acc" not in metrics and note == RAYDROP_NOTE
    assert metrics["lidar_num_sweeps"] == 2 and metrics["lidar_intensity_rmse"] == pytest.approx(0.0, abs=1e-6)
    assert "\n" not in RAYDROP_NOTE


def test_the_built_in_streets_no_return_rays_are_drop_labels(tmp_path):
    scene = _pandaset_layout(tmp_path / "002", noreturn=True)
    assert has_drop_labels(scene.lidar)
    sweeps = scene.lidar[1:]
    returned = np.concatenate([s.returned for s in sweeps])
    per_sweep = [1.0 - s.returned.mean() for s in sweeps]  # predicting "dropped" everywhere
    metrics, note = held_out_lidar_metrics(scene, sweeps, _render(0.9), 0.5)
    assert note is None and metrics["lidar_raydrop_acc"] == pytest.approx(np.mean(per_sweep))
    metrics, _ = held_out_lidar_metrics(scene, sweeps, _render(0.1), 0.5)
    assert metrics["lidar_raydrop_acc"] == pytest.approx(1 - np.mean(per_sweep))
    assert 0 < (~returned).mean() < 1


@pytest.mark.skipif(not WAYMO_FRAME.is_file(), reason=f"real Waymo frame not found at {WAYMO_FRAME}")
def test_waymo_range_images_give_drop_labels_and_the_metric(tmp_path):
    from idsplat_ns.data.waymo import load_segment
    from idsplat_ns.data.waymo.fixtures import write_synthetic_segment

    path = write_synthetic_segment(WAYMO_FRAME, tmp_path / "seg.tfrecord", 2, top_width=200)
    scene = load_segment(path, cameras=["FRONT"], lidars=["TOP"])
    assert has_drop_labels(scene.lidar)
    sweep = scene.lidar[1]
    metrics, note = held_out_lidar_metrics(scene, [sweep], _render(0.1), 0.5)
    assert note is None and metrics["lidar_raydrop_acc"] == pytest.approx(sweep.returned.mean())
    assert 0.8 < metrics["lidar_raydrop_acc"] < 0.95  # the fixture's ~10 % of rays without a return


def test_report_prints_present_metrics_and_one_line_per_absent_one(tmp_path, capsys):
    from idsplat_ns.eval.lpips import LPIPS_NOTE
    from idsplat_ns.cli.report import main

    results = {"psnr": 25.0, "ssim": 0.8, "dpsnr": 24.0, "dpsnr_pedestrian": 21.5, "dpsnr_pedestrian_num_images": 3,
               "num_images": 6, "lidar_chamfer": 0.3, "lidar_num_sweeps": 2,
               "mota@2m": 1.0, "motp@2m": 0.12, "objects@2m": 40.0, "matches@2m": 40.0, "false_positives@2m": 0.0,
               "misses@2m": 0.0, "id_switches@2m": 0.0,
               "pedestrian_mota@2m": 0.5, "pedestrian_objects@2m": 10.0, "pedestrian_matches@2m": 6.0,
               "pedestrian_false_positives@2m": 1.0, "pedestrian_misses@2m": 4.0, "pedestrian_id_switches@2m": 0.0,
               "lpips_note": LPIPS_NOTE, "lidar_raydrop_note": RAYDROP_NOTE}
    path = tmp_path / "eval.json"
    path.write_text(json.dumps({"experiment_name": "x", "results": results}))
    import os

    os.environ["COLUMNS"] = "200"  # rich wraps at the terminal's width: keep each note on one line
    try:
        main([str(path)])
    finally:
        os.environ.pop("COLUMNS")
    out = capsys.readouterr().out
    lines = out.splitlines()
    assert sum(RAYDROP_NOTE in ln for ln in lines) == 1 and sum(LPIPS_NOTE in ln for ln in lines) == 1
    assert "ray-drop accuracy  " not in out and "LPIPS  " not in out  # no row for either metric
    assert "DPSNR (dB, pedestrians) [3 images]" in out and "cyclists" not in out
    row = next(ln for ln in lines if ln.startswith("│ pedestrians"))
    assert [c.strip() for c in row.strip("│").split("│")][1:] == ["10", "6", "0", "1", "4", "0.500", ""]
    assert any(ln.startswith("│ vehicles (headline)") for ln in lines)


def test_a_sweep_without_any_finite_value_leaves_the_metric_out():
    # A held-out set whose rays all returned nothing has no depth error to average: absent, not NaN.
    n = 50
    d = np.tile([1.0, 0.0, 0.0], (n, 1))
    sweep = LidarSweep(frame_index=0, time=0.0, raw_timestamp=0.0, sensor_to_world=np.eye(4), origins=np.zeros((n, 3)),
                       directions=d, ranges=np.zeros(n), intensities=np.zeros(n, np.float32), times=np.zeros(n),
                       returned=np.zeros(n, bool), sensor_ids=np.zeros(n, np.int16))

    class _Scene:
        lidar = [sweep]

    metrics, note = held_out_lidar_metrics(_Scene(), [sweep], _render(0.9), 0.5)
    assert note is None and metrics["lidar_raydrop_acc"] == 1.0
    assert "lidar_depth_median_sq_err" not in metrics and "lidar_chamfer" not in metrics
