"""Benchmark the pure-torch camera rasterizer: forward and forward+backward time, peak memory,
megapixels per second, and the speed-up over the dense reference where that fits.

Scene: gsplat's garden points (../shared/data/gsplat/test_garden.npz), subsampled or jittered to
N Gaussians, isotropic scales from the 3-nearest-neighbour distance (3DGS initialisation),
random rotations, opacities U(0.05, 0.95), 16 features (3 RGB + 13), camera 0 of the file
with intrinsics scaled to the image size.

Street workload (``--scene street``): the synthetic ``small`` street sequence
(~/.cache/idsplat_ns/synthetic/synth_small_0, written by the demo), Gaussians initialised from
its lidar points as the model does (``--street-points`` of them, about) (``initial_points_from_scene`` + ``GaussianSet.from_points``,
13 features + RGB), rendered from its first camera image; ``--counts`` is ignored there.

    .venv/bin/python bench/bench_rasterizer.py --threads 2
    .venv/bin/python bench/bench_rasterizer.py --sizes 320x240 --counts 10000,100000 --repeats 5 --dense-sizes ""
    .venv/bin/python bench/bench_rasterizer.py --scene street --sizes 320x192 --repeats 5 --dense-sizes ""
"""

from __future__ import annotations

import argparse
import os
import resource
import time
from pathlib import Path

import numpy as np
import torch
from scipy.spatial import cKDTree

from idsplat_ns.render import project_gaussians, rasterize_camera, rasterize_dense

GARDEN = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "gsplat" / "test_garden.npz"
STREET = Path.home() / ".cache" / "idsplat_ns" / "synthetic" / "synth_small_0"


def make_scene(n: int, width: int, height: int, seed: int = 0, path: Path = GARDEN, anisotropic: bool = False):
    """N Gaussians from the garden points and its camera 0 at ``width`` x ``height`` (CPU tensors);
    ``anisotropic``: the 3-NN scale times U(0.5, 2) per axis (so that rotations get a gradient)."""
    d = np.load(path)
    rng = np.random.default_rng(seed)
    pts = d["means3d"]
    idx = rng.choice(len(pts), n, replace=n > len(pts))
    pts = pts[idx] + (rng.normal(scale=0.01, size=(n, 3)) if n > len(d["means3d"]) else 0)
    dist, _ = cKDTree(pts).query(pts, k=4)
    s = np.sqrt((dist[:, 1:] ** 2).mean(1)).clip(1e-4, None)
    g = torch.Generator().manual_seed(seed)
    K = torch.from_numpy(d["Ks"][:1]).float().clone()
    K[:, 0] *= width / float(d["width"])
    K[:, 1] *= height / float(d["height"])
    quats = torch.randn(n, 4, generator=g)
    scales = torch.from_numpy(s).float()[:, None].repeat(1, 3)
    if anisotropic:
        scales = scales * (0.5 + 1.5 * torch.rand(n, 3, generator=g))
    return dict(
        means=torch.from_numpy(pts).float(), quats=quats, scales=scales,
        opacities=torch.rand(n, generator=g) * 0.9 + 0.05, features=torch.rand(n, 16, generator=g),
        viewmats=torch.from_numpy(d["viewmats"][:1]).float(), Ks=K,
    )  # fmt: skip


def make_street_scene(width: int, height: int, num: int):
    """The demo's small synthetic street, Gaussians initialised from lidar as in training."""
    from idsplat_ns.data.images import load_rgb
    from idsplat_ns.data.pandaset import load_sequence
    from idsplat_ns.model.gaussians import GaussianSet
    from idsplat_ns.model.initialisation import InitConfig, initial_points_from_scene

    if not STREET.exists():
        raise SystemExit(f"{STREET} not found: run the demo once (it writes the synthetic street) or use --scene garden")
    seq = load_sequence(STREET)
    # num lidar points plus half as many random ones (the model's points_per_lidar_point).
    init_cfg = InitConfig(max_lidar_points=round(num / 1.5))
    init = initial_points_from_scene(seq, init_cfg, lambda im: load_rgb(im, 0.5))
    g = GaussianSet.from_points(init, 13, opacity=init_cfg.initial_opacity).activated()
    image = seq.images[0]
    viewmat = torch.from_numpy(np.linalg.inv(image.camera_to_world)).float()[None]
    intr = image.intrinsics
    K = torch.from_numpy(intr.K).float()[None].clone()
    K[:, 0] *= width / float(intr.width)
    K[:, 1] *= height / float(intr.height)
    return dict(
        means=g["means"].detach(), quats=g["quats"].detach(), scales=g["scales"].detach(),
        opacities=g["opacities"].detach(), features=torch.cat([g["colors"], g["features"]], 1).detach(),
        viewmats=viewmat, Ks=K,
    )  # fmt: skip


