"""The GPU checks, in one run: the pure-torch rasterizers on CUDA against the same code on the CPU,
gsplat's parity test, and the rendering and training-step speed at the paper's image size.

Runs on a machine with torch and a CUDA GPU; nerfstudio is not needed (the engine imports none).
gsplat 1.4.0 is a JIT build: ``--gsplat-build`` compiles it in a background process while the
torch-backend checks run. Each stage is timed with CUDA events around whole calls (medians of
``--repeats`` after one warm-up) and a failing stage is written down, not fatal.

Scene: gsplat's garden points (``--garden``, default ../shared/data/gsplat/test_garden.npz),
replicated with 1 cm jitter to N Gaussians, 3-NN scales times U(0.5, 2) per axis, camera 0 of the file scaled
to 1920x1280. The lidar is placed at that camera: a 64 x 2650 grid (a Waymo top-lidar range
image, 169,600 rays) over elevations -17.6..2.4 degrees.

The training step is the engine's: :class:`SceneModel` (paper sizes: 13-d features, 8-d sensor
embedding, CNN decoder 32/3/2, lidar head) renders one 1920x1280 camera and a 16,384-ray lidar
batch, an L1 loss on each, backward, one Adam step. MCMC relocation, SSIM and the data loader
are not in it: a lower bound of the paper configuration's step.

    python -m bench.gpu_check --out OUT --gsplat-build          # on the GPU machine
    .venv/bin/python -m bench.gpu_check --out /tmp/g --device cpu --quick   # smoke test here
"""

from __future__ import annotations

import argparse
import functools
import json
import math
import os
import platform
import statistics
import subprocess
import sys
import time
import traceback
from pathlib import Path

import torch

from bench.bench_rasterizer import make_scene
from idsplat_ns.render import rasterize_camera, rasterize_lidar

REPO = Path(__file__).resolve().parents[1]

T0 = time.perf_counter()
DEADLINE = [math.inf]  # seconds since T0 after which no new measurement starts (--torch-deadline-s)
OUT = [Path(".")]  # --out
DEFAULT_GARDEN = REPO.parent / "shared" / "data" / "gsplat" / "test_garden.npz"
BUILD_SNIPPET = "import time; t=time.time(); from gsplat.cuda._backend import _C; print('gsplat built in', round(time.time()-t,1), 's', _C is not None)"


@functools.lru_cache(maxsize=4)
def garden_scene(path: Path, n: int, width: int, height: int, seed: int = 0) -> dict:
    """N Gaussians from the garden points (anisotropic scales) and its camera 0 (CPU tensors)."""
    return make_scene(n, width, height, seed, path=path, anisotropic=True)


def lidar_rays(num_az: int = 2650, num_el: int = 64) -> tuple[torch.Tensor, torch.Tensor]:  # -> [R], [R]
    """Azimuth and elevation of a Waymo-top-like range image (radians)."""
    az = torch.linspace(-math.pi, math.pi, num_az + 1)[:-1]
    el = torch.linspace(math.radians(-17.6), math.radians(2.4), num_el)
    e, a = torch.meshgrid(el, az, indexing="ij")
    return a.reshape(-1), e.reshape(-1)


def to(scene: dict, device: str, grad: bool = False) -> dict:
    out = {}
    for k, v in scene.items():
        v = v.to(device)
        out[k] = v.clone().requires_grad_() if grad and k not in ("viewmats", "Ks") else v
    return out


def timed(fn, device: str, repeats: int) -> dict:
    """Median and min wall time of ``fn()`` over ``repeats`` runs after one warm-up (seconds), and
    the peak CUDA memory of one run (GiB)."""
    fn()
    if device == "cuda":
        torch.cuda.synchronize()
        torch.cuda.reset_peak_memory_stats()
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        if device == "cuda":
            torch.cuda.synchronize()
        times.append(time.perf_counter() - t0)
    peak = torch.cuda.max_memory_allocated() / 2**30 if device == "cuda" else float("nan")
    return {"median_s": statistics.median(times), "min_s": min(times), "peak_gib": peak}


