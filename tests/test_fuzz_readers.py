"""Damaged files end in the project's one-line error or in a clean, sane read, never anything else.

Fixed-seed fuzzing of every reader (issue 25): PandaSet-layout JSON and lidar/cuboid pickles,
a Waymo v1 TFRecord and Waymo v2 parquet components. Three kinds of damage per format:

- bytes: bit flips, a truncation, or a run of random bytes in the file as stored;
- payload: the same inside the container with its checksum made valid again (gzip, TFRecord's
  CRC32C), so that the damage reaches the parser instead of the checksum;
- value: one field set to NaN, inf, zero, a negative or huge number, text, or dropped, so that the
  damage reaches the validation.

A read that succeeds must be sane (finite poses, times, lidar and boxes; positive intrinsics with the
principal point inside the image; decodable images), or the damage trained silently.
"""

from __future__ import annotations

import gzip
import json
import pickle
import shutil
from collections import Counter
from pathlib import Path
from typing import Callable

import numpy as np
import pandas as pd
import pytest

from idsplat_ns.data.scene import Scene
from idsplat_ns.errors import IDSplatError

REPO = Path(__file__).resolve().parents[1]
WAYMO_FRAME = REPO.parent / "shared" / "data" / "waymo" / "pvps_data_one_frame.tfrecord"
ODD_VALUES = [float("nan"), float("inf"), float("-inf"), 0.0, -1.0, 1e30, -1e30, 1e-30, "text", None]


# --- damage -----------------------------------------------------------------------------------------

def damage_bytes(data: bytes, rng: np.random.Generator) -> bytes:
    """Bit flips, a truncation or an overwritten run of bytes (one of the three, at random)."""
    kind = int(rng.integers(3))
    if kind == 1 or len(data) == 0:
        return data[: int(rng.integers(len(data) + 1))]
    out = bytearray(data)
    if kind == 0:
        for _ in range(int(rng.integers(1, 9))):
            i = int(rng.integers(len(out)))
            out[i] ^= 1 << int(rng.integers(8))
    else:
        i, n = int(rng.integers(len(out))), int(rng.integers(1, 17))
        out[i:i + n] = rng.integers(0, 256, n, dtype=np.uint8).tobytes()
    return bytes(out)


def odd_value(rng: np.random.Generator, old):
    value = ODD_VALUES[int(rng.integers(len(ODD_VALUES)))]
    if isinstance(value, float) and abs(value) == 1.0 and isinstance(old, (int, float)) and not isinstance(old, bool):
        return -old  # a sign flip of the real value (a negative time, a mirrored pose)
    return value


def damage_json_value(data, rng: np.random.Generator):
    """One leaf of a JSON document replaced by an odd value, or one key / list element dropped."""
    parents = []

    def walk(node):
        items = node.items() if isinstance(node, dict) else enumerate(node) if isinstance(node, list) else []
        for key, child in items:
            parents.append((node, key))
            walk(child)

    walk(data)
    if not parents:
        return odd_value(rng, data)
    node, key = parents[int(rng.integers(len(parents)))]
    if rng.random() < 0.2:
        del node[key]
    else:
        node[key] = odd_value(rng, node[key])
    return data


def damage_frame_value(df: pd.DataFrame, rng: np.random.Generator) -> pd.DataFrame:
    """One cell set to an odd value, one column dropped, or every row dropped."""
    df = df.copy()
    roll = rng.random()
    if roll < 0.15:
        return df.drop(columns=[df.columns[int(rng.integers(len(df.columns)))]])
    if roll < 0.2:
        return df.iloc[:0]
    column = df.columns[int(rng.integers(len(df.columns)))]
    row = df.index[int(rng.integers(len(df)))]
    value = odd_value(rng, df.at[row, column])
    if value is not None and not isinstance(value, str) and df[column].dtype.kind in "iub":
        df[column] = df[column].astype(np.float64)  # an int column takes NaN only as floats
    elif isinstance(value, str) or value is None:
        df[column] = df[column].astype(object)
    df.at[row, column] = value
    return df


