"""idsplat-batch (issue 23): three tiny streets through Ray, one of them corrupted; a re-run skips
what is done; a batch killed during a training resumes it when run again.

Each batch runs as its own process (``idsplat-batch``, which starts its own local Ray), as a
user runs it; the streets are ``tiny`` and train 5 steps, so a sequence takes about half a minute.
"""

from __future__ import annotations

import csv
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from _chromium import free_port

from idsplat_ns.batch.commands import split_user_options, train_command, preprocess_command
from idsplat_ns.batch.layout import SequencePaths
from idsplat_ns.runs.checkpoints import checkpoint_step, latest_complete, list_checkpoints
from idsplat_ns.batch.sequences import Sequence, load_sequences, parse_sequence_file
from idsplat_ns.errors import IDSplatError

METHOD = "idsplat-fast"
# The smallest model that trains: few steps, few initial Gaussians.
SMALL = ["--pipeline.model.num-random-points", "2000", "--pipeline.model.max-lidar-points", "8000"]


def _bin(name: str) -> str:
    return str(Path(sys.executable).with_name(name))


def _batch(seq_file: Path, out: Path, *extra: str, timeout: float = 600) -> subprocess.CompletedProcess:
    cmd = [_bin("idsplat-batch"), "--sequences", str(seq_file), "--output-dir", str(out), "--method", METHOD,
           "--num-cpus", "2", *extra, *SMALL]
    return subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, env={**os.environ, "COLUMNS": "200"})


@pytest.fixture(scope="module")
def streets(tiny_street: Path, tmp_path_factory) -> dict[str, Path]:
    """Two good tiny streets (seeds 0 and 1) and one whose front camera poses are not JSON."""
    root = tmp_path_factory.mktemp("batch_streets")
    subprocess.run([_bin("idsplat-synth"), "--preset", "tiny", "--seed", "1", "--out", str(root), "--quiet"],
                   check=True, capture_output=True, timeout=300)
    broken = root / "broken"
    shutil.copytree(tiny_street, broken)  # a copy: own name, own cache, own failure
    (broken / "camera" / "front_camera" / "poses.json").write_text("{ not json")
    return {"synth_tiny_0": Path(tiny_street), "synth_tiny_1": root / "synth_tiny_1", "broken": broken}


@pytest.fixture(scope="module")
def first_batch(streets: dict[str, Path], tmp_path_factory):
    """The batch run once over the three streets: (list file, output folder, result)."""
    root = tmp_path_factory.mktemp("batch")
    seq_file = root / "sequences.txt"
    seq_file.write_text("# three streets, one broken\n" + "\n".join(str(p) for p in streets.values()) + "\n")
    out = root / "out"
    return seq_file, out, _batch(seq_file, out, "--max-num-iterations", "5")


def _csv_rows(path: Path) -> list[dict]:
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def test_failure_is_isolated_and_the_table_has_the_others(first_batch, streets) -> None:
    _, out, done = first_batch
    assert done.returncode == 1, done.stdout[-3000:] + done.stderr[-3000:]  # one sequence failed
    # The broken one is reported with its reader's one-line error, naming the file.
    status = json.loads((out / "broken" / METHOD / "status.json").read_text())
    assert status["state"] == "failed" and status["step"] == "preprocess"
    assert "front_camera/poses.json" in status["error"] and "\n" not in status["error"]
    assert "broken: FAILED at preprocess" in done.stdout and "front_camera/poses.json" in done.stdout
    assert not (out / "broken" / METHOD / "eval.json").exists()
    # The others trained, were evaluated and are in the table, with the mean of the two.
    rows = _csv_rows(out / f"{METHOD}_results.csv")
    assert [r["sequence"] for r in rows] == ["synth_tiny_0", "synth_tiny_1", "mean (2)"]
    psnr = []
    for name in ("synth_tiny_0", "synth_tiny_1"):
        results = json.loads((out / name / METHOD / "eval.json").read_text())["results"]
        row = next(r for r in rows if r["sequence"] == name)
        assert float(row["psnr"]) == pytest.approx(results["psnr"])
        assert float(row["dpsnr"]) == pytest.approx(results["dpsnr"])
        assert 5.0 < results["psnr"] < 40.0
        psnr.append(results["psnr"])
        ckpt = latest_complete(SequencePaths(out, name, METHOD).checkpoints)
        assert ckpt is not None and checkpoint_step(ckpt) == 4  # 5 steps: 0..4
        for step in ("preprocess", "train", "eval"):
            assert (out / name / METHOD / f"{step}.log").stat().st_size > 0
    assert float(rows[-1]["psnr"]) == pytest.approx(sum(psnr) / 2)
    assert "lpips" not in rows[0]  # no backbone weights: the column is left out, not zero
    assert (out / f"{METHOD}_dpsnr.png").stat().st_size > 1000
    assert "PSNR" in done.stdout and "mean (2)" in done.stdout  # the printed table


