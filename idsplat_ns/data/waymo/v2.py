"""Waymo Open Dataset v2: ``<root>/<split>/<component>/<context>.parquet`` read with pyarrow.

Only the needed columns are read, in small row batches, and only rows of the selected frames
(by ``key.frame_timestamp_micros``) are kept, so memory grows with the frames asked for. Frame
numbers are the ranks of the sorted ``vehicle_pose`` timestamps (the same numbering as v1 records).
Column names are Waymo's: ``key.*`` and ``[<Component>].<field>.<subfield>``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Iterator, Optional, Sequence

import numpy as np

from idsplat_ns.data.waymo.records import (
    CAMERA_NAMES,
    LASER_NAMES,
    BoxLabel,
    CameraCalib,
    CameraFrame,
    FrameRecord,
    LidarCalib,
    LidarFrame,
    SegmentCalibration,
)
from idsplat_ns.data.waymo.v1 import resolve_names, sensor_rank
from idsplat_ns.data.validation import check_timestamps
from idsplat_ns.data.waymo.checks import check_calibration, check_frame
from idsplat_ns.errors import IDSplatError

SPLITS = ("training", "validation", "testing")
TS = "key.frame_timestamp_micros"
CAM = "key.camera_name"
LASER = "key.laser_name"
_BATCH_ROWS = 8  # camera and lidar rows are MBs each


def col(component: str, field: str) -> str:
    """Waymo's v2 column name, e.g. ``col('VehiclePoseComponent', 'world_from_vehicle.transform')``."""
    return f"[{component}].{field}"


def find_component_dir(root: Path, context_name: str) -> Path:
    """The folder holding the component folders for this context (``root`` itself or a split)."""
    for base in [root] + [root / s for s in SPLITS]:
        if (base / "vehicle_pose" / f"{context_name}.parquet").is_file():
            return base
    raise IDSplatError(
        f"{root}: no vehicle_pose/{context_name}.parquet here or under {'/, '.join(SPLITS)}/; "
        "pass the v2 root and an existing context_name"
    )


def _file(base: Path, component: str, context_name: str, required: bool) -> Optional[Path]:
    path = base / component / f"{context_name}.parquet"
    if path.is_file():
        return path
    if required:
        raise IDSplatError(f"{path}: missing v2 component {component}; download it for this context")
    return None


def _read(path: Path, columns: list[str], keep=None, optional: tuple[str, ...] = ()) -> dict[str, list]:
    """Columns as Python lists, streaming row batches and keeping rows where ``keep(batch)`` [n] is true.

    A null in a column not named in ``optional`` is damage, named by file, column and row, so that
    no ``None`` reaches the conversions below.
    """
    import pyarrow as pa
    import pyarrow.parquet as pq

    try:
        pf = pq.ParquetFile(path)
        missing = [c for c in columns if c not in pf.schema_arrow.names]
        if missing:
            raise IDSplatError(f"{path}: no column {missing[0]!r}; is this a Waymo v2 file of that component?")
        out: dict[str, list] = {c: [] for c in columns}
        rows = 0
        for batch in pf.iter_batches(batch_size=_BATCH_ROWS if keep is not None else 65536, columns=columns):
            if keep is not None:
                batch = batch.filter(pa.array(keep(batch)))
            for c in columns:
                arr = batch.column(c)
                if arr.null_count and c not in optional:
                    row = rows + int(np.argmax(np.asarray(arr.is_null())))
                    raise IDSplatError(f"{path}: column {c!r} is empty (null) in row {row}; the file is damaged: re-download it")
                out[c].extend(_column_values(arr))
            rows += batch.num_rows
        return out
    except IDSplatError:
        raise
    # ArrowInvalid for non-parquet bytes; a damaged footer or schema can also fail to decode as text.
    except (pa.ArrowException, OSError, UnicodeDecodeError, EOFError) as err:
        raise IDSplatError(f"{path}: not a readable parquet file ({type(err).__name__}: {err}); re-download it") from None