def max_rel(a: torch.Tensor, b: torch.Tensor) -> float:
    """Largest difference relative to the reference's largest magnitude."""
    a, b = a.detach().double().cpu(), b.detach().double().cpu()
    return float((a - b).abs().max() / b.abs().max().clamp_min(1e-12))


def camera_out(scene: dict, w: int, h: int, backend: str, backward: bool, chunk: int | None = None):
    p = scene
    kw = {} if backend == "gsplat" else {"chunk_elems": chunk}
    out = rasterize_camera(p["means"], p["quats"], p["scales"], p["opacities"], p["features"], p["viewmats"],
                           p["Ks"], w, h, backend=backend, **kw)  # fmt: skip
    if backward:
        (out.features.square().sum() + out.depth.sum() + out.alpha.sum()).backward()
    return out


def lidar_out(scene: dict, az, el, backward: bool, cutoff=None, chunk: int | None = None):
    p = scene
    out = rasterize_lidar(p["means"], p["quats"], p["scales"], p["opacities"], p["features"], p["viewmats"][0],
                          az, el, ray_cutoff=cutoff, chunk_elems=chunk)  # fmt: skip
    if backward:
        loss = out.features.square().sum() + out.range.sum() + out.alpha.sum()
        if cutoff is not None:
            loss = loss + out.alpha_before_cutoff.sum()
        loss.backward()
    return out


def stage_parity(garden: Path, device: str, n: int, w: int, h: int) -> dict:
    """The torch backends on ``device`` against the same code on the CPU (outputs and gradients)."""
    scene = garden_scene(garden, n, w, h)
    res = {}
    cpu, dev = to(scene, "cpu", grad=True), to(scene, device, grad=True)
    a, b = camera_out(dev, w, h, "torch", True), camera_out(cpu, w, h, "torch", True)
    res["camera"] = {
        "features": max_rel(a.features, b.features), "alpha": max_rel(a.alpha, b.alpha),
        "depth": max_rel(a.depth, b.depth), "median_depth": max_rel(a.median_depth, b.median_depth),
        "instance_id_equal": bool((a.instance_id.cpu() == b.instance_id).float().mean() > 0.999),
        **{f"grad_{k}": max_rel(dev[k].grad, cpu[k].grad) for k in ("means", "quats", "scales", "opacities", "features")},
    }  # fmt: skip
    az, el = lidar_rays(660, 32)
    cutoff = torch.full_like(az, 5.0)
    cpu, dev = to(scene, "cpu", grad=True), to(scene, device, grad=True)
    a = lidar_out(dev, az.to(device), el.to(device), True, cutoff.to(device))
    b = lidar_out(cpu, az, el, True, cutoff)
    res["lidar"] = {
        "features": max_rel(a.features, b.features), "alpha": max_rel(a.alpha, b.alpha),
        "range": max_rel(a.range, b.range), "alpha_before_cutoff": max_rel(a.alpha_before_cutoff, b.alpha_before_cutoff),
        **{f"grad_{k}": max_rel(dev[k].grad, cpu[k].grad) for k in ("means", "quats", "scales", "opacities", "features")},
    }  # fmt: skip
    return res


def stage_camera_speed(garden: Path, device: str, backend: str, counts: list[int], w: int, h: int, repeats: int) -> list:
    rows = []
    for n in counts:
        if backend == "torch" and time.perf_counter() - T0 > DEADLINE[0]:
            rows.append({"backend": backend, "gaussians": n, "skipped": "past --torch-deadline-s"})
            continue
        try:
            rows.append(camera_row(garden, device, backend, n, w, h, repeats))
        except torch.OutOfMemoryError as exc:
            rows.append({"backend": backend, "gaussians": n, "size": f"{w}x{h}", "error": f"out of memory: {exc}"[:300]})
        print(json.dumps(rows[-1]), flush=True)
        if device == "cuda":
            torch.cuda.empty_cache()
    return rows


