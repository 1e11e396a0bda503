"""idsplat-edit: remove, move, re-time or duplicate instances of a trained IDSplat run and write the
result as a new run (config.yml + checkpoint) that ns-eval, ns-render and ns-viewer load.

Edits are applied in a fixed order, whatever the order on the command line: removals, re-timings,
moves, then duplicates (a duplicate copies the instance as already re-timed and moved). The maths
is in :mod:`idsplat_ns.model.editing`; instance IDs are those of the checkpoint, as listed by
``--list`` and shown in ns-eval's instance renders and plots.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from rich.console import Console
from rich.table import Table

from idsplat_ns.atomic import check_writable
from idsplat_ns.errors import IDSplatError, run_cli
from idsplat_ns.model.editing import EditError, SceneTensors
from idsplat_ns.model.instance_summary import summarise_instances
from idsplat_ns.nerfstudio.model_inputs import instance_inputs
from idsplat_ns.runs.edits import apply_edits, check_edit_values
from idsplat_ns.runs.run_folder import SCENE_PREFIX, load_run, write_run

EPILOG = """examples:
  idsplat-edit --load-config outputs/x/idsplat-fast/T/config.yml --list
  idsplat-edit --load-config CFG --output-dir edited --remove 3 5
  idsplat-edit --load-config CFG --output-dir edited --move 2 0 3.5 0 0          # 3.5 m to its left
  idsplat-edit --load-config CFG --output-dir edited --move 2 5 0 0 90 --frame world
  idsplat-edit --load-config CFG --output-dir edited --retime 4 0.5 1.5           # 0.5 s later, 1.5x as fast
  idsplat-edit --load-config CFG --output-dir edited --duplicate 1 0 -3.5 0      # a copy one lane over
"""


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    p = argparse.ArgumentParser(prog="idsplat-edit", description=__doc__, epilog=EPILOG,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--load-config", type=Path, required=True, help="config.yml of the trained run")
    p.add_argument("--output-dir", type=Path, default=None, help="folder of the edited run (needed for any edit)")
    p.add_argument("--list", action="store_true", help="print the instances (after the edits, if any)")
    p.add_argument("--points", action="store_true",
                   help="with --list: also the lidar points, label and class of each instance, from the run's data "
                        "(re-reads the data and its instance decomposition, cached: seconds to minutes)")
    p.add_argument("--remove", type=int, nargs="+", default=[], metavar="ID", help="remove these instances")
    p.add_argument("--move", type=float, nargs=5, action="append", default=[], metavar=("ID", "DX", "DY", "DZ", "DYAW"),
                   help="shift by DX DY DZ metres and turn by DYAW degrees (repeatable)")
    p.add_argument("--frame", choices=("instance", "world"), default="instance",
                   help="axes of --move/--duplicate offsets: the instance's own (x forward, y left; yaw about "
                        "its centre) or the world's (the path turns about its mean position)")
    p.add_argument("--retime", type=float, nargs="+", action="append", default=[], metavar="ARG",
                   help="ID SHIFT_S [SPEED]: start SHIFT_S seconds later and move SPEED times as fast "
                        "(default 1; repeatable)")
    p.add_argument("--duplicate", type=float, nargs=4, action="append", default=[], metavar=("ID", "DX", "DY", "DZ"),
                   help="add a copy under a new ID, offset by DX DY DZ metres (repeatable)")
    return p.parse_args(argv)


def instance_points(config) -> dict[int, tuple[int, str, str]]:
    """``{instance_id: (lidar points, label, class)}`` of the run's instance decomposition, rebuilt from its
    data as ns-eval does (stage caches make it cheap the second time). IDs that the data does not
    have (duplicates) are absent."""
    datamanager = config.pipeline.datamanager.setup(device="cpu", test_mode="inference")
    tracks = instance_inputs(datamanager.train_dataset.metadata).tracks
    if tracks is None:
        return {}
    return {int(t.instance_id): (len(t.canonical_points), str(t.label), t.category) for t in tracks.instances}


def print_instances(scene, console: Console, points: dict[int, tuple[int, str, str]] | None = None) -> None:
    rows = summarise_instances(scene)
    static = int((scene.gaussians["instance_ids"] == 0).sum())
    table = Table(title=f"{len(rows)} instances, {static} static Gaussians")
    columns = ["ID", "class (guess)", "from (s)", "to (s)", "Gaussians", "speed (m/s)", "L x W x H (m)"]
    if points is not None:
        columns += ["lidar points", "label", "class"]
    for col in columns:
        table.add_column(col, justify="left" if col in ("class (guess)", "label", "class") else "right")
    for r in rows:
        size = " x ".join(f"{v:.1f}" for v in r.size)
        cells = [str(r.instance_id), r.class_guess, f"{r.first_time:.2f}", f"{r.last_time:.2f}",
                 str(r.num_gaussians), f"{r.mean_speed:.1f}", size]
        if points is not None:
            n, label, cls = points.get(r.instance_id, (None, "?", "?"))
            cells += ["?" if n is None else str(n), label, cls]
        table.add_row(*cells)
    console.print(table)


def run(args: argparse.Namespace) -> Path | None:
    edits_given = bool(args.remove or args.move or args.retime or args.duplicate)
    if not edits_given and not args.list:
        raise IDSplatError("nothing to do: give --list or an edit (--remove, --move, --retime, --duplicate)")
    if edits_given and args.output_dir is None:
        raise IDSplatError("--output-dir is needed to write the edited run; give a new folder")
    if args.points and not args.list:
        raise IDSplatError("--points goes with --list")
    check_edit_values(args)
    if edits_given:
        check_writable(args.output_dir, "--output-dir", folder=True)
    trained = load_run(args.load_config)
    try:
        scene = SceneTensors.from_state_dict(trained.pipeline_state, SCENE_PREFIX)
    except EditError as err:
        raise IDSplatError(f"{trained.checkpoint_path}: {err}") from None
    if edits_given and scene.trajectories is None:
        raise IDSplatError(f"{args.load_config}: this run has no instances (a static model); nothing to edit")
    console = Console()
    if not console.is_terminal:  # piped or captured: rich would wrap the table at 80 columns
        console = Console(width=140)
    done = apply_edits(scene, args)
    if args.list:
        print_instances(scene, console, instance_points(trained.config) if args.points else None)
    if not edits_given:
        return None
    state = scene.to_state_dict(trained.pipeline_state, SCENE_PREFIX)
    config_path = write_run(trained, state, args.output_dir, {"edits": done})
    for line in done:
        console.print(line)
    console.print(f"edited run: {config_path}  (ns-eval / ns-render / ns-viewer --load-config {config_path})")
    return config_path


def main(argv: list[str] | None = None) -> None:
    args = parse_args(argv)
    run_cli(lambda: run(args))


if __name__ == "__main__":
    main()