def _range_image(values, shape, what: str) -> np.ndarray:
    """A flat range image (or pixel-pose image) reshaped to its stored [H, W, C] shape, checked first."""
    values = np.asarray(values, np.float32)
    shape = [] if shape is None else [int(v) for v in np.asarray(shape).reshape(-1)]
    if len(shape) != 3 or min(shape) <= 0 or int(np.prod(shape)) != values.size:
        raise IDSplatError(f"{what}: shape {shape} does not fit {values.size} values; the file is damaged: re-download it")
    return values.reshape(shape)


def _column_values(arr) -> list:
    """Rows of an arrow column; list columns become numpy arrays (to_pylist is ~50x slower on 10^6 floats)."""
    import pyarrow as pa

    t = arr.type
    if pa.types.is_fixed_size_list(t):
        values = arr.flatten().to_numpy(zero_copy_only=False)
        return list(values.reshape(len(arr), t.list_size)) if len(arr) else []
    if pa.types.is_list(t) or pa.types.is_large_list(t):
        if arr.null_count:
            return arr.to_pylist()
        offsets = arr.offsets.to_numpy()
        values = arr.flatten().to_numpy(zero_copy_only=False)
        offsets = offsets - offsets[0]
        return [values[offsets[i] : offsets[i + 1]] for i in range(len(arr))]
    return arr.to_pylist()


def _mat(values, what: str) -> np.ndarray:
    arr = np.asarray(values, dtype=np.float64)
    if arr.size != 16:
        raise IDSplatError(f"{what}: transform has {arr.size} values, expected 16")
    return arr.reshape(4, 4)


def _in(batch, column: str, allowed: set) -> np.ndarray:
    return np.isin(np.asarray(batch.column(column).to_numpy(zero_copy_only=False)), list(allowed))