def camera_row(garden: Path, device: str, backend: str, n: int, w: int, h: int, repeats: int) -> dict:
    """Forward and forward+backward time of one camera image with ``n`` Gaussians."""
    scene = to(garden_scene(garden, n, w, h), device)
    fwd = timed(lambda: camera_out(scene, w, h, backend, False), device, repeats)
    both = timed(lambda: camera_out(to(scene, device, grad=True), w, h, backend, True), device, repeats)
    return {"backend": backend, "gaussians": n, "size": f"{w}x{h}", "fwd": fwd, "fwd_bwd": both,
                "mpix_per_s_fwd": w * h / fwd["median_s"] / 1e6, "mpix_per_s_fwd_bwd": w * h / both["median_s"] / 1e6}


def stage_lidar_speed(garden: Path, device: str, counts: list[int], grids: list[tuple[int, int]], repeats: int) -> list:
    rows = []
    for n in counts:
        scene = to(garden_scene(garden, n, 320, 240), device)
        for num_az, num_el in grids:
            if time.perf_counter() - T0 > DEADLINE[0]:
                rows.append({"gaussians": n, "rays": num_az * num_el, "skipped": "past --torch-deadline-s"})
                continue
            az, el = (x.to(device) for x in lidar_rays(num_az, num_el))
            fwd = timed(lambda: lidar_out(scene, az, el, False), device, repeats)
            both = timed(lambda: lidar_out({k: (v.clone().requires_grad_() if k not in ("viewmats", "Ks") else v)
                                            for k, v in scene.items()}, az, el, True), device, repeats)  # fmt: skip
            rays = num_az * num_el
            rows.append({"gaussians": n, "rays": rays, "fwd": fwd, "fwd_bwd": both,
                         "mrays_per_s_fwd": rays / fwd["median_s"] / 1e6})
            print(json.dumps(rows[-1]), flush=True)
        del scene
    return rows


def stage_block_sweep(garden: Path, device: str, n: int, w: int, h: int, blocks: list[int], repeats: int) -> list:
    """Forward+backward time of the torch camera and lidar rasterizers by compositor block size."""
    rows = []
    scene = to(garden_scene(garden, n, w, h), device)
    az, el = (x.to(device) for x in lidar_rays(2650, 64))
    for block in blocks:
        row = {"block_elems": block, "gaussians": n}
        try:
            row["camera_fwd_bwd"] = timed(lambda: camera_out(to(scene, device, grad=True), w, h, "torch", True, block),
                                          device, repeats)  # fmt: skip
            row["lidar_fwd_bwd"] = timed(lambda: lidar_out(to(scene, device, grad=True), az, el, True, chunk=block),
                                         device, repeats)  # fmt: skip
        except torch.OutOfMemoryError as exc:
            row["error"] = f"out of memory: {exc}"[:300]
        rows.append(row)
        print(json.dumps(row), flush=True)
        if device == "cuda":
            torch.cuda.empty_cache()
    return rows


