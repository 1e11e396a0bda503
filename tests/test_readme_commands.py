"""Every command in the README's bash blocks parses with the program's real command-line parser,
so that the README cannot drift from the options the programs take. (The commands' behaviour is
run elsewhere: tests/test_data_selection.py, test_tracks_json.py, test_end_to_end.py.)"""

from __future__ import annotations

import re
import shlex
from pathlib import Path

import pytest

pytest.importorskip("nerfstudio")

README = Path(__file__).resolve().parents[1] / "README.md"


def readme_commands() -> list[str]:
    """Command lines of the README's ```bash blocks (comments and continuations handled)."""
    text = README.read_text()
    lines = []
    for block in re.findall(r"```bash\n(.*?)```", text, flags=re.S):
        block = block.replace("\\\n", " ")
        for line in block.splitlines():
            line = line.split(" #")[0].strip()
            if line and not line.startswith("#"):
                lines.append(line)
    return lines


def _tyro(cls, args: list[str]):
    import tyro

    return tyro.cli(cls, args=args)


def _ns_train(args):
    from nerfstudio.configs.method_configs import AnnotatedBaseConfigUnion

    return _tyro(AnnotatedBaseConfigUnion, args)


def _ns_eval(args):
    from nerfstudio.scripts.eval import ComputePSNR

    return _tyro(ComputePSNR, args)


def _ns_viewer(args):
    import tyro
    from nerfstudio.scripts.viewer.run_viewer import RunViewer

    return _tyro(tyro.conf.FlagConversionOff[RunViewer], args)


def _idsplat_synth(args):
    from idsplat_ns.data.synthetic.cli import _parser

    return _parser().parse_args(args)


def _idsplat_preprocess(args):
    from idsplat_ns.cli.preprocess import parse_args

    return parse_args(args)


def _idsplat_edit(args):
    from idsplat_ns.cli.edit import parse_args

    return parse_args(args)


def _idsplat_export(args):
    from idsplat_ns.cli.export import parse_args

    return parse_args(args)


def _idsplat_batch(args):
    from idsplat_ns.batch.cli import parse_args

    # The batch's own options are checked by its parser; the rest must be valid ns-train options.
    batch, user = parse_args(args)
    return _ns_train([batch.method, *user.method_args, user.dataparser, "--data", "x", *user.dataparser_args])


def _idsplat_render_drive(args):
    from idsplat_ns.cli.render_drive import parse_args

    return parse_args(args)


def _idsplat_report(args):
    from idsplat_ns.cli.report import parse_args

    return parse_args(args)


def _idsplat_export_onnx(args):
    from idsplat_ns.instances.export_onnx.cli import parse_args

    return parse_args(args)


PARSERS = {
    "idsplat-export-onnx": _idsplat_export_onnx,
    "idsplat-batch": _idsplat_batch,
    "idsplat-edit": _idsplat_edit,
    "idsplat-export": _idsplat_export,
    "idsplat-render-drive": _idsplat_render_drive,
    "idsplat-report": _idsplat_report,
    "ns-train": _ns_train,
    "ns-eval": _ns_eval,
    "ns-viewer": _ns_viewer,
    "idsplat-synth": _idsplat_synth,
    "idsplat-preprocess": _idsplat_preprocess,
}
NOT_PARSED = {"make", "source", "pip"}  # make demo / make test are run by CI itself; pip is not ours


def test_the_readme_has_commands():
    programs = {shlex.split(c)[0] for c in readme_commands()}
    assert {"ns-train", "ns-eval", "idsplat-preprocess"} <= programs


@pytest.mark.parametrize("command", readme_commands())
def test_readme_command_parses(command):
    argv = shlex.split(command)
    program, args = argv[0], argv[1:]
    if program in NOT_PARSED:
        return
    assert program in PARSERS, f"README shows {program!r}, which no test parses: add it to PARSERS"
    PARSERS[program](args)  # tyro/argparse exit with an error (SystemExit) on any unknown option


@pytest.mark.parametrize("command", [
    "ns-train idsplat-fast --pipeline.datamanager.dataparser.builtin-preset tiny",  # the old option layout
    "ns-train idsplat idsplat-waymo --data x.tfrecord --no-such-option 1",
    "idsplat-preprocess --data DIR --masks.kind precomputed",
])
def test_a_wrong_command_is_caught(command, capsys):
    argv = shlex.split(command)
    with pytest.raises(SystemExit):
        PARSERS[argv[0]](argv[1:])
