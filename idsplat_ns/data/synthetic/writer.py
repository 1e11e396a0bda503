"""Write a synthetic sequence in the PandaSet on-disk layout, plus the project's extras.

Layout (see docs/synthetic.md): camera/<cam>/{NN.jpg, intrinsics.json, poses.json, timestamps.json},
lidar/{NN.pkl.gz, poses.json, timestamps.json}, annotations/cuboids/NN.pkl.gz,
meta/{timestamps.json, gps.json}, idsplat_extras/{lidar_noreturn/NN.npz,
instance_masks/<cam>/NN.png, instances.json, generator.json}.

Every file is a deterministic function of (config, seed): gzip headers carry no time stamp,
zip entries a fixed date, JSON a fixed key order.
"""

from __future__ import annotations

import gzip
import io
import json
import os
import pickle
import shutil
import zipfile
from pathlib import Path

import numpy as np
import pandas as pd
from PIL import Image

from idsplat_ns.data.geometry import rotmat_to_quat
from idsplat_ns.errors import IDSplatError

CUBOID_COLUMNS = [
    "uuid",
    "label",
    "yaw",
    "stationary",
    "camera_used",
    "position.x",
    "position.y",
    "position.z",
    "dimensions.x",
    "dimensions.y",
    "dimensions.z",
    "attributes.object_motion",
    "cuboids.sibling_id",
    "cuboids.sensor_id",
    "attributes.rider_status",
    "attributes.pedestrian_behavior",
    "attributes.pedestrian_age",
]
"""Columns of PandaSet's cuboid DataFrames, in the devkit's order."""


def pose_dict(rotation: np.ndarray, position: np.ndarray) -> dict:
    """PandaSet pose record for a sensor-to-world rotation [3, 3] and position [3]."""
    w, x, y, z = rotmat_to_quat(rotation)  # one canonical sign: w >= 0
    return {
        "position": {"x": float(position[0]), "y": float(position[1]), "z": float(position[2])},
        "heading": {"w": float(w), "x": float(x), "y": float(y), "z": float(z)},
    }


def write_json(path: Path, data) -> None:
    """JSON with a fixed layout (deterministic bytes)."""
    path.write_text(json.dumps(data, indent=1) + "\n")


def write_pickle_gz(path: Path, df: pd.DataFrame) -> None:
    """A gzip-compressed pickle that `pd.read_pickle(path)` reads; no time stamp in the gzip header."""
    path.write_bytes(gzip.compress(pickle.dumps(df, protocol=4), compresslevel=1, mtime=0))


def write_npz(path: Path, **arrays: np.ndarray) -> None:
    """Like `np.savez_compressed`, with fixed zip dates so that the bytes are deterministic."""
    with zipfile.ZipFile(path, "w", compression=zipfile.ZIP_DEFLATED) as zf:
        for name, arr in arrays.items():
            buf = io.BytesIO()
            np.lib.format.write_array(buf, np.ascontiguousarray(arr), allow_pickle=False)
            info = zipfile.ZipInfo(f"{name}.npy", date_time=(1980, 1, 1, 0, 0, 0))
            info.compress_type = zipfile.ZIP_DEFLATED
            zf.writestr(info, buf.getvalue())


def write_jpeg(path: Path, image: np.ndarray, quality: int) -> None:
    """RGB uint8 [H, W, 3] as JPEG."""
    Image.fromarray(image, mode="RGB").save(path, format="JPEG", quality=quality)


def lidar_frame(points: np.ndarray, intensity: np.ndarray, times: np.ndarray) -> pd.DataFrame:
    """PandaSet lidar DataFrame: x, y, z (world, float64), i (0..255), t (unix s), d (0 = Pandar64)."""
    return pd.DataFrame(
        {
            "x": points[:, 0].astype(np.float64),
            "y": points[:, 1].astype(np.float64),
            "z": points[:, 2].astype(np.float64),
            "i": intensity.astype(np.float64),
            "t": times.astype(np.float64),
            "d": np.zeros(len(points), dtype=np.int64),
        }
    )


def cuboid_frame(rows: list[dict]) -> pd.DataFrame:
    """PandaSet cuboid DataFrame from per-object dicts (missing attributes become NaN)."""
    df = pd.DataFrame(rows, columns=CUBOID_COLUMNS)
    for col in ("yaw", "position.x", "position.y", "position.z", "dimensions.x", "dimensions.y", "dimensions.z"):
        df[col] = df[col].astype(np.float64)
    df["stationary"] = df["stationary"].astype(bool)
    df["camera_used"] = df["camera_used"].astype(np.int64)
    df["cuboids.sensor_id"] = df["cuboids.sensor_id"].astype(np.int64)
    # Plain object columns like the real files (pandas >= 3 would otherwise infer its string dtype).
    for col in ("uuid", "label", "attributes.object_motion", "cuboids.sibling_id", "attributes.rider_status",
                "attributes.pedestrian_behavior", "attributes.pedestrian_age"):
        df[col] = df[col].astype(object)
    return df


def replace_folder_atomically(tmp: Path, final: Path) -> None:
    """Move the finished `tmp` folder to `final`, replacing an existing one only after success."""
    if final.exists():
        trash = final.with_name(f".{final.name}.old-{os.getpid()}")
        final.rename(trash)
        tmp.rename(final)
        shutil.rmtree(trash)
    else:
        tmp.rename(final)


def check_writable(out_dir: Path) -> None:
    """Create `out_dir` or fail with one line naming it."""
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise IDSplatError(f"cannot create output folder {out_dir}: {err.strerror}; choose another --out") from None