def test_rerun_skips_the_finished_sequences(first_batch) -> None:
    seq_file, out, _ = first_batch
    logs = {n: (out / n / METHOD / "train.log").stat().st_mtime_ns for n in ("synth_tiny_0", "synth_tiny_1")}
    before = (out / "batch.log").read_text()
    done = _batch(seq_file, out, "--max-num-iterations", "5")
    assert done.returncode == 1  # the broken street is tried again, and fails again
    new = (out / "batch.log").read_text()[len(before):]
    for name in ("synth_tiny_0", "synth_tiny_1"):
        assert f"{name}: skipped, already evaluated" in new
        assert f"{name}: training" not in new and f"{name}: preprocessing" not in new
        assert (out / name / METHOD / "train.log").stat().st_mtime_ns == logs[name]
    assert "broken: FAILED at preprocess" in new


def _wait_for(predicate, timeout: float, what: str) -> None:
    end = time.time() + timeout
    while time.time() < end:
        if predicate():
            return
        time.sleep(0.1)
    raise AssertionError(f"timed out waiting for {what}")


def _processes_mentioning(text: str) -> list[int]:
    """Live (not zombie) processes whose command line contains ``text``."""
    found = []
    for proc in Path("/proc").iterdir():
        if not proc.name.isdigit():
            continue
        try:
            if (proc / "stat").read_text().split(")")[-1].split()[0] == "Z":
                continue
            if text in (proc / "cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace"):
                found.append(int(proc.name))
        except OSError:
            continue
    return found


LAST_STEP = 59


@pytest.mark.slow
@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc to check that no training is left")
def test_killed_batch_resumes_the_training(streets, tmp_path: Path) -> None:
    seq_file = tmp_path / "one.txt"
    seq_file.write_text(f"{streets['synth_tiny_0']}\n")
    out = tmp_path / "out"
    steps = ["--max-num-iterations", str(LAST_STEP + 1), "--steps-per-save", "3"]
    cmd = [_bin("idsplat-batch"), "--sequences", str(seq_file), "--output-dir", str(out), "--method", METHOD,
           "--num-cpus", "2", *steps, *SMALL]
    paths = SequencePaths(out, "synth_tiny_0", METHOD)
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    try:
        _wait_for(lambda: len(list_checkpoints(paths.checkpoints)) >= 2 or proc.poll() is not None, 300, "two checkpoints")
        assert proc.poll() is None, "the batch ended before it could be killed"
        os.kill(proc.pid, signal.SIGKILL)  # the driver only: Ray and the training must go with it
        proc.wait()
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    # Ray takes a second or two to notice its driver is gone; the training goes on until then, so
    # the run is long enough (60 steps, about 5 per second here) not to end in that window.
    _wait_for(lambda: not _processes_mentioning(str(out)), 30, "the killed batch's training to end")
    # Then the newest checkpoint is damaged (a copy cut short): the batch resumes from the one before.
    newest, previous = list_checkpoints(paths.checkpoints)[:2]
    newest.write_bytes(newest.read_bytes()[:100])
    killed_at = checkpoint_step(previous)
    assert killed_at < LAST_STEP

    done = subprocess.run(cmd, capture_output=True, text=True, timeout=600, env={**os.environ, "COLUMNS": "200"})
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    log = (out / "batch.log").read_text()
    rerun = log[log.rindex("synth_tiny_0: training"):]
    assert f"resume from step {killed_at}" in rerun and "preprocessing" not in rerun
    train_log = " ".join(paths.log("train").read_text().split())
    assert f"{newest.name}: unreadable checkpoint" in train_log and f"resuming from {previous.name} instead" in train_log
    assert checkpoint_step(latest_complete(paths.checkpoints)) == LAST_STEP  # the run's steps in all, not that many more
    assert json.loads(paths.eval_json.read_text())["results"]["psnr"] > 5.0


