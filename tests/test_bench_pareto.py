"""bench/pareto.py: the presets are its points, its children run on the threads asked, and its
front, means and plot are what the table in docs/reports/2026-11-27-pareto.md says."""

from __future__ import annotations

import pytest

pytest.importorskip("nerfstudio")


def _bench_pareto():
    import importlib

    return importlib.import_module("bench.pareto")  # the repository root is on the path under python -m pytest


def test_the_cpu_presets_are_the_points_measured_in_bench_pareto():
    # docs/reports/2026-11-27-pareto.md reports the CPU presets as points of bench/pareto.py: the
    # presets must be what those points train.
    from method_configs.idsplat import idsplat_fast_method, idsplat_medium_method, idsplat_preview_method

    pareto = _bench_pareto()
    for method, point in ((idsplat_fast_method, "steps-1500 (idsplat-fast)"),
                          (idsplat_medium_method, "steps-3000 (idsplat-medium)"),
                          (idsplat_preview_method, "steps-1000, half initial Gaussians")):  # fmt: skip
        cfg = pareto.point_config(*pareto.POINTS[point])
        assert cfg.max_num_iterations == method.config.max_num_iterations
        assert cfg.pipeline.model == method.config.pipeline.model
        assert cfg.optimizers == method.config.optimizers


def test_bench_pareto_children_run_on_the_threads_asked(capsys):
    # docs/reports/2026-11-27-pareto.md reports CPU times of one-thread trainings: the count reaches the child.
    import os
    import sys

    pareto = _bench_pareto()
    probe = "import torch; print('THREADS', torch.get_num_threads())"
    for threads in (1, 2):
        assert pareto.measured([sys.executable, "-c", probe], threads)["rc"] == 0
        assert f"THREADS {min(threads, os.cpu_count())}" in capsys.readouterr().out  # torch takes at most the cores


def _row(street: str, point: str, cpu_s: float, psnr: float, dpsnr: float | None = None) -> dict:
    return {"street": street, "point": point, "cpu_s": cpu_s, "psnr": psnr, "dpsnr": dpsnr}


def test_the_front_keeps_rows_no_faster_row_beats():
    pareto = _bench_pareto()
    rows = [_row("a", "p1", 100, 20.0), _row("a", "p2", 200, 22.0), _row("a", "p3", 300, 21.0),
            _row("a", "p4", 400, 23.0), _row("a", "p5", 150, None)]  # fmt: skip
    # p3 is slower and worse than p2; p5 has no PSNR, so any faster row with one beats it
    assert [r["point"] for r in pareto.pareto_front(rows, "psnr")] == ["p1", "p2", "p4"]


def test_point_means_average_over_streets_in_time_order():
    pareto = _bench_pareto()
    rows = [_row("a", "slow", 300, 24.0, 25.0), _row("b", "slow", 500, 26.0, None),
            _row("a", "quick", 100, 20.0, 21.0), _row("b", "quick", 200, 22.0, 23.0)]  # fmt: skip
    assert pareto.point_means(rows, "psnr") == {"quick": (150.0, 21.0), "slow": (400.0, 25.0)}
    assert pareto.point_means(rows, "dpsnr") == {"quick": (150.0, 22.0), "slow": (300.0, 25.0)}  # street b has none


def test_the_plot_is_written_for_several_streets(tmp_path):
    pareto = _bench_pareto()
    rows = [_row(s, p, t + 50 * k, q + k, q + k + 1) for k, s in enumerate("ab")
            for p, t, q in (("steps-600", 300, 22.0), ("steps-1500 (idsplat-fast)", 900, 25.0))]  # fmt: skip
    pareto.plot(rows, tmp_path / "front.png")
    assert (tmp_path / "front.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_gpu_rows_are_ranked_by_wall_time_and_show_their_device():
    # On a GPU the CPU mostly waits on it: the front is against wall time, and the table says
    # which card and how much of its memory.
    pareto = _bench_pareto()
    gpu = {"device": "NVIDIA H200", "peak_gpu_gib": 2.0}
    rows = [{**_row("a", "quick", 100, 20.0), "wall_s": 300, **gpu},
            {**_row("a", "slow", 200, 22.0), "wall_s": 150, **gpu}]  # fmt: skip
    assert pareto.time_key(rows) == "wall_s" and pareto.time_key([_row("a", "p", 1, 1.0)]) == "cpu_s"
    assert [r["point"] for r in pareto.pareto_front(rows, "psnr")] == ["slow"]  # faster in wall time and better
    assert list(pareto.point_means(rows, "psnr")) == ["slow", "quick"]
    header, _, line = pareto.table(rows[:1]).splitlines()
    assert header.endswith("| device | peak_gpu_gib |") and line.endswith("| NVIDIA H200 | 2.0 |")
    assert "device" not in pareto.table([{**_row("a", "p", 1, 1.0), "wall_s": 1}])


def test_the_childs_device_line_joins_its_measurement():
    import sys

    pareto = _bench_pareto()
    probe = "print('DEVICE {\"device\": \"NVIDIA H200\", \"peak_gpu_gib\": 1.5}')"
    got = pareto.measured([sys.executable, "-c", probe], 1)
    assert got["device"] == "NVIDIA H200" and got["peak_gpu_gib"] == 1.5 and got["rc"] == 0


def test_import_tracks_without_a_streets_file_stops_before_any_work(tmp_path, monkeypatch, capsys):
    import sys

    pareto = _bench_pareto()
    monkeypatch.setattr(sys, "argv", ["pareto.py", "--seeds", "7", "--work", str(tmp_path / "w"),
                                      "--import-tracks", str(tmp_path / "tracks")])  # fmt: skip
    with pytest.raises(SystemExit, match="synth_small_7.json; write it with idsplat-preprocess --data"):
        pareto.main()
    assert not (tmp_path / "w").exists()  # no street generated
