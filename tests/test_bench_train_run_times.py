"""bench/train_run_times.py: the step times and peak memory of a training read back from what
nerfstudio and nvidia-smi wrote."""

import json

from torch.utils.tensorboard import SummaryWriter

from bench.train_run_times import ALLOCATED_TAG, STEP_TIME_TAG, summarise, table


def _training(folder, tag, start, end, seconds_by_step, allocated_mib):
    folder.mkdir(parents=True)
    (folder / "run.json").write_text(json.dumps({"tag": tag, "engine": "/x", "backend": "torch",
                                                 "start": start, "end": end, "train_rc": 0}))
    writer = SummaryWriter(log_dir=str(folder))
    for step, s in seconds_by_step.items():
        writer.add_scalar(STEP_TIME_TAG, s, step)
    writer.add_scalar(ALLOCATED_TAG, allocated_mib, 10)
    writer.close()


def test_the_median_step_and_the_peak_memory_are_those_of_each_training_s_own_window(tmp_path):
    # Steps outside the window (setup, the end) are slow and must not count.
    first = {step: (5.0 if step < 3 else 0.1 + 0.01 * (step % 3)) for step in range(0, 30)}
    second = {step: 0.2 for step in range(0, 30)}
    _training(tmp_path / "b", "against", 200, 300, second, 900.0)
    _training(tmp_path / "a", "this", 100, 190, first, 1500.0)
    (tmp_path / "gpu_memory.txt").write_text("95 9999\n100 3000\n150 4096\n190 3500\n250 2048\n310 8888\n")

    rows = summarise(tmp_path, 3, 26)
    assert [r["tag"] for r in rows] == ["this", "against"]  # in the order they ran
    assert abs(rows[0]["median_step_s"] - 0.11) < 1e-6 and rows[0]["steps_in_window"] == 24
    assert abs(rows[1]["median_step_s"] - 0.2) < 1e-6
    assert rows[0]["peak_gpu_mib"] == 4096 and rows[1]["peak_gpu_mib"] == 2048
    assert rows[0]["peak_allocated_mib"] == 1500.0
    md = table(rows, 3, 26)
    assert "| this | torch | 0.110 (1.00x)" in md and "0.200 (1.82x)" in md and "4.0 / 1.5" in md
