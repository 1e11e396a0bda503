"""Benchmark the pure-torch camera rasterizer: forward and forward+backward time, peak memory,
megapixels per second, and the speed-up over the dense reference where that fits.

Scene: gsplat's garden points (../shared/data/gsplat/test_garden.npz), subsampled or jittered to
N Gaussians, isotropic scales from the 3-nearest-neighbour distance (3DGS initialisation),
random rotations, opacities U(0.05, 0.95), 16 features (3 RGB + 13), camera 0 of the file
with intrinsics scaled to the image size.

    .venv/bin/python bench/bench_rasterizer.py --threads 2
    .venv/bin/python bench/bench_rasterizer.py --sizes 320x240 --counts 100000 --dense-sizes ""
"""

from __future__ import annotations

import argparse
import resource
import time
from pathlib import Path

import numpy as np
import torch
from scipy.spatial import cKDTree

from idsplat_ns.render import project_gaussians, rasterize_camera, rasterize_dense

GARDEN = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "gsplat" / "test_garden.npz"


def make_scene(n: int, width: int, height: int, seed: int = 0):
    d = np.load(GARDEN)
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
    return dict(
        means=torch.from_numpy(pts).float(), quats=torch.randn(n, 4, generator=g),
        scales=torch.from_numpy(s).float()[:, None].repeat(1, 3),
        opacities=torch.rand(n, generator=g) * 0.9 + 0.05, features=torch.rand(n, 16, generator=g),
        viewmats=torch.from_numpy(d["viewmats"][:1]).float(), Ks=K,
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
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    dense = {tuple(x.split(":")) for x in args.dense_sizes.split(",") if x}
    print(f"threads={args.threads} tile={args.tile_size} torch={torch.__version__}")
    print("| size | Gaussians | fwd s | fwd+bwd s | MPix/s (fwd+bwd) | peak RSS GiB | dense fwd s | dense fwd+bwd s | speed-up fwd / fwd+bwd |")
    print("|---|---|---|---|---|---|---|---|---|")
    for size in args.sizes.split(","):
        w, h = map(int, size.split("x"))
        for n in map(int, args.counts.split(",")):
            scene = make_scene(n, w, h)
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
            print(row, flush=True)


if __name__ == "__main__":
    main()
