"""The command lines of one sequence's steps (``idsplat-preprocess``, ``ns-train``, ``ns-eval``),
built from the batch's options and the user's pass-through ``ns-train`` options.

The user's options are ns-train's own, in ns-train's order: method options first, then optionally
a dataparser subcommand (``idsplat-auto``, ``idsplat-pandaset``, ``idsplat-waymo``) and its
options. The batch adds the data and the output folder. The same
selection and instance settings are translated for ``idsplat-preprocess`` so that it fills the
stage cache that ns-train then reuses.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Optional

from idsplat_ns.batch.sequences import Sequence
from idsplat_ns.data.formats import DATAPARSER_SUBCOMMANDS
from idsplat_ns.errors import IDSplatError
from idsplat_ns.instances.options import PREFIX as _PREPROCESS_PREFIX  # how ns-train spells a preprocessing setting

DATAPARSERS = tuple(DATAPARSER_SUBCOMMANDS[k] for k in ("auto", "pandaset", "waymo"))
"""Dataparser subcommands a batch can drive (each takes --data and --protocol)."""
BUILTIN = DATAPARSER_SUBCOMMANDS["builtin"]
RUN_TIMESTAMP = "run"
"""ns-train's --timestamp: a fixed run folder, so that a re-run finds (and resumes) it."""
OWNED_OPTIONS = ("--data", "--output-dir", "--experiment-name", "--timestamp", "--load-dir", "--load-step",
                 "--load-checkpoint", "--method-name")
"""ns-train options the batch sets itself (the data, the run folder, and which checkpoint a resume
starts from: the run's latest); given by the user they are refused."""
# Dataparser options that idsplat-preprocess shares (same names): the frame, camera and lidar
# selection and the split (the image scale does not change its input: it reads full-size images).
_PREPROCESS_DATA_OPTIONS = ("--segment", "--context-name", "--protocol", "--cameras", "--start-frame", "--end-frame",
                            "--train-fraction", "--eval-every", "--lidars", "--second-return", "--lidar-sensors")
_PREPROCESS_SUBCOMMAND = _PREPROCESS_PREFIX[2:]  # a settings subcommand, e.g. ...smoothing:none
_INSTANCE_MODE = "--pipeline.datamanager.instance-mode"


@dataclass(frozen=True)
class UserOptions:
    """The pass-through ns-train options, split at the dataparser subcommand."""

    method_args: tuple[str, ...]
    """Options before the dataparser subcommand (method, trainer, pipeline options)."""
    dataparser: str
    """The dataparser subcommand (``idsplat-auto`` when the user named none)."""
    dataparser_args: tuple[str, ...]
    """Options after the dataparser subcommand."""


def _flag(token: str) -> str:
    """``--a_b=3`` -> ``--a-b`` (tyro accepts both spellings and the ``=`` form)."""
    return token.split("=", 1)[0].replace("_", "-") if token.startswith("--") else token


def split_user_options(args: list[str]) -> UserOptions:
    """Split the pass-through options; one-line error for an option the batch owns."""
    for token in args:
        if _flag(token) in OWNED_OPTIONS:
            raise IDSplatError(f"ns-train option {_flag(token)}: set by idsplat-batch itself (data from --sequences, "
                               "run folders under --output-dir); remove it")
    subcommands = [i for i, t in enumerate(args) if t in DATAPARSERS]
    if BUILTIN in args:
        raise IDSplatError(f"ns-train dataparser {BUILTIN}: reads no --data; use one of {', '.join(DATAPARSERS)} "
                           "(write built-in streets to disk with idsplat-synth)")
    if len(subcommands) > 1:
        raise IDSplatError("ns-train options: more than one dataparser subcommand; give at most one")
    if not subcommands:
        return UserOptions(tuple(args), DATAPARSER_SUBCOMMANDS["auto"], ())
    i = subcommands[0]
    return UserOptions(tuple(args[:i]), args[i], tuple(args[i + 1:]))


