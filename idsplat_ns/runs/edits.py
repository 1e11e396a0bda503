"""The edits of a trained run's scene as ``idsplat-edit`` and the viewer panel give them: remove,
re-time, move, then duplicate (that fixed order whatever the order given; a duplicate copies the
instance as already re-timed and moved). The maths is in :mod:`idsplat_ns.model.editing`."""

from __future__ import annotations

import argparse
import math

from idsplat_ns.errors import IDSplatError
from idsplat_ns.model.editing import EditError


def _instance_id(value: float, option: str) -> int:
    if value != int(value) or value < 1:
        raise IDSplatError(f"{option}: instance ID {value:g} is not a positive integer; see --list")
    return int(value)


def check_edit_values(args: argparse.Namespace) -> None:
    """Every number of ``--move``, ``--duplicate`` and ``--retime`` finite (and a re-timing's speed
    positive), checked before the run is read or anything written: a NaN offset would be written
    into the trajectories."""
    for option, specs in (("--move", args.move), ("--duplicate", args.duplicate), ("--retime", args.retime)):
        for spec in specs:
            if not all(math.isfinite(v) for v in spec):
                raise IDSplatError(f"{option} {' '.join(f'{v:g}' for v in spec)}: every value must be a finite number")
    for spec in args.retime:
        if len(spec) == 3 and spec[2] <= 0:
            raise IDSplatError(f"--retime {' '.join(f'{v:g}' for v in spec)}: SPEED must be positive")


def apply_edits(scene, args: argparse.Namespace) -> list[str]:
    """Apply the command line's edits to ``scene`` (a SceneTensors); returns one line per edit."""
    done: list[str] = []
    try:
        if args.remove:
            scene.remove([_instance_id(i, "--remove") for i in args.remove])
            done.append(f"removed {' '.join(map(str, args.remove))}")
        for spec in args.retime:
            if len(spec) not in (2, 3):
                raise IDSplatError(f"--retime {' '.join(f'{v:g}' for v in spec)}: give ID SHIFT_S [SPEED]")
            iid, shift, speed = _instance_id(spec[0], "--retime"), spec[1], spec[2] if len(spec) == 3 else 1.0
            scene.retime(iid, shift, speed)
            done.append(f"retimed {iid}: {shift:+g} s, x{speed:g}")
        for iid, dx, dy, dz, dyaw in args.move:
            iid = _instance_id(iid, "--move")
            scene.move(iid, (dx, dy, dz), math.radians(dyaw), args.frame)
            done.append(f"moved {iid}: ({dx:g}, {dy:g}, {dz:g}) m, {dyaw:g} deg, {args.frame} frame")
        for iid, dx, dy, dz in args.duplicate:
            iid = _instance_id(iid, "--duplicate")
            new = scene.duplicate(iid, (dx, dy, dz), 0.0, args.frame)
            done.append(f"duplicated {iid} as {new}: ({dx:g}, {dy:g}, {dz:g}) m, {args.frame} frame")
    except EditError as err:
        raise IDSplatError(f"{args.load_config}: {err}") from None
    return done
