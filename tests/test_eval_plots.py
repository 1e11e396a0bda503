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
    names = ["trajectories_top.png", "position_errors.png", "per_image_psnr.png"]
    assert result["plots"] == [str(plots / name) for name in names]
    assert all(Image.open(p).size[0] > 400 for p in result["plots"])
    (tmp_path / "eval.json").write_text(json.dumps({"experiment_name": "tiny", "results": result}))
    res = subprocess.run([sys.executable, "-m", "idsplat_ns.nerfstudio.report", str(tmp_path / "eval.json")],
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
