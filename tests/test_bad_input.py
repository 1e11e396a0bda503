"""Bad data never train silently (issue 25; bad settings: test_bad_settings.py).

Table-driven: each case damages a copy of the ``tiny`` street (or a Waymo segment) and asserts a
one-line :class:`IDSplatError` naming the file (and frame and field) or the option.
Most cases call the readers directly (fast); a few go through the real
``ns-train``/``ns-eval`` (slow: ~12 s of imports each), asserting the exit code, the last line,
no traceback and an empty output folder.
"""

from __future__ import annotations

import copy
import gzip
import json
import os
import pickle
import shutil
import subprocess
import sys
from pathlib import Path
from typing import Callable

import numpy as np
import pandas as pd
import pytest
import scipy.linalg
from scipy.spatial.transform import Rotation

from idsplat_ns.data.pandaset import load_sequence
from idsplat_ns.errors import IDSplatError

REPO = Path(__file__).resolve().parents[1]
WAYMO_FRAME = REPO.parent / "shared" / "data" / "waymo" / "pvps_data_one_frame.tfrecord"


# --- PandaSet layout: (case id, damage, file named, words the line must hold) ---------------------

def _edit_json(rel: str, edit: Callable) -> Callable[[Path], None]:
    def damage(root: Path) -> None:
        path = root / rel
        data = json.loads(path.read_text())
        new = edit(data)  # None: edited in place; anything else replaces the content
        data = data if new is None else new
        path.write_text(json.dumps(data))  # json writes NaN/Infinity, which json.loads reads back
    return damage


def _set(d: dict, *keys_and_value) -> None:
    *keys, last, value = keys_and_value
    for k in keys:
        d = d[k]
    d[last] = value


def _drop(d: dict, key: str) -> None:
    del d[key]  # returns None: _edit_json then keeps the edited object


def _edit_pickle(rel: str, edit: Callable[[pd.DataFrame], pd.DataFrame]) -> Callable[[Path], None]:
    def damage(root: Path) -> None:
        path = root / rel
        df = edit(pd.read_pickle(path))
        with gzip.open(path, "wb") as fh:
            pickle.dump(df, fh)
    return damage


def _with_nan(column: str, row: int = 0) -> Callable[[pd.DataFrame], pd.DataFrame]:
    def edit(df: pd.DataFrame) -> pd.DataFrame:
        df = df.copy()
        df.loc[df.index[row], column] = np.nan
        return df
    return edit