def test_sequence_file_and_commands(tmp_path: Path) -> None:
    (tmp_path / "a").mkdir()
    (tmp_path / "waymo").mkdir()
    listing = tmp_path / "list.txt"
    listing.write_text(f"# comment\n\na   pandaset-10\n{tmp_path / 'waymo'} streetgs --segment segment-123_with_camera_labels\n"
                       "a - --cameras front_camera\n")
    seqs = parse_sequence_file(listing)
    assert [s.name for s in seqs] == ["a", "123", "a-2"]
    assert seqs[0].data == tmp_path / "a" and seqs[0].protocol == "pandaset-10"
    assert seqs[2].protocol is None and seqs[2].dataparser_args == ("--cameras", "front_camera")
    listing.write_text("a bogus-protocol\n")
    with pytest.raises(IDSplatError, match="line 1: unknown protocol 'bogus-protocol'"):
        parse_sequence_file(listing)
    listing.write_text("a\nmissing-street\n")  # found before any task starts, naming the line
    with pytest.raises(IDSplatError, match=f"line 2: {tmp_path / 'missing-street'}: no such file or folder"):
        parse_sequence_file(listing)
    with pytest.raises(IDSplatError, match=r"10 of the 10 pandaset-10 sequences are not there \(001, 011, 016, ...\)"):
        load_sequences("pandaset-10", tmp_path)

    user = split_user_options(["--max-num-iterations", "5", "--pipeline.datamanager.preprocess.masks.kind",
                               "ground-truth", "idsplat-auto", "--cameras", "front_camera", "--downscale-factor", "2"])
    seq = Sequence("a", Path("/d/a"), "pandaset-10")
    train = train_command(seq, METHOD, user, Path("/o"))
    assert train[:8] == ["ns-train", METHOD, "--output-dir", "/o", "--experiment-name", "a", "--timestamp", "run"]
    assert train[train.index("idsplat-auto"):] == ["idsplat-auto", "--data", "/d/a", "--protocol", "pandaset-10",
                                                  "--cameras", "front_camera", "--downscale-factor", "2"]
    pre = preprocess_command(seq, user)
    assert pre == ["idsplat-preprocess", "--instance-mode", "self-supervised", "--data", "/d/a", "--protocol",
                   "pandaset-10", "--cameras", "front_camera", "--preprocess.masks.kind", "ground-truth"]
    assert preprocess_command(seq, split_user_options(["--pipeline.datamanager.instance-mode", "static"])) is None
    with pytest.raises(IDSplatError, match="--output-dir: set by idsplat-batch"):
        split_user_options(["--output-dir", "x"])


def test_the_preprocess_command_is_what_idsplat_preprocess_parses() -> None:
    # The batch translates ns-train options for idsplat-preprocess: true/false settings keep
    # ns-train's spelling, and the lidar selection (which changes the stage caches' input) carries over.
    from idsplat_ns.cli.preprocess import parse_args

    user = split_user_options(["--pipeline.datamanager.preprocess.lifting.use-dbscan", "False",
                               "--pipeline.datamanager.preprocess.trajectory.registration.max-iterations", "1000",
                               "pipeline.datamanager.preprocess.smoothing:smoothing-config",
                               "--pipeline.datamanager.preprocess.smoothing.drop-outlier-points", "True",
                               "idsplat-waymo", "--lidars", "TOP", "FRONT", "--second-return", "False",
                               "--downscale-factor", "2"])  # fmt: skip
    pre = preprocess_command(Sequence("s", Path("/d/s.tfrecord"), None), user)
    assert pre[0] == "idsplat-preprocess" and "--downscale-factor" not in pre  # preprocessing reads full-size images
    args = parse_args(pre[1:])
    assert (args.data, args.lidars, args.second_return) == (Path("/d/s.tfrecord"), ("TOP", "FRONT"), False)
    assert args.preprocess.lifting.use_dbscan is False and args.preprocess.trajectory.registration.max_iterations == 1000
    assert args.preprocess.smoothing.drop_outlier_points is True


def test_bad_invocation_is_one_line(tmp_path: Path) -> None:
    done = subprocess.run([_bin("idsplat-batch"), "--sequences", str(tmp_path / "none.txt"), "--output-dir",
                           str(tmp_path / "o")], capture_output=True, text=True, timeout=120)
    assert done.returncode == 2
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"error: --sequences {tmp_path / 'none.txt'}: no such file"), lines


def test_one_line_error_of_a_step(tmp_path: Path) -> None:
    from idsplat_ns.batch.tasks import one_line_error

    log = tmp_path / "step.log"
    log.write_text("loading\nprogress: 10%\rprogress: 80%\nerror: /d/poses.json: not valid JSON; regenerate it\n")
    assert one_line_error(log, 2) == "/d/poses.json: not valid JSON; regenerate it"
    log.write_text("╭─ Config ─╮\n│ a │\n╰──╯\nTraceback (most recent call last):\n  File x\nValueError: bad\n")
    assert one_line_error(log, 1) == "ValueError: bad"  # an earlier box is not the failure
    log.write_text("╭─ Unrecognized options ─╮\n│ Unrecognized options: --nope, 1 │\n│ ───── │\n╰───────╯\n")
    assert one_line_error(log, 2) == "Unrecognized options: --nope, 1"
    log.write_text("step 12\n")
    assert one_line_error(log, -9).startswith("killed by SIGKILL (out of memory?")