def _params(scene):
    return {k: (v.clone().requires_grad_() if k not in ("viewmats", "Ks") else v) for k, v in scene.items()}


def time_tile(scene, width, height, repeats, tile_size, backward):
    best = float("inf")
    for _ in range(repeats + 1):  # first call is a warm-up
        p = _params(scene)
        t0 = time.perf_counter()
        out = rasterize_camera(**p, width=width, height=height, tile_size=tile_size, backend="torch")
        if backward:
            (out.features.square().sum() + out.depth.sum() + out.alpha.sum()).backward()
        best = min(best, time.perf_counter() - t0)
    return best


def time_dense(scene, width, height, backward, strip=8):
    """Dense reference, rendered in horizontal strips (K shifted) so that it fits in memory."""
    p = _params(scene)
    t0 = time.perf_counter()
    for y0 in range(0, height, strip):
        h = min(strip, height - y0)
        K = p["Ks"].clone()
        K[:, 1, 2] -= y0
        with torch.set_grad_enabled(backward):
            proj = project_gaussians(p["means"], p["quats"], p["scales"], p["viewmats"], K, width, h)
            f, a, *_ = rasterize_dense(proj.means2d, proj.conics, proj.depths, proj.radii,
                                       p["opacities"], p["features"], width, h)  # fmt: skip
            if backward:
                (f.square().sum() + a.sum()).backward()
    return time.perf_counter() - t0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--sizes", default="160x120,320x240,640x480")
    ap.add_argument("--counts", default="10000,100000,300000")
    ap.add_argument("--dense-sizes", default="160x120:10000", help="WxH:N pairs for the dense ratio")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--repeats", type=int, default=2)
    ap.add_argument("--tile-size", type=int, default=8)
    ap.add_argument("--scene", choices=("garden", "street"), default="garden")
    ap.add_argument("--street-points", type=int, default=80000, help="Gaussians of the street scene (about)")
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    dense = {tuple(x.split(":")) for x in args.dense_sizes.split(",") if x}
    print(f"scene={args.scene} threads={args.threads} tile={args.tile_size} torch={torch.__version__} "
          f"load average before={os.getloadavg()[0]:.2f}")  # fmt: skip
    print("| size | Gaussians | fwd s | fwd+bwd s | MPix/s (fwd+bwd) | peak RSS GiB | dense fwd s | dense fwd+bwd s | speed-up fwd / fwd+bwd |")
    print("|---|---|---|---|---|---|---|---|---|")
    for size in args.sizes.split(","):
        w, h = map(int, size.split("x"))
        counts = args.counts.split(",") if args.scene == "garden" else [None]
        for n in counts:
            scene = make_scene(int(n), w, h) if args.scene == "garden" else make_street_scene(w, h, int(args.street_points))
            n = scene["means"].shape[0]
            fwd = time_tile(scene, w, h, args.repeats, args.tile_size, backward=False)
            both = time_tile(scene, w, h, args.repeats, args.tile_size, backward=True)
            rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20
            row = f"| {w}x{h} | {n} | {fwd:.3f} | {both:.3f} | {w * h / both / 1e6:.2f} | {rss:.2f} |"
            if (size, str(n)) in dense:
                dfwd = time_dense(scene, w, h, backward=False)
                dboth = time_dense(scene, w, h, backward=True)
                row += f" {dfwd:.2f} | {dboth:.2f} | {dfwd / fwd:.0f}x / {dboth / both:.0f}x |"
            else:
                row += " - | - | - |"
            print(row + f" load {os.getloadavg()[0]:.2f}", flush=True)


if __name__ == "__main__":
    main()
