"""idsplat-export: write a trained IDSplat run as standard 3DGS .ply files and trajectories.

Writes into ``--output-dir``:

* ``static.ply``: the static background Gaussians (world frame);
* ``instances/instance_XXX.ply``: each instance's Gaussians in its own canonical frame (x forward,
  y left, z up), to be placed by its trajectory;
* ``trajectories.json``: per instance its canonical-to-world 4x4 pose at each step of its span,
  the step times (seconds since the sequence start) and the presence margin;
* ``scene_t<T>.ply``: the whole scene in the world at ``--time`` seconds (default: the first step).

Colours are the Gaussians' base colours (the screen-space decoder's correction has no
per-Gaussian form); see :mod:`idsplat_ns.model.ply_export`.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from rich.console import Console

from idsplat_ns.atomic import check_writable, removed_on_failure
from idsplat_ns.errors import IDSplatError, run_cli
from idsplat_ns.model.editing import SceneTensors
from idsplat_ns.model.ply_export import scene_at_time, select, splat_records, write_ply
from idsplat_ns.model.trajectories import default_span_margin
from idsplat_ns.runs.run_folder import SCENE_PREFIX, load_run

COLOUR_NOTE = ("f_dc holds the base colour (features_rgb) as a degree-0 SH; the model's screen-space "
               "decoder correction is not exportable per Gaussian, f_rest is zero")


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    p = argparse.ArgumentParser(prog="idsplat-export", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--load-config", type=Path, required=True, help="config.yml of a trained (or edited) run")
    p.add_argument("--output-dir", type=Path, required=True, help="folder for the .ply files and trajectories.json")
    p.add_argument("--time", type=float, default=None, help="seconds since the sequence start of the whole-scene .ply (default: first step)")
    p.add_argument("--sh-rest", type=int, default=45, help="zero f_rest coefficients to write (45: the degree-3 layout; 0: none)")
    return p.parse_args(argv)


def _trajectory_record(scene, z: int, ply: str, margin: float) -> dict:
    t = scene.trajectories
    first, last = int(t["span_first"][z]), int(t["span_last"][z])
    steps = range(first, last + 1) if first >= 0 else range(0)
    poses = scene.as_trajectories().step_poses().detach().double()[z]  # [F, 4, 4]
    return {
        "id": int(t["instance_ids"][z]),
        "ply": ply,
        "num_gaussians": int((scene.gaussians["instance_ids"] == int(t["instance_ids"][z])).sum()),
        "present_from": float(t["frame_times"][first]) - margin if first >= 0 else None,
        "present_to": float(t["frame_times"][last]) + margin if first >= 0 else None,
        "times": [float(t["frame_times"][k]) for k in steps],
        "poses": [poses[k].tolist() for k in steps],
    }


def export(args: argparse.Namespace) -> dict:

    if args.sh_rest < 0:
        raise IDSplatError(f"--sh-rest {args.sh_rest}: must be 0 or more")
    check_writable(args.output_dir, "--output-dir", folder=True)
    run = load_run(args.load_config)
    scene = SceneTensors.from_state_dict(run.pipeline_state, SCENE_PREFIX)
    with removed_on_failure(Path(args.output_dir)) as out:
        out.mkdir(parents=True, exist_ok=True)
        record, num_static = _write(scene, run, out, args)
    console = Console()
    console.print(f"wrote {out / 'static.ply'} ({num_static} Gaussians), {len(record['instances'])} instance .ply files, "
                  f"{out / record['scene_ply']} and {out / 'trajectories.json'}")
    return record


def _write(scene, run, out: Path, args: argparse.Namespace) -> tuple[dict, int]:
    """The .ply files and trajectories.json of ``scene`` in ``out``; returns the JSON record and the
    number of static Gaussians."""

    g, ids = scene.gaussians, scene.gaussians["instance_ids"]
    write_ply(out / "static.ply", splat_records(select(g, ids == 0), args.sh_rest))
    instances = []
    if scene.trajectories is not None:
        times = scene.trajectories["frame_times"].double().numpy()
        margin = default_span_margin(times)
        for z, iid in enumerate(scene.instance_ids):
            rel = f"instances/instance_{iid:03d}.ply"
            write_ply(out / rel, splat_records(select(g, ids == iid), args.sh_rest))
            instances.append(_trajectory_record(scene, z, rel, margin))
        time = float(times[0]) if args.time is None else args.time
    else:
        margin, time = 0.0, 0.0 if args.time is None else args.time
    scene_name = f"scene_t{time:.3f}.ply"
    write_ply(out / scene_name, splat_records(scene_at_time(scene, time), args.sh_rest))
    record = {"source_config": str(Path(args.load_config).resolve()), "step": run.step, "colour": COLOUR_NOTE,
              "time_unit": "seconds since the sequence start", "span_margin": margin, "scene_time": time,
              "scene_ply": scene_name, "static_ply": "static.ply", "instances": instances}
    (out / "trajectories.json").write_text(json.dumps(record, indent=1))
    return record, int((ids == 0).sum())


def main(argv: list[str] | None = None) -> None:
    args = parse_args(argv)
    run_cli(lambda: export(args))


if __name__ == "__main__":
    main()