def read_v2(
    root: Path,
    context_name: Optional[str],
    cameras: Optional[Sequence[str]],
    lidars: Optional[Sequence[str]],
    start: int,
    end: Optional[int],
    second_return: bool = True,
) -> tuple[SegmentCalibration, Iterator[FrameRecord], Path]:
    """Calibration, the kept frames (read eagerly for the selected range) and the folder read."""
    if not context_name:
        contexts = sorted(p.stem for base in [root] + [root / s for s in SPLITS] for p in (base / "vehicle_pose").glob("*.parquet"))
        if len(contexts) != 1:
            raise IDSplatError(f"{root}: a v2 root needs context_name= (found {len(contexts)} contexts)")
        context_name = contexts[0]
    base = find_component_dir(root, context_name)

    # Frames: sorted vehicle-pose timestamps, then the [start, end) slice.
    vp = _read(_file(base, "vehicle_pose", context_name, True), [TS, col("VehiclePoseComponent", "world_from_vehicle.transform")])
    order = np.argsort(vp[TS])
    all_ts = [int(vp[TS][i]) for i in order]
    # Frames are keyed by timestamp below: a repeated one would silently merge two frames.
    check_timestamps(all_ts, str(base / "vehicle_pose" / f"{context_name}.parquet"), "key.frame_timestamp_micros")
    if start >= len(all_ts):
        raise IDSplatError(f"{base}: context {context_name} has {len(all_ts)} frames, none at index {start}; lower the start frame")
    selected = all_ts[start:end]
    index_of = {ts: start + k for k, ts in enumerate(selected)}
    poses = {int(vp[TS][i]): _mat(vp[col("VehiclePoseComponent", "world_from_vehicle.transform")][i], f"{base}: vehicle pose") for i in order}

    # Calibrations.
    C = "CameraCalibrationComponent"
    intr = ["f_u", "f_v", "c_u", "c_v", "k1", "k2", "p1", "p2", "k3"]
    cc = _read(_file(base, "camera_calibration", context_name, True),
               [CAM] + [col(C, f"intrinsic.{k}") for k in intr] + [col(C, f) for f in ("extrinsic.transform", "width", "height", "rolling_shutter_direction")])
    cam_calibs = {}
    for i, number in enumerate(cc[CAM]):
        name = CAMERA_NAMES.get(int(number), f"CAMERA_{int(number)}")
        cam_calibs[name] = CameraCalib(
            name=name, intrinsic=np.array([cc[col(C, f"intrinsic.{k}")][i] for k in intr], dtype=np.float64),
            extrinsic=_mat(cc[col(C, "extrinsic.transform")][i], f"{base}: camera {name} extrinsic"),
            width=int(cc[col(C, "width")][i]), height=int(cc[col(C, "height")][i]),
            rolling_shutter_direction=int(cc[col(C, "rolling_shutter_direction")][i]),
        )
    L = "LiDARCalibrationComponent"
    lidar_calibs = {}
    lc_path = _file(base, "lidar_calibration", context_name, lidars is not None and len(lidars) > 0)
    if lc_path is not None:
        lc = _read(lc_path, [LASER] + [col(L, f) for f in ("extrinsic.transform", "beam_inclination.min", "beam_inclination.max", "beam_inclination.values")],
                   optional=(col(L, "beam_inclination.values"),))
        for i, number in enumerate(lc[LASER]):
            name = LASER_NAMES.get(int(number), f"LASER_{int(number)}")
            values = lc[col(L, "beam_inclination.values")][i]
            lidar_calibs[name] = LidarCalib(
                name=name, extrinsic=_mat(lc[col(L, "extrinsic.transform")][i], f"{base}: lidar {name} extrinsic"),
                beam_inclinations=np.asarray(values, dtype=np.float64) if values is not None and len(values) else None,
                inclination_min=float(lc[col(L, "beam_inclination.min")][i]),
                inclination_max=float(lc[col(L, "beam_inclination.max")][i]),
            )
    calib = SegmentCalibration(context_name=context_name, cameras=cam_calibs, lidars=lidar_calibs)
    component = {name: str(base / name / f"{context_name}.parquet") for name in ("vehicle_pose", "camera_calibration", "lidar_calibration", "camera_image", "lidar")}
    check_calibration(calib, component["camera_calibration"], component["lidar_calibration"])
    cam_names = resolve_names(cameras, list(cam_calibs), "camera", base / "camera_calibration" / f"{context_name}.parquet")
    lidar_names = resolve_names(lidars, list(lidar_calibs), "lidar", base / "lidar_calibration" / f"{context_name}.parquet")
    cam_numbers = {n for n, name in CAMERA_NAMES.items() if name in cam_names}
    laser_numbers = {n for n, name in LASER_NAMES.items() if name in lidar_names}
    want = set(selected)

    records = {ts: FrameRecord(index=index_of[ts], timestamp_micros=ts, pose=poses[ts]) for ts in selected}

    # Camera images.
    I = "CameraImageComponent"
    icols = [TS, CAM, col(I, "image"), col(I, "pose.transform"), col(I, "pose_timestamp"),
             col(I, "rolling_shutter_params.shutter"), col(I, "rolling_shutter_params.camera_trigger_time"),
             col(I, "rolling_shutter_params.camera_readout_done_time")]
    ci = {c: [] for c in icols}
    if cam_numbers:
        ci = _read(_file(base, "camera_image", context_name, True), icols, keep=lambda b: _in(b, TS, want) & _in(b, CAM, cam_numbers))
    by_frame_cam = {}
    for i, ts in enumerate(ci[TS]):
        name = CAMERA_NAMES[int(ci[CAM][i])]
        by_frame_cam[(int(ts), name)] = CameraFrame(
            name=name, image=ci[col(I, "image")][i], pose=_mat(ci[col(I, "pose.transform")][i], f"{base}: {name} image pose"),
            pose_timestamp=float(ci[col(I, "pose_timestamp")][i]), shutter=float(ci[col(I, "rolling_shutter_params.shutter")][i]),
            trigger_time=float(ci[col(I, "rolling_shutter_params.camera_trigger_time")][i]),
            readout_done_time=float(ci[col(I, "rolling_shutter_params.camera_readout_done_time")][i]),
        )
    del ci
    for ts in selected:
        for name in cam_names:
            if (ts, name) not in by_frame_cam:
                raise IDSplatError(f"{base / 'camera_image' / (context_name + '.parquet')}: frame {index_of[ts]} has no {name} image; choose cameras it has")
            records[ts].cameras.append(by_frame_cam.pop((ts, name)))

    # Lidar range images and TOP pixel poses.
    if laser_numbers:
        R = "LiDARComponent"
        lcols = [TS, LASER, col(R, "range_image_return1.values"), col(R, "range_image_return1.shape")]
        if second_return:
            lcols += [col(R, "range_image_return2.values"), col(R, "range_image_return2.shape")]
        li = _read(_file(base, "lidar", context_name, True), lcols, keep=lambda b: _in(b, TS, want) & _in(b, LASER, laser_numbers),
                   optional=(col(R, "range_image_return2.values"), col(R, "range_image_return2.shape")))
        P = "LiDARPoseComponent"
        lp_path = _file(base, "lidar_pose", context_name, False)
        pix = {}
        if lp_path is not None:
            lp = _read(lp_path, [TS, LASER, col(P, "range_image_return1.values"), col(P, "range_image_return1.shape")],
                       keep=lambda b: _in(b, TS, want) & _in(b, LASER, laser_numbers))
            for i, ts in enumerate(lp[TS]):
                pix[(int(ts), int(lp[LASER][i]))] = _range_image(lp[col(P, "range_image_return1.values")][i], lp[col(P, "range_image_return1.shape")][i],
                                                                 f"{lp_path}: row {i}: pixel pose")
        for i, ts in enumerate(li[TS]):
            number = int(li[LASER][i])
            where = f"{component['lidar']}: frame {index_of[int(ts)]}: lidar {LASER_NAMES.get(number, number)}"
            r1 = _range_image(li[col(R, "range_image_return1.values")][i], li[col(R, "range_image_return1.shape")][i], f"{where} return 1")
            r2 = None
            if second_return and li[col(R, "range_image_return2.values")][i] is not None and len(li[col(R, "range_image_return2.values")][i]):
                r2 = _range_image(li[col(R, "range_image_return2.values")][i], li[col(R, "range_image_return2.shape")][i], f"{where} return 2")
            records[int(ts)].lidars.append(LidarFrame(name=LASER_NAMES[number], return1=r1, return2=r2, pixel_pose=pix.pop((int(ts), number), None)))
        del li
        for rec in records.values():
            rec.lidars.sort(key=lambda lf: sensor_rank(lf.name, LASER_NAMES))

    # 3D box labels.
    B = "LiDARBoxComponent"
    lb_path = _file(base, "lidar_box", context_name, False)
    if lb_path is not None:
        bcols = [TS, "key.laser_object_id"] + [col(B, f"box.center.{a}") for a in "xyz"] + [col(B, f"box.size.{a}") for a in "xyz"] + \
                [col(B, "box.heading"), col(B, "type"), col(B, "num_lidar_points_in_box"), col(B, "num_top_lidar_points_in_box")] + \
                [col(B, f"speed.{a}") for a in "xyz"]
        lb = _read(lb_path, bcols, keep=lambda b: _in(b, TS, want),
                   optional=tuple(col(B, f"speed.{a}") for a in "xyz") + (col(B, "num_top_lidar_points_in_box"),))
        for i, ts in enumerate(lb[TS]):
            records[int(ts)].labels.append(BoxLabel(
                id=lb["key.laser_object_id"][i], type=int(lb[col(B, "type")][i]),
                center=np.array([lb[col(B, f"box.center.{a}")][i] for a in "xyz"], dtype=np.float64),
                size=np.array([lb[col(B, f"box.size.{a}")][i] for a in "xyz"], dtype=np.float64),
                heading=float(lb[col(B, "box.heading")][i]),
                speed=np.array([lb[col(B, f"speed.{a}")][i] or 0.0 for a in "xyz"], dtype=np.float64),
                num_lidar_points=int(lb[col(B, "num_lidar_points_in_box")][i]),
                num_top_lidar_points=int(lb[col(B, "num_top_lidar_points_in_box")][i] or 0),
            ))

    def frames() -> Iterator[FrameRecord]:
        previous = None
        for ts in selected:
            rec = records.pop(ts)
            check_frame(rec, previous, component["vehicle_pose"], component["camera_image"], component["lidar"],
                        str(lb_path) if lb_path else None)
            previous = rec.timestamp_micros
            yield rec

    return calib, frames(), base