def stage_training_step(garden: Path, device: str, n: int, w: int, h: int, steps: int, backend_auto: bool) -> dict:
    """Median time of one engine training step at the paper's sizes (see the module docstring)."""
    from idsplat_ns.model.gaussians import GaussianSet
    from idsplat_ns.model.lidar_render import LidarRayBatch
    from idsplat_ns.model.scene_model import DecoderConfig, SceneModel

    scene = garden_scene(garden, n, w, h)
    g = GaussianSet(n, 13)
    with torch.no_grad():
        g.means.copy_(scene["means"])
        g.scales.copy_(scene["scales"].log())
        g.quats.copy_(scene["quats"] / scene["quats"].norm(dim=1, keepdim=True))
        g.opacities.copy_(torch.logit(scene["opacities"]))
        g.features_rgb.normal_(0, 1)
        g.features.normal_(0, 0.01)
    model = SceneModel(g, num_sensors=1, decoder=DecoderConfig(), lidar_head_hidden=32).to(device)
    opt = torch.optim.Adam(model.parameters(), lr=1e-3, eps=1e-15)
    viewmat, K = scene["viewmats"][0].to(device), scene["Ks"][0].to(device)
    target = torch.rand(h, w, 3, device=device)
    az, el = lidar_rays(2650, 64)
    pick = torch.randperm(az.numel(), generator=torch.Generator().manual_seed(0))[:16384]
    d = torch.stack([el[pick].cos() * az[pick].cos(), el[pick].cos() * az[pick].sin(), el[pick].sin()], 1)
    c2w = torch.linalg.inv(scene["viewmats"][0])
    rays = LidarRayBatch(
        origins=c2w[:3, 3].expand(16384, 3).clone(), directions=d @ c2w[:3, :3].T, ranges=torch.full((16384,), 10.0),
        intensities=torch.full((16384,), 0.3), times=torch.zeros(16384, dtype=torch.float64),
        returned=torch.ones(16384, dtype=torch.bool),
    ).to(device)  # fmt: skip

    def step():
        opt.zero_grad(set_to_none=True)
        out = model.render_camera(viewmat, K, w, h, time=None)
        loss = (out["rgb"] - target).abs().mean()
        render, head = model.render_lidar(rays, c2w.to(device), num_time_bins=1)
        loss = loss + (render.range[:, 0] - rays.ranges).abs().mean() + head.intensity.sub(rays.intensities).abs().mean()
        loss.backward()
        opt.step()

    import idsplat_ns.render.camera as camera_module

    available = camera_module.gsplat_available
    if not backend_auto:  # keep render_camera's "auto" on the torch tile rasterizer
        camera_module.gsplat_available = lambda: False
    try:
        t = timed(step, device, steps)
    finally:
        camera_module.gsplat_available = available
    return {"gaussians": n, "size": f"{w}x{h}", "lidar_rays": 16384, "camera_backend": "auto" if backend_auto else "torch",
            **t, "paper_30k_steps_h": t["median_s"] * 30_000 / 3600}


