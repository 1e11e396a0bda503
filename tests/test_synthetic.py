"""Tests of the built-in synthetic street (idsplat_ns.data.synthetic), on the `tiny` preset."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from PIL import Image
from scipy.spatial.transform import Rotation

from idsplat_ns.data.synthetic import CAMERA_NAMES, PRESETS, generate_sequence, get_preset
from idsplat_ns.data.synthetic.raycast import RayCaster, intersect_box, intersect_cylinder, intersect_ellipsoid
from idsplat_ns.data.synthetic.shapes import BOX, CYLINDER, PLANE
from idsplat_ns.data.synthetic.world import build_world
from idsplat_ns.errors import IDSplatError

TINY = get_preset("tiny")


@pytest.fixture(scope="module")
def seq(tmp_path_factory) -> Path:
    return generate_sequence(tmp_path_factory.mktemp("synth"), "tiny", seed=3, progress=False)


@pytest.fixture(scope="module")
def world():
    return build_world(TINY, 3)


def _pose_matrix(p: dict) -> np.ndarray:
    h, t = p["heading"], p["position"]
    m = np.eye(4)
    m[:3, :3] = Rotation.from_quat([h["x"], h["y"], h["z"], h["w"]]).as_matrix()
    m[:3, 3] = [t["x"], t["y"], t["z"]]
    return m


def _to_local(world, pts: np.ndarray) -> np.ndarray:
    return (pts - world.local_to_world_offset) @ world.local_to_world_rotation


def _json(path: Path):
    return json.loads(path.read_text())


# -- layout ------------------------------------------------------------------------------------------


def test_files_follow_pandaset_layout(seq: Path):
    n = TINY.num_frames
    for cam in CAMERA_NAMES:
        folder = seq / "camera" / cam
        assert sorted(p.name for p in folder.glob("*.jpg")) == [f"{k:02d}.jpg" for k in range(n)]
        assert set(_json(folder / "intrinsics.json")) == {"fx", "fy", "cx", "cy"}
        assert len(_json(folder / "poses.json")) == n
        assert len(_json(folder / "timestamps.json")) == n
        img = Image.open(folder / "00.jpg")
        assert img.mode == "RGB" and img.size == (TINY.cameras.image_width, TINY.cameras.image_height)
        mask = np.array(Image.open(seq / "idsplat_extras" / "instance_masks" / cam / "00.png"))
        assert mask.dtype == np.uint16 and mask.shape == (img.size[1], img.size[0])
    assert len(list((seq / "lidar").glob("*.pkl.gz"))) == n
    assert len(_json(seq / "lidar" / "poses.json")) == n
    assert len(_json(seq / "meta" / "timestamps.json")) == n
    assert set(_json(seq / "meta" / "gps.json")[0]) == {"lat", "long", "height", "xvel", "yvel"}
    assert len(list((seq / "idsplat_extras" / "lidar_noreturn").glob("*.npz"))) == n
    df = pd.read_pickle(seq / "lidar" / "03.pkl.gz")
    assert list(df.columns) == ["x", "y", "z", "i", "t", "d"]
    assert [str(t) for t in df.dtypes] == ["float64"] * 5 + ["int64"]
    assert (df["d"] == 0).all() and len(df) > 5000
    cub = pd.read_pickle(seq / "annotations" / "cuboids" / "03.pkl.gz")
    assert list(cub.columns) == [
        "uuid", "label", "yaw", "stationary", "camera_used", "position.x", "position.y", "position.z",
        "dimensions.x", "dimensions.y", "dimensions.z", "attributes.object_motion", "cuboids.sibling_id",
        "cuboids.sensor_id", "attributes.rider_status", "attributes.pedestrian_behavior", "attributes.pedestrian_age",
    ]  # fmt: skip
    assert (cub["cuboids.sensor_id"] == -1).all() and (cub["cuboids.sibling_id"] == "-").all()
    nr = np.load(seq / "idsplat_extras" / "lidar_noreturn" / "03.npz")
    assert nr["origins"].shape == nr["directions"].shape and nr["origins"].dtype == np.float64
    np.testing.assert_allclose(np.linalg.norm(nr["directions"], axis=1), 1.0, atol=1e-9)
    # World coordinates keep the large UTM-like offset (the parser must recentre).
    assert abs(df["x"].mean() - TINY.world_offset[0]) < 200 and abs(df["y"].mean() - TINY.world_offset[1]) < 200


def test_same_seed_same_bytes_other_seed_differs(tmp_path: Path):
    cfg = dataclasses.replace(TINY, name="tiny3", num_frames=2)
    a = generate_sequence(tmp_path / "a", cfg, seed=5, progress=False)
    b = generate_sequence(tmp_path / "b", cfg, seed=5, progress=False)
    c = generate_sequence(tmp_path / "c", cfg, seed=6, progress=False)
    files_a = sorted(p.relative_to(a) for p in a.rglob("*") if p.is_file())
    assert files_a == sorted(p.relative_to(b) for p in b.rglob("*") if p.is_file())
    assert len(files_a) > 30
    for rel in files_a:
        assert (a / rel).read_bytes() == (b / rel).read_bytes(), rel
    assert (a / "lidar" / "00.pkl.gz").read_bytes() != (c / "lidar" / "00.pkl.gz").read_bytes()
    assert (a / "camera" / "front_camera" / "00.jpg").read_bytes() != (c / "camera" / "front_camera" / "00.jpg").read_bytes()


def test_existing_sequence_is_reused_or_refused(seq: Path, tmp_path: Path):
    stamp = (seq / "lidar" / "00.pkl.gz").stat().st_mtime_ns
    assert generate_sequence(seq.parent, "tiny", seed=3, progress=False) == seq  # cache hit
    assert (seq / "lidar" / "00.pkl.gz").stat().st_mtime_ns == stamp
    other = dataclasses.replace(TINY, ego_speed=7.0)
    with pytest.raises(IDSplatError, match="exists"):
        generate_sequence(seq.parent, other, seed=3, progress=False)
    with pytest.raises(IDSplatError, match="unknown synthetic preset"):
        generate_sequence(tmp_path, "huge", seed=0)
    assert not any(p.name.startswith(".") for p in seq.parent.iterdir())  # no temporary folder left


# -- ground truth ------------------------------------------------------------------------------------


def _tracks(seq: Path) -> pd.DataFrame:
    frames = []
    for k in range(TINY.num_frames):
        df = pd.read_pickle(seq / "annotations" / "cuboids" / f"{k:02d}.pkl.gz")
        frames.append(df.assign(frame=k))
    return pd.concat(frames, ignore_index=True)


def test_parked_and_moving_vehicles_with_a_turn(seq: Path):
    tracks = _tracks(seq)
    parked = tracks[tracks["stationary"]]
    moving = tracks[~tracks["stationary"]]
    assert parked["uuid"].nunique() >= 3 and (parked["attributes.object_motion"] == "Parked").all()
    assert moving["uuid"].nunique() >= 4 and (moving["attributes.object_motion"] == "Moving").all()
    # Parked boxes do not move; moving ones do.
    for _, g in parked.groupby("uuid"):
        assert np.ptp(g["position.x"]) < 1e-9 and np.ptp(g["position.y"]) < 1e-9
    turns, speeds, headings = [], {}, {}
    for uid, g in moving.groupby("uuid"):
        g = g.sort_values("frame")
        assert np.ptp(np.hypot(g["position.x"], g["position.y"])) > 0.5
        turns.append(np.degrees(np.ptp(np.unwrap(g["yaw"].to_numpy()))))
        dxy = np.diff(g[["position.x", "position.y"]].to_numpy(), axis=0)
        speeds[uid] = np.linalg.norm(dxy, axis=1).mean() * TINY.frame_rate
        # Heading along velocity: the box's length axis (-sin yaw, cos yaw) points where it drives.
        yaw = g["yaw"].to_numpy()[:-1]
        heading = np.stack([-np.sin(yaw), np.cos(yaw)], 1)
        cos = (heading * dxy).sum(1) / np.linalg.norm(dxy, axis=1)
        assert (cos > 0.95).all(), uid
        headings[uid] = np.arctan2(dxy[:, 1].mean(), dxy[:, 0].mean())
    assert max(turns) > 30.0  # the turning car, within the tiny sequence
    ego = np.array([[p["position"]["x"], p["position"]["y"]] for p in _json(seq / "lidar" / "poses.json")])
    ego_dir = np.arctan2(*(ego[-1] - ego[0])[::-1])
    rel = {u: np.cos(h - ego_dir) for u, h in headings.items()}
    assert any(c < -0.99 for c in rel.values())  # oncoming
    assert any(rel[u] > 0.99 and speeds[u] > TINY.ego_speed + 2.0 for u in rel)  # overtaking


def test_moving_cuboid_centres_project_into_their_masks(seq: Path):
    instances = _json(seq / "idsplat_extras" / "instances.json")
    id_of = {v["uuid"]: int(k) for k, v in instances.items()}
    assert sum(v["moving"] for v in instances.values()) >= 4
    matches = 0
    for cam in CAMERA_NAMES:
        folder = seq / "camera" / cam
        intr = _json(folder / "intrinsics.json")
        K = np.array([[intr["fx"], 0, intr["cx"]], [0, intr["fy"], intr["cy"]], [0, 0, 1.0]])
        poses = _json(folder / "poses.json")
        for k in range(TINY.num_frames):
            cub = pd.read_pickle(seq / "annotations" / "cuboids" / f"{k:02d}.pkl.gz")
            mask = np.array(Image.open(seq / "idsplat_extras" / "instance_masks" / cam / f"{k:02d}.png"))
            world_to_cam = np.linalg.inv(_pose_matrix(poses[k]))
            centres = cub[["position.x", "position.y", "position.z"]].to_numpy()
            pc = centres @ world_to_cam[:3, :3].T + world_to_cam[:3, 3]
            depth = dict(zip(cub["uuid"], pc[:, 2]))
            for row, p in zip(cub.itertuples(), pc):
                if row.stationary or p[2] <= 1.0:
                    continue
                u, v = (K @ p)[:2] / p[2]
                if not (0 <= u < mask.shape[1] and 0 <= v < mask.shape[0]):
                    continue
                got = int(mask[int(v), int(u)])
                if got == id_of[row.uuid]:
                    matches += 1
                else:  # only a nearer vehicle may hide it
                    occluder = [u_ for u_, i in id_of.items() if i == got]
                    assert occluder and depth.get(occluder[0], np.inf) < p[2] + 1.0, (cam, k, row.uuid, got)
    assert matches >= 10


def test_instance_masks_hold_known_ids(seq: Path):
    ids = {int(k) for k in _json(seq / "idsplat_extras" / "instances.json")}
    seen = set()
    for cam in CAMERA_NAMES:
        for png in (seq / "idsplat_extras" / "instance_masks" / cam).glob("*.png"):
            seen |= set(np.unique(np.array(Image.open(png))).tolist())
    assert 0 in seen and seen - {0} <= ids and len(seen - {0}) >= 5


# -- lidar ---------------------------------------------------------------------------------------------


def _sweep(seq: Path, k: int):
    df = pd.read_pickle(seq / "lidar" / f"{k:02d}.pkl.gz")
    poses = _json(seq / "lidar" / "poses.json")
    stamps = np.array(_json(seq / "lidar" / "timestamps.json"))
    return df, poses, stamps


def _sensor_origin(poses, stamps, t: np.ndarray) -> np.ndarray:
    """Lidar position at times `t` by linear interpolation of the per-sweep poses (exact at constant velocity)."""
    pos = np.array([[p["position"][a] for a in "xyz"] for p in poses])
    s = (t - stamps[0]) / (stamps[1] - stamps[0])
    return pos[0] + s[:, None] * (pos[1] - pos[0])


def test_lidar_times_follow_azimuth(seq: Path):
    df, poses, stamps = _sweep(seq, 4)
    period = 1.0 / TINY.frame_rate
    t = df["t"].to_numpy()
    assert (t >= stamps[4] - period / 2 - 1e-6).all() and (t < stamps[4] + period / 2).all()
    assert np.ptp(t) > 0.9 * period
    pts = df[["x", "y", "z"]].to_numpy()
    rot = _pose_matrix(poses[4])[:3, :3]
    local = (pts - _sensor_origin(poses, stamps, t)) @ rot  # sensor frame: x right, y forward
    az = np.mod(np.arctan2(local[:, 1], local[:, 0]) + np.pi / 2, 2 * np.pi)  # 0 behind, increasing CCW
    az[az > 2 * np.pi - 1e-6] -= 2 * np.pi  # the first column sits exactly on the seam
    order = np.argsort(t, kind="stable")
    assert np.diff(az[order]).min() > -1e-3  # azimuth never goes back as time goes on
    assert np.corrcoef(az, t)[0, 1] > 0.999


def test_lidar_points_lie_on_surfaces(seq: Path, world):
    """Recast each returned ray (its sensor position at its time, its direction) without noise."""
    caster = RayCaster(world)
    df, poses, stamps = _sweep(seq, 6)
    sample = df.sample(400, random_state=0)
    pts = sample[["x", "y", "z"]].to_numpy()
    t_abs = sample["t"].to_numpy()
    origin = _sensor_origin(poses, stamps, t_abs)
    rng_measured = np.linalg.norm(pts - origin, axis=1)
    d = (pts - origin) / rng_measured[:, None]
    hits = caster.cast(_to_local(world, origin), d @ world.local_to_world_rotation, t_abs - TINY.start_time)
    assert hits.hit.all()
    err = rng_measured - hits.distance
    sigma = TINY.lidar.range_noise_std
    assert np.abs(err).max() < 6 * sigma
    assert 0.5 * sigma < err.std() < 1.5 * sigma  # the Gaussian range noise is there
    assert (rng_measured < TINY.lidar.max_range + 6 * sigma).all()


def test_no_lidar_return_from_sky_and_intensity_range(seq: Path, world):
    df, _, _ = _sweep(seq, 2)
    local = _to_local(world, df[["x", "y", "z"]].to_numpy())
    top = max(o.bounding_sphere()[0][2] + o.bounding_sphere()[1] for o in world.objects[1:])
    assert local[:, 2].max() <= top
    i = df["i"].to_numpy()
    assert i.min() >= 0 and i.max() <= 255 and i.max() > 150 and np.median(i) < 60
    nr = np.load(seq / "idsplat_extras" / "lidar_noreturn" / "02.npz")
    d = nr["directions"]
    assert (d[:, 2] > 0.1).sum() > 100  # upward rays into the sky are recorded as no-return
    # Every returned + non-returned ray: 64 beams x azimuth steps.
    assert len(df) + len(d) == 64 * TINY.lidar.azimuth_steps
    # Most non-returns really hit nothing within range; the rest are the random drop-outs.
    caster = RayCaster(world)
    hits = caster.cast(_to_local(world, nr["origins"]), d @ world.local_to_world_rotation, nr["t"] - TINY.start_time)
    in_range = hits.hit & (hits.distance <= TINY.lidar.max_range)
    assert in_range.sum() < 0.15 * (len(df) + len(d))  # drop-outs: ~3 % overall, more on glass
    assert in_range.sum() > 0  # drop-outs exist


# -- ray casting primitives against independent references ---------------------------------------------


def _march(inside, o: np.ndarray, d: np.ndarray, t_max: float = 50.0, step: float = 1e-3) -> np.ndarray:
    """First distance where `inside(points)` holds along each ray, by brute-force marching."""
    ts = np.arange(0.0, t_max, step)
    out = np.full(len(o), np.inf)
    for i in range(len(o)):
        pts = o[i] + ts[:, None] * d[i]
        hit = np.flatnonzero(inside(pts))
        if len(hit):
            out[i] = ts[hit[0]]
    return out


def _random_rays(n: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    o = rng.uniform(-6, 6, (n, 3))
    o[:, 0] = np.where(np.abs(o[:, 0]) < 3, 3 * np.sign(o[:, 0] + 1e-9), o[:, 0])  # start outside the shapes
    target = rng.uniform(-1.2, 1.2, (n, 3))
    d = target - o
    return o, d / np.linalg.norm(d, axis=1, keepdims=True)


def test_intersections_match_brute_force_marching():
    rng = np.random.default_rng(0)
    o, d = _random_rays(60, rng)
    half = np.array([1.0, 0.6, 0.8])
    t, n = intersect_box(o, d, half)
    ref = _march(lambda p: (np.abs(p) <= half).all(1), o, d)
    assert np.isfinite(t).sum() > 20 and (np.isfinite(t) == np.isfinite(ref)).mean() > 0.95
    both = np.isfinite(t) & np.isfinite(ref)
    np.testing.assert_allclose(t[both], ref[both], atol=2e-3)
    p = o + t[:, None] * d
    assert (np.abs(np.abs(p[both]) - half)[np.arange(both.sum()), np.abs(n[both]).argmax(1)] < 1e-9).all()
    t, _ = intersect_cylinder(o, d, 0.7, 0.9)
    ref = _march(lambda p: (np.hypot(p[:, 0], p[:, 1]) <= 0.7) & (np.abs(p[:, 2]) <= 0.9), o, d)
    both = np.isfinite(t) & np.isfinite(ref)
    assert both.sum() > 20 and (np.isfinite(t) == np.isfinite(ref)).mean() > 0.95
    np.testing.assert_allclose(t[both], ref[both], atol=2e-3)
    radii = np.array([1.1, 0.7, 0.9])
    t, _ = intersect_ellipsoid(o, d, radii)
    ref = _march(lambda p: ((p / radii) ** 2).sum(1) <= 1.0, o, d)
    both = np.isfinite(t) & np.isfinite(ref)
    assert both.sum() > 20 and (np.isfinite(t) == np.isfinite(ref)).mean() > 0.95
    np.testing.assert_allclose(t[both], ref[both], atol=2e-3)


def test_cast_hits_lie_on_their_parts(world):
    """Rays from the ego's roof in all directions: each hit is on the surface of the part it names."""
    caster = RayCaster(world)
    rng = np.random.default_rng(1)
    d = rng.normal(size=(20000, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    o = np.tile([10.0, -5.25, 1.9], (len(d), 1))
    t = np.full(len(d), 0.3)
    hits = caster.cast(o, d, t)
    assert hits.hit[d[:, 2] < -0.01].all()  # the ground catches every downward ray
    for kind, check in (
        (PLANE, lambda q, s: np.abs(q[:, 2])),
        (BOX, lambda q, s: np.abs(np.abs(q) - s).min(1)),
        (CYLINDER, lambda q, s: np.minimum(np.abs(np.hypot(q[:, 0], q[:, 1]) - s[:, 0]), np.abs(np.abs(q[:, 2]) - s[:, 2]))),
    ):
        rows = np.flatnonzero(hits.hit & (np.array([p.kind for p in caster.parts])[np.maximum(hits.part, 0)] == kind))
        assert len(rows) > 10, kind
        q = hits.point_part[rows]
        assert check(q, caster.part_size[hits.part[rows]]).max() < 1e-6, kind
    # The ground distance is the closed form -o_z / d_z wherever nothing stands in between.
    ground = np.flatnonzero(hits.part == 0)
    np.testing.assert_allclose(hits.distance[ground], -o[ground, 2] / d[ground, 2], rtol=1e-12)


def test_presets_scale_up():
    assert set(PRESETS) >= {"tiny", "small", "bench"}
    sizes = [PRESETS[p].cameras.image_width * PRESETS[p].cameras.image_height for p in ("tiny", "small", "bench")]
    assert sizes == sorted(sizes) and PRESETS["small"].num_frames >= 30
    for p in PRESETS.values():
        assert 6.0 <= p.ego_speed <= 10.0


def test_five_camera_rig_adds_the_side_cameras(tmp_path: Path):
    from idsplat_ns.data.pandaset import load_sequence
    from idsplat_ns.data.synthetic import SIDE_CAMERA_NAMES
    from idsplat_ns.data.synthetic.config import config_to_dict

    assert "side_cameras" not in config_to_dict(TINY)["cameras"]  # three-camera streets keep their generator.json
    segment = get_preset("segment")
    assert (segment.num_frames, segment.lidar.azimuth_steps, segment.cameras.side_cameras) == (200, 2650, True)
    five = dataclasses.replace(TINY, name="tiny5", num_frames=2,
                               cameras=dataclasses.replace(TINY.cameras, side_cameras=True))
    seq = generate_sequence(tmp_path, five, seed=3, progress=False, workers=1)
    scene = load_sequence(seq)
    assert scene.camera_names == list(CAMERA_NAMES + SIDE_CAMERA_NAMES)
    # Each camera's optical axis, against the front camera's, at its mounting yaw (left positive).
    axes = {cam: _pose_matrix(_json(seq / "camera" / cam / "poses.json")[0])[:3, 2] for cam in scene.camera_names}
    front = axes["front_camera"]
    for cam, yaw in zip(scene.camera_names, (0.0, 55.0, -55.0, 110.0, -110.0)):
        turn = np.degrees(np.arctan2(np.cross(front[:2], axes[cam][:2]), np.dot(front[:2], axes[cam][:2])))
        assert turn == pytest.approx(yaw, abs=0.5), cam
