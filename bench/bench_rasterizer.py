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

Times are medians over ``--repeats`` calls after one untimed call (which also loads or compiles
the compiled compositor). ``--compositor torch`` times the tensor-op compositor instead of the
default (compiled on the CPU).

Side by side with another revision (``--against REV``, or ``--against-tree DIR``, see
``bench/revisions.py``): each revision runs in child processes of its own, alternating
``--rounds`` times, and the table gives both revisions' medians and their ratio.

    .venv/bin/python -m bench.bench_rasterizer --threads 2
    .venv/bin/python -m bench.bench_rasterizer --sizes 320x240 --counts 10000,100000 --repeats 5 --dense-sizes ""
    .venv/bin/python -m bench.bench_rasterizer --scene street --sizes 320x192 --repeats 5 --dense-sizes ""
    .venv/bin/python -m bench.bench_rasterizer --sizes 320x240 --counts 100000 --dense-sizes "" --against HEAD~1
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
import time
from pathlib import Path

import numpy as np
import torch
from scipy.spatial import cKDTree

from bench import revisions
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


def time_tile(scene, width, height, repeats, tile_size, backward, compositor="auto") -> list[float]:
    """Seconds of ``repeats`` calls after an untimed one (forward, or forward and backward)."""
    # Only named when asked, so that revisions from before the option run the same command.
    options = {} if compositor == "auto" else {"compositor": compositor}
    times = []
    for _ in range(repeats + 1):
        p = _params(scene)
        t0 = time.perf_counter()
        out = rasterize_camera(**p, width=width, height=height, tile_size=tile_size, backend="torch", **options)
        if backward:
            (out.features.square().sum() + out.depth.sum() + out.alpha.sum()).backward()
        times.append(time.perf_counter() - t0)
    return times[1:]


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


def _cases(args):
    for size in args.sizes.split(","):
        w, h = map(int, size.split("x"))
        for n in args.counts.split(",") if args.scene == "garden" else [None]:
            yield size, w, h, n


def measure(args) -> list[dict]:
    """One row per (size, count): forward and forward+backward times, peak RSS, dense ratios."""
    dense = {tuple(x.split(":")) for x in args.dense_sizes.split(",") if x}
    rows = []
    for size, w, h, n in _cases(args):
        scene = make_scene(int(n), w, h) if args.scene == "garden" else make_street_scene(w, h, int(args.street_points))
        n = scene["means"].shape[0]
        fwd = time_tile(scene, w, h, args.repeats, args.tile_size, False, args.compositor)
        both = time_tile(scene, w, h, args.repeats, args.tile_size, True, args.compositor)
        row = dict(size=f"{w}x{h}", w=w, h=h, n=n, fwd=fwd, both=both,
                   rss=resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20, load=os.getloadavg()[0])  # fmt: skip
        if (size, str(n)) in dense:
            row["dense"] = (time_dense(scene, w, h, backward=False), time_dense(scene, w, h, backward=True))
        rows.append(row)
        if not args.child:
            print(_row_text(row), flush=True)
    return rows


def _row_text(row: dict) -> str:
    fwd, both = statistics.median(row["fwd"]), statistics.median(row["both"])
    text = (f"| {row['size']} | {row['n']} | {fwd:.3f} | {both:.3f} | {row['w'] * row['h'] / both / 1e6:.2f} "
            f"| {row['rss']:.2f} |")  # fmt: skip
    if "dense" in row:
        dfwd, dboth = row["dense"]
        text += f" {dfwd:.2f} | {dboth:.2f} | {dfwd / fwd:.0f}x / {dboth / both:.0f}x |"
    else:
        text += " - | - | - |"
    return text + f" load {row['load']:.2f}"


def side_by_side(args) -> None:
    """Each revision in child processes, alternating ``--rounds`` times; one table of medians."""
    trees = revisions.trees("bench_rasterizer.py", args.against, args.against_tree)
    cmd = ["-m", "bench.bench_rasterizer", "--child", "--sizes", args.sizes, "--counts", args.counts, "--dense-sizes", "",
           "--threads", str(args.threads), "--repeats", str(args.repeats), "--tile-size", str(args.tile_size),
           "--scene", args.scene, "--street-points", str(args.street_points), "--compositor", args.compositor]  # fmt: skip
    times: dict = {}
    for r in range(args.rounds):
        for name, tree in trees.items():
            for row in revisions.run_child("bench_rasterizer.py", cmd, tree, args.threads):
                key = (row["size"], row["n"])
                slot = times.setdefault(key, {}).setdefault(name, {"fwd": [], "both": []})
                slot["fwd"] += row["fwd"]
                slot["both"] += row["both"]
                print(f"round {r + 1}: {name}: {row['size']}, {row['n']} Gaussians: forward+backward "
                      f"{statistics.median(row['both']):.3f} s", flush=True)  # fmt: skip
    names = list(trees)
    print(f"\nscene={args.scene} threads={args.threads} compositor={args.compositor}, medians of {args.rounds} x "
          f"{args.repeats} calls per revision\n")  # fmt: skip
    head = " | ".join(f"{n} fwd s | {n} fwd+bwd s" for n in names)
    print(f"| size | Gaussians | {head} | fwd+bwd time against the working tree |")
    print("|---|---|" + "---|---|" * len(names) + "---|")
    for (size, n), per in times.items():
        cells = " | ".join(f"{statistics.median(per[x]['fwd']):.3f} | {statistics.median(per[x]['both']):.3f}" for x in names)
        base = statistics.median(per["working tree"]["both"])
        ratios = ", ".join(f"{x} {statistics.median(per[x]['both']) / base:.2f}x" for x in names[1:])
        print(f"| {size} | {n} | {cells} | {ratios or '-'} |")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--sizes", default="160x120,320x240,640x480")
    ap.add_argument("--counts", default="10000,100000,300000")
    ap.add_argument("--dense-sizes", default="160x120:10000", help="WxH:N pairs for the dense ratio")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--repeats", type=int, default=3, help="timed calls after an untimed one (median)")
    ap.add_argument("--tile-size", type=int, default=8)
    ap.add_argument("--scene", choices=("garden", "street"), default="garden")
    ap.add_argument("--street-points", type=int, default=80000, help="Gaussians of the street scene (about)")
    # Written out, not imported from idsplat_ns.render.compositor: children run older engines too.
    ap.add_argument("--compositor", choices=("auto", "compiled", "torch"), default="auto",
                    help="tile compositor (auto: compiled on the CPU)")
    ap.add_argument("--against", default=None, help="git revision to time beside the working tree")
    ap.add_argument("--against-tree", type=Path, default=None, help="a source tree with idsplat_ns/ to time beside it")
    ap.add_argument("--rounds", type=int, default=3, help="alternations of the revisions (with --against)")
    ap.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    if args.against or args.against_tree:
        side_by_side(args)
        return
    if args.child:
        print("RESULT " + json.dumps(measure(args)))
        return
    print(f"scene={args.scene} threads={args.threads} tile={args.tile_size} compositor={args.compositor} "
          f"torch={torch.__version__} load average before={os.getloadavg()[0]:.2f}")  # fmt: skip
    print("| size | Gaussians | fwd s | fwd+bwd s | MPix/s (fwd+bwd) | peak RSS GiB | dense fwd s | dense fwd+bwd s | speed-up fwd / fwd+bwd |")
    print("|---|---|---|---|---|---|---|---|---|")
    measure(args)


if __name__ == "__main__":
    main()