def run_stage(results: dict, name: str, fn, *args):
    t0 = time.perf_counter()
    try:
        results[name] = fn(*args)
    except Exception as exc:  # a failed stage is a finding to write down, not the end of the run
        results[name] = {"error": f"{type(exc).__name__}: {exc}", "traceback": traceback.format_exc()}
    results.setdefault("stage_seconds", {})[name] = round(time.perf_counter() - t0, 1)
    print(f"== {name}: {results['stage_seconds'][name]} s", json.dumps(results[name], default=str)[:2000], flush=True)
    # written after every stage: a run stopped at its time limit keeps what it measured
    (OUT[0] / "gpu_check.json").write_text(json.dumps(results, indent=2, default=str))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", type=Path, required=True, help="folder for gpu_check.json and the logs")
    ap.add_argument("--device", default="cuda")
    ap.add_argument("--garden", type=Path, default=DEFAULT_GARDEN)
    ap.add_argument("--gsplat-build", action="store_true", help="compile gsplat's CUDA code in the background first")
    ap.add_argument("--quick", action="store_true", help="tiny sizes (a smoke test of this script on the CPU)")
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--torch-deadline-s", type=float, default=math.inf,
                    help="start no torch-backend measurement after this many seconds (leaves time for gsplat)")
    ap.add_argument("--stages", default="parity,camera-torch,lidar-torch,step-torch,pytest,camera-gsplat,step-gsplat",
                    help="comma-separated; also: block-sweep (the torch compositor's block size on this device)")
    ap.add_argument("--build-deadline-s", type=float, default=math.inf, help="stop the gsplat build after this many seconds")
    args = ap.parse_args()
    DEADLINE[0], OUT[0] = args.torch_deadline_s, args.out
    args.out.mkdir(parents=True, exist_ok=True)
    dev = args.device
    results: dict = {"python": platform.python_version(), "torch": torch.__version__,
                     "device_name": torch.cuda.get_device_name() if dev == "cuda" else platform.processor()}
    build = None
    if args.gsplat_build:
        # The same flags in every process (pytest's too): torch rebuilds an extension whose flags changed.
        os.environ.setdefault("MAX_JOBS", str(os.cpu_count() or 8))
        os.environ.setdefault("TORCH_CUDA_ARCH_LIST", "9.0")
        env = dict(os.environ)
        log = open(args.out / "gsplat_build.log", "w")
        build = subprocess.Popen([sys.executable, "-c", BUILD_SNIPPET], stdout=log, stderr=subprocess.STDOUT, env=env)
        build_t0 = time.perf_counter()
    w, h = (160, 120) if args.quick else (1920, 1280)
    big = [5000] if args.quick else [300_000, 1_000_000]
    stages = set(args.stages.split(","))
    if "parity" in stages:
        run_stage(results, "parity_torch_backend_vs_cpu", stage_parity, args.garden, dev, 2000 if args.quick else 20_000,
                  160 if args.quick else 320, 120 if args.quick else 240)  # fmt: skip
    if "camera-torch" in stages:
        run_stage(results, "camera_speed_torch", stage_camera_speed, args.garden, dev, "torch", big, w, h, args.repeats)
    if "lidar-torch" in stages:
        run_stage(results, "lidar_speed_torch", stage_lidar_speed, args.garden, dev, big[-1:],
                  [(330, 8)] if args.quick else [(2650, 64), (256, 64)], args.repeats)  # fmt: skip
    if "block-sweep" in stages:
        run_stage(results, "block_sweep_torch", stage_block_sweep, args.garden, dev, big[-1], w, h,
                  [1 << 18, 1 << 20, 1 << 22, 1 << 24], args.repeats)  # fmt: skip
    if "step-torch" in stages and time.perf_counter() - T0 < DEADLINE[0]:
        run_stage(results, "training_step_torch", stage_training_step, args.garden, dev, big[-1], w, h, args.repeats, False)
    if build is not None:
        try:
            rc = build.wait(timeout=max(1.0, args.build_deadline_s - (time.perf_counter() - T0)))
        except subprocess.TimeoutExpired:
            build.kill()
            rc = "killed at --build-deadline-s"
        results["gsplat_build"] = {"rc": rc, "seconds": round(time.perf_counter() - build_t0, 1),
                                   "log_tail": (args.out / "gsplat_build.log").read_text()[-3000:]}
        print("== gsplat build", json.dumps(results["gsplat_build"]), flush=True)
    if dev == "cuda" and results.get("gsplat_build", {}).get("rc", 0) == 0:
        try:
            import gsplat  # noqa: F401

            pytest = None if "pytest" not in stages else subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "tests/test_render_gsplat.py",
                                     "tests/test_mcmc.py", "-k", "gsplat or cuda"], cwd=REPO, capture_output=True, text=True,
                                    env=dict(os.environ, PYTHONPATH=os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")])))  # fmt: skip
            if pytest is not None:
                results["pytest_gpu"] = {"rc": pytest.returncode, "tail": (pytest.stdout + pytest.stderr)[-3000:]}
                print("== pytest", results["pytest_gpu"]["tail"], flush=True)
            if "camera-gsplat" in stages:
                run_stage(results, "camera_speed_gsplat", stage_camera_speed, args.garden, dev, "gsplat",
                          big + [3_000_000], w, h, args.repeats)  # fmt: skip
            if "step-gsplat" in stages:  # render_camera's backend "auto" picks gsplat on CUDA once it is importable
                run_stage(results, "training_step_gsplat", stage_training_step, args.garden, dev, 3_000_000, w, h, 10, True)
        except ImportError as exc:
            results["gsplat"] = f"not importable: {exc}"
    (args.out / "gpu_check.json").write_text(json.dumps(results, indent=2, default=str))
    print("wrote", args.out / "gpu_check.json")


if __name__ == "__main__":
    main()