def test_a_local_ray_that_times_out_at_startup_is_started_again(monkeypatch) -> None:
    import types

    from idsplat_ns.batch.ray_cluster import STARTUP_ATTEMPTS, RayStart, start_ray
    from idsplat_ns.errors import IDSplatError

    calls = []

    def fake_ray(fail_times: int):
        def init(**kwargs):
            calls.append("init")
            if calls.count("init") <= fail_times:
                raise Exception("The current node timed out during startup. This could happen because ...")

        return types.SimpleNamespace(init=init, shutdown=lambda: calls.append("shutdown"))

    monkeypatch.setitem(sys.modules, "ray", fake_ray(1))
    start_ray(RayStart())
    assert calls == ["init", "shutdown", "init"]
    calls.clear()
    monkeypatch.setitem(sys.modules, "ray", fake_ray(10))
    with pytest.raises(IDSplatError, match="did not start in 3 tries"):
        start_ray(RayStart())
    assert calls.count("init") == STARTUP_ATTEMPTS == 3


@pytest.mark.slow
def test_address_of_a_cluster_with_token_authentication(streets, tmp_path: Path) -> None:
    """A cluster started with ``ray start --head`` and a token (Ray 2.59+ does so whenever a token
    exists): a driver without RAY_AUTH_MODE=token is told so in one line; with it, the tasks run there."""
    import secrets
    import socket

    import tempfile

    port = free_port()
    # Its own Ray temp folder (short: Ray's socket paths must fit 107 characters), so that the
    # head's record of itself never reaches another Ray on this machine.
    ray_tmp = Path(tempfile.mkdtemp(prefix="ray-", dir="/tmp"))
    token = tmp_path / "auth_token"
    token.write_text(secrets.token_hex(32))
    env = {**os.environ, "RAY_AUTH_MODE": "token", "RAY_AUTH_TOKEN_PATH": str(token), "RAY_USAGE_STATS_ENABLED": "0",
           "COLUMNS": "200"}
    head = subprocess.Popen([_bin("ray"), "start", "--head", "--port", str(port), "--num-cpus", "2",
                             "--include-dashboard=false", "--disable-usage-stats", "--temp-dir", str(ray_tmp), "--block"],
                            env=env, start_new_session=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        def listening() -> bool:
            with socket.socket() as s:
                return s.connect_ex(("127.0.0.1", port)) == 0

        _wait_for(lambda: listening() or head.poll() is not None, 180, "the Ray head")
        assert head.poll() is None, "ray start --head ended"
        seq_file = tmp_path / "sequences.txt"
        seq_file.write_text(f"{streets['broken']}\n")  # fails in its first task: enough to show where tasks run
        command = [_bin("idsplat-batch"), "--sequences", str(seq_file), "--output-dir", str(tmp_path / "out"),
                   "--method", METHOD, "--address", f"127.0.0.1:{port}"]
        without = {k: v for k, v in env.items() if k != "RAY_AUTH_MODE"}
        refused = subprocess.run(command, capture_output=True, text=True, timeout=300, env=without)
        last = refused.stderr.strip().splitlines()[-1]
        assert refused.returncode == 2 and "Traceback" not in refused.stderr, refused.stderr[-2000:]
        assert last.startswith(f"error: --address 127.0.0.1:{port}: the cluster uses Ray token authentication") and \
            "RAY_AUTH_MODE=token" in last and str(token) in last, last
        assert "InvalidAuthToken" not in refused.stderr  # Ray's ~20 retry lines are summed up in that one line

        ran = subprocess.run(command, capture_output=True, text=True, timeout=600, env=env)
        assert ran.returncode == 1, ran.stdout[-2000:] + ran.stderr[-2000:]  # the broken street's own failure
        assert ran.stdout.strip().splitlines()[-1] == "0 evaluated, 0 skipped (already evaluated), 1 failed: broken"
        status = json.loads((tmp_path / "out" / "broken" / METHOD / "status.json").read_text())
        assert status["step"] == "preprocess" and "front_camera/poses.json" in status["error"]
    finally:
        os.killpg(head.pid, signal.SIGTERM)
        try:
            head.wait(timeout=60)
        except subprocess.TimeoutExpired:
            os.killpg(head.pid, signal.SIGKILL)
            head.wait()
        shutil.rmtree(ray_tmp, ignore_errors=True)