def _resize_image(root: Path) -> None:
    from PIL import Image

    path = root / "camera" / "front_camera" / "04.jpg"
    with Image.open(path) as im:
        im.resize((im.width // 2, im.height // 2)).save(path)


def _replace_image(make: Callable[[Path], None]) -> Callable[[Path], None]:
    def damage(root: Path) -> None:
        path = root / "camera" / "front_camera" / "05.jpg"
        path.unlink()
        make(path)
    return damage


CAM = "camera/front_camera"
PANDASET_CASES = [
    ("nan-camera-position", _edit_json(f"{CAM}/poses.json", lambda d: _set(d[3], "position", "x", float("nan"))),
     f"{CAM}/poses.json", ["frame 3", "position", "not finite"]),
    ("nan-camera-quaternion", _edit_json(f"{CAM}/poses.json", lambda d: _set(d[2], "heading", "w", float("nan"))),
     f"{CAM}/poses.json", ["frame 2", "heading"]),
    ("zero-quaternion", _edit_json(f"{CAM}/poses.json", lambda d: _set(d[1], "heading", {"w": 0, "x": 0, "y": 0, "z": 0})),
     f"{CAM}/poses.json", ["frame 1", "heading", "zero norm"]),
    ("inf-lidar-position", _edit_json("lidar/poses.json", lambda d: _set(d[5], "position", "z", float("inf"))),
     "lidar/poses.json", ["frame 5", "position"]),
    ("pose-without-heading", _edit_json(f"{CAM}/poses.json", lambda d: _drop(d[4], "heading")),
     f"{CAM}/poses.json", ["frame 4", "heading"]),
    ("poses-empty", _edit_json(f"{CAM}/poses.json", lambda d: []), f"{CAM}/poses.json", ["non-empty"]),
    ("fewer-camera-poses", _edit_json(f"{CAM}/poses.json", lambda d: d[:6]), f"{CAM}/poses.json", ["6 entries for 10 frames"]),
    ("fx-zero", _edit_json(f"{CAM}/intrinsics.json", lambda d: _set(d, "fx", 0)), f"{CAM}/intrinsics.json", ["fx", "> 0"]),
    ("fy-negative", _edit_json(f"{CAM}/intrinsics.json", lambda d: _set(d, "fy", -80.0)), f"{CAM}/intrinsics.json", ["fy"]),
    ("fx-nan", _edit_json(f"{CAM}/intrinsics.json", lambda d: _set(d, "fx", float("nan"))), f"{CAM}/intrinsics.json", ["fx", "not finite"]),
    ("cx-outside-image", _edit_json(f"{CAM}/intrinsics.json", lambda d: _set(d, "cx", 5000.0)), f"{CAM}/intrinsics.json", ["cx", "outside"]),
    ("cy-negative", _edit_json(f"{CAM}/intrinsics.json", lambda d: _set(d, "cy", -1.0)), f"{CAM}/intrinsics.json", ["cy", "outside"]),
    ("intrinsics-missing-key", _edit_json(f"{CAM}/intrinsics.json", lambda d: _drop(d, "cy")), f"{CAM}/intrinsics.json", ["fx, fy, cx, cy"]),
    ("intrinsics-text", _edit_json(f"{CAM}/intrinsics.json", lambda d: _set(d, "fx", "eighty")), f"{CAM}/intrinsics.json", ["numbers"]),
    ("lidar-timestamp-duplicate", _edit_json("lidar/timestamps.json", lambda d: _set(d, 5, d[4])),
     "lidar/timestamps.json", ["frame 5", "duplicates frame 4"]),
    ("lidar-timestamp-backwards", _edit_json("lidar/timestamps.json", lambda d: _set(d, 7, d[2])),
     "lidar/timestamps.json", ["frame 7", "goes back"]),
    ("camera-timestamp-nan", _edit_json(f"{CAM}/timestamps.json", lambda d: _set(d, 3, float("nan"))),
     f"{CAM}/timestamps.json", ["not finite"]),
    ("camera-timestamps-text", _edit_json(f"{CAM}/timestamps.json", lambda d: {"a": 1}), f"{CAM}/timestamps.json", ["not numbers"]),
    ("fewer-camera-timestamps", _edit_json(f"{CAM}/timestamps.json", lambda d: d[:3]), f"{CAM}/timestamps.json", ["3 entries for 10 frames"]),
    ("lidar-nan-x", _edit_pickle("lidar/03.pkl.gz", _with_nan("x")), "lidar/03.pkl.gz", ["frame 3", "column x", "not finite"]),
    ("lidar-nan-time", _edit_pickle("lidar/06.pkl.gz", _with_nan("t", 10)), "lidar/06.pkl.gz", ["frame 6", "column t"]),
    ("lidar-missing-column", _edit_pickle("lidar/02.pkl.gz", lambda df: df.drop(columns=["i"])), "lidar/02.pkl.gz", ["lacks columns ['i']"]),
    ("cuboid-nan-position", _edit_pickle("annotations/cuboids/01.pkl.gz", _with_nan("position.y")),
     "annotations/cuboids/01.pkl.gz", ["frame 1", "position.y"]),
    ("image-size-differs", _resize_image, "camera/front_camera", ["frame 4", "image size"]),
    ("image-missing", _replace_image(lambda p: None), f"{CAM}/05.jpg", ["the image is missing"]),
    ("image-is-a-folder", _replace_image(lambda p: p.mkdir()), f"{CAM}/05.jpg", ["the image is a folder"]),
    ("image-link-loop", _replace_image(lambda p: p.symlink_to(p.name)), f"{CAM}/05.jpg", ["symbolic link loop"]),
    ("image-broken-link", _replace_image(lambda p: p.symlink_to("gone.jpg")), f"{CAM}/05.jpg", ["broken symbolic link (to gone.jpg)"]),
]


@pytest.fixture()
def street_copy(tiny_street: Path, tmp_path: Path) -> Path:
    root = tmp_path / "street"
    shutil.copytree(tiny_street, root)
    return root


def _one_line(err: IDSplatError) -> str:
    text = str(err)
    assert "\n" not in text, text
    return text


@pytest.mark.parametrize("damage,file,words", [c[1:] for c in PANDASET_CASES], ids=[c[0] for c in PANDASET_CASES])
def test_damaged_pandaset_fails_in_one_line(street_copy: Path, damage, file: str, words: list[str]) -> None:
    damage(street_copy)
    with pytest.raises(IDSplatError) as info:
        load_sequence(street_copy)
    line = _one_line(info.value)
    assert str(street_copy / file) in line, line
    for word in words:
        assert word in line, (word, line)


def test_slightly_off_quaternion_is_renormalised_with_a_warning(street_copy: Path, capsys) -> None:
    undamaged = load_sequence(street_copy)
    path = street_copy / CAM / "poses.json"
    poses = json.loads(path.read_text())
    for entry in poses:  # a stored quaternion scaled by 1.01: a precision loss, not damage
        entry["heading"] = {k: v * 1.01 for k, v in entry["heading"].items()}
    path.write_text(json.dumps(poses))
    scene = load_sequence(street_copy)
    for image, before in zip(scene.images, undamaged.images):  # a scaled quaternion is the same rotation
        assert np.allclose(image.camera_to_world, before.camera_to_world, atol=1e-9)
    err = capsys.readouterr().err
    assert err.count("warning:") == 1 and "renormalised" in err and "poses.json" in err


# --- Validation functions alone --------------------------------------------------------------------

def test_rotation_checks() -> None:
    from idsplat_ns.data.validation import check_pose, check_rotation

    R = np.eye(3)
    R[0, 1] = 1e-3  # slightly off: projected back onto SO(3)
    fixed = check_rotation(R, "f.json", "pose", 0)
    assert np.allclose(fixed, scipy.linalg.polar(R)[0], atol=1e-12)  # the nearest rotation
    exact = Rotation.from_rotvec([0.3, -0.2, 1.1]).as_matrix()
    assert np.array_equal(check_rotation(exact, "f.json", "pose", 0), exact)  # within tolerance: unchanged
    with pytest.raises(IDSplatError, match=r"f.json: frame 2: pose: not a rotation"):
        check_rotation(np.diag([1.0, 1.0, -1.0]), "f.json", "pose", 2)  # a reflection
    bad = np.eye(4)
    bad[3, 0] = 1.0
    with pytest.raises(IDSplatError, match="last row"):
        check_pose(bad, "f.json", "pose")


# --- Waymo v1 and v2 ---------------------------------------------------------------------------------

def _frames():
    from idsplat_ns.data.waymo import proto
    from idsplat_ns.data.waymo.tfrecord import iter_records

    frames = []
    for _, data in iter_records(WAYMO_FRAME):
        frame = proto.Frame()
        frame.ParseFromString(data)
        frames.append(frame)
    return frames


def _nan_vehicle_pose(frames):
    frames[0].pose.transform[3] = float("nan")


def _zero_focal(frames):
    frames[0].context.camera_calibrations[0].intrinsic[0] = 0.0


def _nan_image_pose(frames):
    frames[0].images[1].pose.transform[7] = float("inf")


def _scaled_rotation(frames):
    for k in (0, 5, 10):
        frames[0].pose.transform[k] *= 2.0


def _repeated_frame(frames):
    frames.append(copy.deepcopy(frames[0]))


WAYMO_CASES = [
    ("v1-nan-vehicle-pose", _nan_vehicle_pose, ["frame 0", "vehicle pose", "not finite"]),
    ("v1-zero-focal", _zero_focal, ["fx", "> 0"]),
    ("v1-inf-image-pose", _nan_image_pose, ["frame 0", "image pose", "not finite"]),
    ("v1-scaled-rotation", _scaled_rotation, ["vehicle pose", "not a rotation"]),
    ("v1-duplicate-timestamp", _repeated_frame, ["frame 1", "duplicates"]),
]


@pytest.mark.skipif(not WAYMO_FRAME.is_file(), reason="real Waymo frame not present")
@pytest.mark.parametrize("damage,words", [c[1:] for c in WAYMO_CASES], ids=[c[0] for c in WAYMO_CASES])
def test_damaged_waymo_v1_fails_in_one_line(tmp_path: Path, damage, words: list[str]) -> None:
    from idsplat_ns.data.waymo import load_segment
    from idsplat_ns.data.waymo.tfrecord import write_records

    frames = _frames()
    damage(frames)
    path = tmp_path / "segment.tfrecord"
    write_records(path, [f.SerializeToString() for f in frames])
    with pytest.raises(IDSplatError) as info:
        load_segment(path, progress=False)
    line = _one_line(info.value)
    assert str(path) in line, line
    for word in words:
        assert word in line, (word, line)


@pytest.mark.skipif(not WAYMO_FRAME.is_file(), reason="real Waymo frame not present")
def test_damaged_waymo_v2_vehicle_pose(tmp_path: Path) -> None:
    import pyarrow as pa
    import pyarrow.parquet as pq

    from idsplat_ns.data.waymo import load_segment
    from idsplat_ns.data.waymo.fixtures import write_synthetic_segment, write_v2_from_v1

    seg = write_synthetic_segment(WAYMO_FRAME, tmp_path / "seg.tfrecord", 3, top_width=200, side_shape=(20, 60))
    context = write_v2_from_v1(seg, tmp_path / "v2")
    path = tmp_path / "v2" / "training" / "vehicle_pose" / f"{context}.parquet"
    table = pq.read_table(path)
    column = "[VehiclePoseComponent].world_from_vehicle.transform"
    values = table.column(column).to_pylist()
    values[1] = [float("nan")] + list(values[1][1:])
    table = table.set_column(table.schema.get_field_index(column), column, pa.array(values, table.schema.field(column).type))
    pq.write_table(table, path)
    with pytest.raises(IDSplatError) as info:
        load_segment(tmp_path / "v2", context_name=context, progress=False)
    line = _one_line(info.value)
    assert str(path) in line and "frame 1" in line and "vehicle pose" in line, line


def _run(args: list[str], cwd: Path) -> subprocess.CompletedProcess:
    env = dict(os.environ, PYTHONWARNINGS="ignore")
    return subprocess.run(args, cwd=cwd, env=env, capture_output=True, text=True, timeout=300)


def _assert_one_line_error(proc: subprocess.CompletedProcess, named: str) -> None:
    err = proc.stderr.strip().splitlines()
    assert proc.returncode == 2, proc.stderr[-2000:]
    assert "Traceback" not in proc.stderr and "Traceback" not in proc.stdout
    assert err and err[-1].startswith("error: ") and named in err[-1], err[-1:]


CLI_CASES = [
    ("nan-camera-pose", PANDASET_CASES[0][1], [], f"{CAM}/poses.json"),
    ("fx-zero", PANDASET_CASES[7][1], [], f"{CAM}/intrinsics.json"),
    ("downscale-zero", None, ["idsplat-auto", "--downscale-factor", "0"], "--downscale-factor"),
    ("negative-lr", None, ["--optimizers.means.optimizer.lr", "-0.001"], "--optimizers.means.optimizer.lr"),
]


@pytest.mark.slow
@pytest.mark.parametrize("damage,extra,named", [c[1:] for c in CLI_CASES], ids=[c[0] for c in CLI_CASES])
def test_ns_train_fails_in_one_line_and_leaves_nothing(street_copy: Path, tmp_path: Path, damage, extra, named) -> None:
    if damage is not None:
        damage(street_copy)
    out = tmp_path / "outputs"
    method = ["idsplat-fast", "--max-num-iterations", "3", "--vis", "tensorboard", "--output-dir", str(out)]
    data = ["--data", str(street_copy)]
    # The dataparser subcommand comes after the method options; --data then belongs to it.
    args = method + (extra[:1] + data + extra[1:] if extra[:1] == ["idsplat-auto"] else extra + data)
    proc = _run([str(Path(sys.executable).parent / "ns-train"), *args], tmp_path)
    _assert_one_line_error(proc, named)
    assert not out.exists(), sorted(out.rglob("*"))  # ns-train made --output-dir: it goes too


@pytest.mark.slow
def test_ns_eval_missing_config_is_one_line(tmp_path: Path) -> None:
    proc = _run([str(Path(sys.executable).parent / "ns-eval"), "--load-config", "/nonexistent/config.yml"], tmp_path)
    _assert_one_line_error(proc, "/nonexistent/config.yml")


def test_empty_lidar_sweeps_are_named_once(tiny_street: Path, capsys) -> None:
    from idsplat_ns.data.scene import note_empty_sweeps

    scene = load_sequence(tiny_street)
    for k in (2, 5):
        scene.lidar[k] = scene.lidar[k].select(np.zeros(scene.lidar[k].num_rays, dtype=bool))  # a sweep of zero points
    assert note_empty_sweeps(scene) == [scene.lidar[2].frame_index, scene.lidar[5].frame_index]
    note_empty_sweeps(scene)  # said once per sequence, not per call
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "2 of 10 frames hold no point (frames 2, 5)" in err[0], err


def test_outputs_are_checked_before_any_work(tmp_path: Path) -> None:
    from idsplat_ns.atomic import check_writable
    from idsplat_ns.cli.preprocess import PreprocessArgs, preprocess

    a_file = tmp_path / "a-file"
    a_file.write_text("x")
    check_writable(tmp_path / "new" / "deeper", "--output-dir", folder=True)  # made later: fine
    assert not (tmp_path / "new").exists()
    with pytest.raises(IDSplatError, match=f"--output-dir {a_file}: is a file, not a folder"):
        check_writable(a_file, "--output-dir", folder=True)
    with pytest.raises(IDSplatError, match=f"--export {tmp_path}: is a folder, not a file"):
        check_writable(tmp_path, "--export", folder=False)
    with pytest.raises(IDSplatError, match=f"--export {a_file / 'tracks.json'}: {a_file} is not a folder"):
        check_writable(a_file / "tracks.json", "--export", folder=False)
    # idsplat-preprocess says so before it reads the data (here: none at that path at all).
    with pytest.raises(IDSplatError, match="--export"):
        preprocess(PreprocessArgs(data=tmp_path / "no-such-street", export=a_file / "tracks.json"))
    if os.geteuid() != 0:  # root writes anywhere: a read-only folder stops only other users
        locked = tmp_path / "locked"
        locked.mkdir(mode=0o500)
        with pytest.raises(IDSplatError, match="is not writable"):
            check_writable(locked / "tracks.json", "--export", folder=False)


@pytest.mark.parametrize("options,words", [
    (["--exposure-drift", "1.5"], ["--exposure-drift", "less than 1"]),
    (["--exposure-drift", "-0.1"], ["--exposure-drift"]),
    (["--calibration-error-deg", "nan", "0"], ["--calibration-error-deg"]),
    (["--calibration-error-deg", "1", "45"], ["--calibration-error-deg", "-10 to 10"]),
    (["--pose-noise", "0.5", "-0.1"], ["--pose-noise", "0 to 2 metres"]),
    (["--pose-noise", "inf", "0.1"], ["--pose-noise", "0 to 5 degrees"]),
], ids=["drift-above-one", "drift-negative", "calibration-nan", "calibration-45-degrees", "pose-noise-negative",
        "pose-noise-infinite"])
def test_bad_rig_defect_option_of_idsplat_synth_fails_in_one_line(tmp_path: Path, options, words, monkeypatch, capsys) -> None:
    """idsplat-synth's rig defects out of range: one line naming the option, exit 2, nothing written."""
    from idsplat_ns.data.synthetic.cli import main

    out = tmp_path / "out"
    monkeypatch.setattr("sys.argv", ["idsplat-synth", "--preset", "tiny", "--out", str(out), *options])
    with pytest.raises(SystemExit) as info:
        main()
    assert info.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and all(w in err[0] for w in words), err
    assert not out.exists()