def option_value(args: tuple[str, ...], flag: str) -> Optional[str]:
    """The value of ``flag`` in ``args`` (the last one, as tyro takes), in either ``--f v`` or ``--f=v`` form."""
    value = None
    for i, token in enumerate(args):
        if _flag(token) == flag:
            if "=" in token:
                value = token.split("=", 1)[1]
            elif i + 1 < len(args):
                value = args[i + 1]
    return value


def _option_groups(args: tuple[str, ...] | list[str], starts: tuple[str, ...] = ("--",)) -> list[list[str]]:
    """``args`` cut before each token that begins with one of ``starts``: each group is an option (or
    subcommand) and the values after it (tuple-valued settings take several)."""
    groups: list[list[str]] = []
    for token in args:
        if not groups or token.startswith(starts):
            groups.append([token])
        else:
            groups[-1].append(token)
    return groups


def _dataparser_tail(seq: Sequence, user: UserOptions) -> list[str]:
    """The data options: the sequence's data, protocol and own options, then the user's."""
    tail = ["--data", str(seq.data)]
    if seq.protocol is not None:
        tail += ["--protocol", seq.protocol]
    return tail + list(seq.dataparser_args) + list(user.dataparser_args)


def train_command(seq: Sequence, method: str, user: UserOptions, output_dir: Path) -> list[str]:
    """``ns-train`` for one sequence, in the fixed run folder ``OUTPUT_DIR/<sequence>/<method>/run``.

    The same command resumes: the project's trainer (idsplat_ns/nerfstudio/trainer.py) continues a
    run folder that holds checkpoints from the latest one, with ``--max-num-iterations`` the total."""
    cmd = ["ns-train", method, "--output-dir", str(output_dir), "--experiment-name", seq.name,
           "--timestamp", RUN_TIMESTAMP]
    if option_value(user.method_args, "--vis") is None:
        cmd += ["--vis", "tensorboard"]  # the default viewer would wait for a browser
    return cmd + list(user.method_args) + [user.dataparser] + _dataparser_tail(seq, user)


def preprocess_command(seq: Sequence, user: UserOptions) -> Optional[list[str]]:
    """``idsplat-preprocess`` with the settings ns-train will use (so that its cache is reused), or
    None when training needs no instances (``instance-mode static``)."""
    mode = option_value(user.method_args, _INSTANCE_MODE) or "self-supervised"
    if mode == "static":
        return None
    cmd = ["idsplat-preprocess", "--instance-mode", mode]
    tail = _dataparser_tail(seq, user)
    cmd += tail[:2]  # --data
    for group in _option_groups(tail[2:]):  # only the selection options idsplat-preprocess shares with the dataparser
        if _flag(group[0]) in _PREPROCESS_DATA_OPTIONS:
            cmd += group
    # The preprocess settings last and in the user's order: a settings subcommand
    # (pipeline.datamanager.preprocess.smoothing:none) takes the options after it, not the data's.
    for head, *values in _option_groups(user.method_args, ("--", _PREPROCESS_SUBCOMMAND)):
        if head.startswith(_PREPROCESS_PREFIX):
            cmd += ["--preprocess." + head[len(_PREPROCESS_PREFIX):], *values]
        elif head.startswith(_PREPROCESS_SUBCOMMAND):
            cmd.append("preprocess." + head[len(_PREPROCESS_SUBCOMMAND):])
    return cmd


def eval_command(config: Path, output: Path) -> list[str]:
    """``ns-eval`` of a trained run, writing ``output`` (eval.json)."""
    return ["ns-eval", "--load-config", str(config), "--output-path", str(output)]


def total_steps(method: str, user: UserOptions) -> int:
    """How many steps a complete training has: ``--max-num-iterations`` when given, else the method's."""
    given = option_value(user.method_args, "--max-num-iterations")
    if given is not None:
        try:
            return int(given)
        except ValueError:
            raise IDSplatError(f"--max-num-iterations {given}: not a whole number") from None
    from nerfstudio.configs.method_configs import all_methods

    if method not in all_methods:
        raise IDSplatError(f"--method {method}: not a registered nerfstudio method; see ns-train --help")
    return int(all_methods[method].max_num_iterations)