# --- what a successful read must satisfy ------------------------------------------------------------

def assert_sane(scene: Scene, decode_images: bool = True) -> None:
    from idsplat_ns.data.images import load_rgb

    assert np.isfinite(scene.ego_poses).all() and np.isfinite(scene.frame_times).all()
    assert np.all(np.diff(scene.frame_times) > 0)
    for im in scene.images:
        K = im.intrinsics
        assert np.isfinite(im.camera_to_world).all() and np.isfinite(im.time)
        R = im.camera_to_world[:3, :3]
        assert np.allclose(R.T @ R, np.eye(3), atol=1e-3)
        assert K.fx > 0 and K.fy > 0 and 0 <= K.cx <= K.width and 0 <= K.cy <= K.height, K
        assert np.isfinite(np.asarray(K.distortion)).all()
        if decode_images:
            rgb = load_rgb(im)
            assert rgb.shape[:2] == (K.height, K.width)
    for sweep in scene.lidar:
        for name in ("origins", "directions", "ranges", "intensities", "times"):
            assert np.isfinite(getattr(sweep, name)).all(), name
        assert np.all(sweep.ranges >= 0)
        hit = sweep.returned
        assert np.allclose(np.linalg.norm(sweep.directions[hit], axis=-1), 1.0, atol=1e-3)
    for track in scene.tracks:
        assert np.isfinite(track.poses).all() and np.isfinite(track.times).all()
        assert np.isfinite(track.size).all() and np.all(track.size > 0)


def run_case(tag: str, load: Callable[[], Scene], outcomes: Counter, failures: list, decode_images: bool = True) -> None:
    """Load once; record 'read' or 'error'; anything else (or an insane read) goes to ``failures``."""
    try:
        scene = load()
    except IDSplatError as err:
        text = str(err)
        if "\n" in text or not text.strip():
            failures.append(f"{tag}: error is not one line: {text!r}")
        outcomes["error"] += 1
        return
    except Exception as err:  # noqa: BLE001 - exactly what the test is looking for
        failures.append(f"{tag}: {type(err).__name__}: {err}"[:400])
        return
    try:
        assert_sane(scene, decode_images)
    except IDSplatError:
        outcomes["error"] += 1  # the damage surfaced when the image was decoded, in one line
        return
    except AssertionError as err:
        failures.append(f"{tag}: read but not sane: {err}"[:400])
        return
    outcomes["read"] += 1


def _check(outcomes: Counter, failures: list, cases: int) -> None:
    assert not failures, f"{len(failures)} of {cases} damaged files escaped:\n" + "\n".join(failures[:20])
    assert outcomes["error"] > cases // 4, outcomes  # the damage was real, most of it caught


# --- PandaSet layout (the built-in street as written by idsplat-synth) ------------------------------

PANDASET_FILES = [
    "camera/front_camera/poses.json", "camera/front_camera/intrinsics.json", "camera/front_camera/timestamps.json",
    "lidar/poses.json", "lidar/timestamps.json", "lidar/00.pkl.gz", "lidar/01.pkl.gz", "annotations/cuboids/01.pkl.gz",
    "camera/front_camera/00.jpg",
]


def _link_copy(src: Path, dst: Path, replaced: str) -> Path:
    """A copy of the street made of symlinks (fast), with ``replaced`` a real file to damage."""
    shutil.rmtree(dst, ignore_errors=True)
    shutil.copytree(src, dst, copy_function=lambda s, d: Path(d).symlink_to(Path(s).resolve()))
    (dst / replaced).unlink()
    return dst / replaced


def _damage_pandaset_file(data: bytes, rel: str, kind: str, rng: np.random.Generator) -> bytes:
    if kind == "bytes":
        return damage_bytes(data, rng)
    if rel.endswith(".json"):
        if kind == "payload":
            return damage_bytes(data, rng)  # JSON has no checksum: bytes and payload are one
        return json.dumps(damage_json_value(json.loads(data), rng)).encode()
    if rel.endswith(".pkl.gz"):
        raw = gzip.decompress(data)
        if kind == "payload":
            return gzip.compress(damage_bytes(raw, rng), mtime=0)
        return gzip.compress(pickle.dumps(damage_frame_value(pickle.loads(raw), rng), protocol=4), mtime=0)
    return damage_bytes(data, rng)  # a JPEG: its decoder is the checksum


