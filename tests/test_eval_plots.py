"""Plots written by ns-eval (issue 21): the top view of the learned trajectories with their IDs
against the annotated vehicles and the ego path, listed in the results and by the report."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from idsplat_ns.eval.trajectory_plots import plot_scene_top_view


def test_top_view_draws_tracks_ids_and_ego(tmp_path):
    gt = {0: {"a": np.array([0.0, 5.0, 0.0])}, 1: {"a": np.array([10.0, 5.0, 0.0])}}
    pred = {0: {3: np.array([0.0, 5.5, 0.0])}, 1: {3: np.array([10.0, 5.5, 0.0])}}
    ego = np.array([[0.0, 0.0, 0.0], [20.0, 0.0, 0.0]])
    empty = np.asarray(Image.open(plot_scene_top_view({}, {}, ego[:0], tmp_path / "empty.png")).convert("L"), float)
    full = np.asarray(Image.open(plot_scene_top_view(gt, pred, ego, tmp_path / "p" / "top.png", "t")).convert("L"), float)
    assert full.shape == empty.shape and (full < 128).sum() > (empty < 128).sum() + 500  # lines and labels drawn
    assert not list((tmp_path / "p").glob("*.tmp-*"))


@pytest.fixture(scope="module")
def pipeline(tiny_street, tmp_path_factory):
    pytest.importorskip("nerfstudio")
    sys.path.insert(0, str(Path(__file__).parent))
    from _tiny_run import loaded_pipeline, tiny_run

    return loaded_pipeline(tiny_run(tiny_street, tmp_path_factory))[0]


def test_eval_writes_the_plot_and_the_report_lists_it(pipeline, tmp_path, monkeypatch):
    monkeypatch.setattr(pipeline.model, "lidar", None)  # the held-out lidar metrics are not tested here (slow)
    result = pipeline.get_average_eval_image_metrics(output_path=tmp_path / "renders", get_std=True)
    plots = tmp_path / "renders" / "plots"
    names = ["trajectories_top.png", "position_errors.png", "per_image_psnr.png", "objects_timeline.png"]
    assert result["plots"] == [str(plots / name) for name in names]
    assert all(Image.open(p).size[0] > 400 for p in result["plots"])
    # The per-object diagnosis: every annotated moving road user the observed protocol counts, with
    # its own DPSNR where the held-out images show it.
    objects = result["objects"]
    assert objects and {o["name"] for o in objects} <= {"leading_car", "overtaking_car", "oncoming_car", "oncoming_bus",
                                                      "turning_car"}  # fmt: skip
    assert sum(o["frames_tracked"] + o["frames_lost"] == o["frames"] for o in objects) == len(objects)
    assert any(o["dpsnr"] is not None for o in objects)
    assert result["objects_frames"] == sum(o["frames"] for o in objects if o["class"] == "vehicle")
    (tmp_path / "eval.json").write_text(json.dumps({"experiment_name": "tiny", "results": result}))
    res = subprocess.run([sys.executable, "-m", "idsplat_ns.cli.report", str(tmp_path / "eval.json")],
                         capture_output=True, text=True, timeout=120)
    listed = res.stdout.replace("\n", "")
    assert res.returncode == 0 and all(name in listed for name in names)


def test_position_errors_pair_each_prediction_with_its_nearest_track():
    from idsplat_ns.eval.trajectory_plots import position_errors

    gt = {f: {"a": np.array([f, 0.0, 0.0]), "b": np.array([f, 10.0, 0.0])} for f in range(4)}
    pred = {f: {1: np.array([f, 9.5, 0.0])} for f in range(4)}
    pred[2] = {1: np.array([2.0, 0.0, 0.0])}  # jumps onto the other track: an error, not a re-pairing
    frames, err = position_errors(gt, pred)[1]
    assert list(frames) == [0, 1, 2, 3]
    np.testing.assert_allclose(err, [0.5, 0.5, 10.0, 0.5])
    assert position_errors({}, pred) == {}


def test_range_error_bins_hold_the_medians_and_counts_of_their_rays():
    from idsplat_ns.eval.lidar_metrics import range_error_by_distance

    ranges = np.array([1.0, 2.0, 9.9, 10.0, 25.0, 25.0, 25.0, 41.0])
    errors = np.array([0.1, 0.3, 0.2, 1.0, 2.0, 4.0, 6.0, 0.5])
    bins = range_error_by_distance(ranges, errors, bin_width=10.0)
    np.testing.assert_array_equal(bins["edges"], [0, 10, 20, 30, 40, 50])
    np.testing.assert_array_equal(bins["count"], [3, 1, 3, 0, 1])
    np.testing.assert_allclose(bins["median"][[0, 1, 2, 4]], [0.2, 1.0, 4.0, 0.5])
    np.testing.assert_allclose(bins["p25"][2], 3.0)  # numpy's linear percentile of 2, 4, 6
    assert np.isnan(bins["median"][3]) and np.isnan(bins["p75"][3])  # an empty bin is NaN, not 0
    with pytest.raises(ValueError, match="ranges against"):
        range_error_by_distance(ranges, errors[:3])


def test_lidar_error_plot_is_written_and_refuses_no_rays(tmp_path):
    from idsplat_ns.errors import IDSplatError
    from idsplat_ns.eval.metric_plots import plot_lidar_error_by_range

    rng = np.random.default_rng(0)
    ranges = rng.uniform(2, 80, 2000)
    path = plot_lidar_error_by_range(ranges, 0.01 * ranges * rng.uniform(0.5, 1.5, 2000), tmp_path / "l.png", "t")
    img = np.asarray(Image.open(path).convert("L"), float)
    assert img.shape[1] > 400 and (img < 128).sum() > 2000
    with pytest.raises(IDSplatError, match="no returned lidar rays"):
        plot_lidar_error_by_range(np.zeros(0), np.zeros(0), tmp_path / "none.png")


def test_sweep_range_errors_take_the_depth_metric_rays():
    import torch

    from idsplat_ns.eval.lidar_evaluation import sweep_range_errors
    from idsplat_ns.model.lidar_supervision import SweepRender

    class Rays:  # the fields of LidarRayBatch that the errors read
        returned = torch.tensor([True, True, False, True])
        ranges = torch.tensor([10.0, 20.0, 0.0, 30.0])

    render = SweepRender(range=np.array([11.0, 19.0, 5.0, 33.0]), range_normalised=np.zeros(4), median_range=np.zeros(4),
                         intensity=np.zeros(4), ray_drop_prob=np.array([0.1, 0.2, 0.1, 0.9]), alpha=np.ones(4),
                         points=np.zeros((0, 3)), rays=Rays())
    gt, err = sweep_range_errors(render, 0.5)  # ray 2: no return in the data; ray 3: predicted dropped
    np.testing.assert_allclose(gt, [10.0, 20.0])
    np.testing.assert_allclose(err, [1.0, 1.0])