def test_fuzz_pandaset_readers(tiny_street: Path, tmp_path: Path) -> None:
    from idsplat_ns.data.pandaset import load_sequence

    rng = np.random.default_rng(2025)
    outcomes, failures = Counter(), []
    cases = 270
    for case in range(cases):
        rel = PANDASET_FILES[case % len(PANDASET_FILES)]
        kind = ("bytes", "payload", "value")[(case // len(PANDASET_FILES)) % 3]
        original = (tiny_street / rel).read_bytes()
        target = _link_copy(tiny_street, tmp_path / "street", rel)
        target.write_bytes(_damage_pandaset_file(original, rel, kind, rng))
        run_case(f"case {case} {kind} {rel}", lambda: load_sequence(target.parents[len(Path(rel).parts) - 1],
                                                                   cameras=["front_camera"], start=0, end=3),
                 outcomes, failures)
    _check(outcomes, failures, cases)


# --- Waymo v1 TFRecord -----------------------------------------------------------------------------

def _waymo_value_edit(frame, rng: np.random.Generator) -> None:
    """One numeric field of a Waymo Frame set to an odd value (poses, calibration, times, labels)."""
    targets = [
        (frame.pose.transform, None),
        (frame.context.camera_calibrations[0].intrinsic, None),
        (frame.context.camera_calibrations[0].extrinsic.transform, None),
        (frame.context.laser_calibrations[0].extrinsic.transform, None),
        (frame.images[0].pose.transform, None),
    ]
    scalars = [
        (frame.images[0], "pose_timestamp"), (frame.images[0], "camera_trigger_time"),
        (frame.images[0], "camera_readout_done_time"), (frame.context.camera_calibrations[0], "width"),
        (frame.context.camera_calibrations[0], "height"), (frame, "timestamp_micros"),
        (frame.context.laser_calibrations[0], "beam_inclination_min"),
        (frame.context.laser_calibrations[0], "beam_inclination_max"),
    ]
    if len(frame.laser_labels):
        box = frame.laser_labels[0].box
        scalars += [(box, "center_x"), (box, "length"), (box, "heading")]
    if rng.random() < 0.5:
        field, _ = targets[int(rng.integers(len(targets)))]
        value = odd_value(rng, 1.0)
        field[int(rng.integers(len(field)))] = value if isinstance(value, float) else float("nan")
        return
    owner, name = scalars[int(rng.integers(len(scalars)))]
    value = odd_value(rng, getattr(owner, name))
    is_int = isinstance(getattr(owner, name), int)
    if not isinstance(value, float):
        value = 0.0
    if is_int:
        value = 0 if not np.isfinite(value) else int(max(min(value, 2**31 - 1), -2**31))
    try:
        setattr(owner, name, value)
    except ValueError:  # a negative value in an unsigned field
        setattr(owner, name, 0)


@pytest.fixture(scope="module")
def waymo_segment(tmp_path_factory) -> Path:
    if not WAYMO_FRAME.is_file():
        pytest.skip("real Waymo frame not present")
    from idsplat_ns.data.waymo.fixtures import write_synthetic_segment

    out = tmp_path_factory.mktemp("fuzz_waymo") / "seg.tfrecord"
    return write_synthetic_segment(WAYMO_FRAME, out, 2, top_width=200, side_shape=(20, 60))


def test_fuzz_waymo_v1_reader(waymo_segment: Path, tmp_path: Path) -> None:
    from idsplat_ns.data.waymo import load_segment
    from idsplat_ns.data.waymo import proto
    from idsplat_ns.data.waymo.tfrecord import iter_records, write_records

    records = [data for _, data in iter_records(waymo_segment)]
    raw = waymo_segment.read_bytes()
    rng = np.random.default_rng(2026)
    outcomes, failures = Counter(), []
    cases = 105
    target = tmp_path / "damaged.tfrecord"
    for case in range(cases):
        kind = ("bytes", "payload", "value")[case % 3]
        if kind == "bytes":
            target.write_bytes(damage_bytes(raw, rng))
        else:
            k = int(rng.integers(len(records)))
            damaged = list(records)
            if kind == "payload":
                # Damage outside the JPEGs (which are most of the bytes) as often as inside them.
                data = records[k]
                head = int(rng.integers(1, len(data)))
                part = data[:head] if rng.random() < 0.5 else data
                damaged[k] = damage_bytes(part, rng) + (data[head:] if part is not data else b"")
            else:
                frame = proto.Frame()
                frame.ParseFromString(records[k])
                _waymo_value_edit(frame, rng)
                damaged[k] = frame.SerializeToString()
            write_records(target, damaged)  # valid CRCs around the damage
        run_case(f"case {case} {kind}", lambda: load_segment(target, cameras=["FRONT"], progress=False), outcomes, failures)
    _check(outcomes, failures, cases)


# --- Waymo v2 parquet ------------------------------------------------------------------------------

V2_COMPONENTS = ["vehicle_pose", "camera_calibration", "camera_image", "lidar_calibration", "lidar", "lidar_pose", "lidar_box"]


def _parquet_value_edit(path: Path, rng: np.random.Generator) -> None:
    import pyarrow as pa
    import pyarrow.parquet as pq

    table = pq.read_table(path)
    columns = [c for c in table.column_names if not c.startswith("key.")]
    column = columns[int(rng.integers(len(columns)))]
    values = table.column(column).to_pylist()
    row = int(rng.integers(len(values)))
    old = values[row]
    if isinstance(old, list) and old:
        old = list(old)
        value = odd_value(rng, 1.0)
        old[int(rng.integers(len(old)))] = value if isinstance(value, float) else float("nan")
        values[row] = old
    elif isinstance(old, (bytes, str)):
        values[row] = old[: len(old) // 2]
    else:
        value = odd_value(rng, old)
        values[row] = value if isinstance(value, float) or value is None else None
    field = table.schema.field(column)
    try:
        array = pa.array(values, field.type)
    except (pa.ArrowInvalid, pa.ArrowTypeError, OverflowError):
        # The odd value does not fit the column's type: a null (or, in a list column, which cannot
        # hold one, a list of NaN) stands for it.
        filler = None
        if isinstance(old, list):
            filler = [float("nan") if pa.types.is_floating(field.type.value_type) else 0] * len(old)
        array = pa.array([filler if i == row else v for i, v in enumerate(values)], field.type)
    pq.write_table(table.set_column(table.schema.get_field_index(column), field.name, array), path)


def test_fuzz_waymo_v2_reader(waymo_segment: Path, tmp_path: Path) -> None:
    from idsplat_ns.data.waymo import load_segment
    from idsplat_ns.data.waymo.fixtures import write_v2_from_v1

    clean = tmp_path / "v2_clean"
    context = write_v2_from_v1(waymo_segment, clean)
    rng = np.random.default_rng(2027)
    outcomes, failures = Counter(), []
    cases = 112
    for case in range(cases):
        component = V2_COMPONENTS[case % len(V2_COMPONENTS)]
        kind = ("bytes", "value")[(case // len(V2_COMPONENTS)) % 2]
        rel = Path("training") / component / f"{context}.parquet"
        root = tmp_path / "v2"
        target = _link_copy(clean, root, str(rel))
        if kind == "bytes":
            target.write_bytes(damage_bytes((clean / rel).read_bytes(), rng))
        else:
            shutil.copyfile(clean / rel, target)
            _parquet_value_edit(target, rng)
        run_case(f"case {case} {kind} {component}",
                 lambda: load_segment(root, context_name=context, cameras=["FRONT"], progress=False), outcomes, failures)
    _check(outcomes, failures, cases)
