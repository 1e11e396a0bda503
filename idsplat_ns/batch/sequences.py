"""The list of sequences a batch runs: a text file of paths, or a protocol name with a data root.

File format, one sequence a line (``#`` starts a comment, blank lines are ignored)::

    /data/pandaset/001                      # a path: any --data that ns-train recognises
    /data/pandaset/011   pandaset-10        # a path and the protocol it is evaluated under
    /data/waymo          streetgs  --segment 1005081002024129653_5313_150_5333_150

Columns: the path (relative paths are taken from the file's folder), then optionally a protocol
name (``--protocol``, idsplat_ns/data/protocols.py) or ``-`` for none, then dataparser options
for that sequence alone (``--segment``, ``--context-name``, ``--cameras ...``).

A protocol name instead of a file (``--sequences pandaset-10 --data-root /data/pandaset``) lists
the protocol's sequences under the data root: PandaSet folders ``ROOT/<id>``; Waymo v1 files
``ROOT/segment-<context>_with_camera_labels.tfrecord`` or a v2 root with the contexts in it.
"""

from __future__ import annotations

import re
import shlex
from dataclasses import dataclass
from pathlib import Path
from typing import Optional

from idsplat_ns.data.formats import is_v2_root
from idsplat_ns.data.protocols import PANDASET_10, PROTOCOL_NAMES, WAYMO_SETTINGS, protocol_dataset
from idsplat_ns.data.waymo.splits import experiment_settings, load_split
from idsplat_ns.errors import IDSplatError

_SAFE_NAME = re.compile(r"[^A-Za-z0-9._-]+")


@dataclass(frozen=True)
class Sequence:
    """One sequence of a batch: what ns-train's dataparser reads, and under which protocol."""

    name: str
    """Folder name of its outputs under --output-dir (unique within the batch)."""
    data: Path
    """The --data path (absolute): a PandaSet folder, a Waymo v1 .tfrecord or folder, a v2 root."""
    protocol: Optional[str] = None
    """The paper's protocol it is evaluated under (None: the dataparser's own split); the table's
    means are per protocol."""
    dataparser_args: tuple[str, ...] = ()
    """Extra dataparser options of this sequence alone (``--segment X``, ``--context-name X``)."""


def sequence_name(data: Path, dataparser_args: tuple[str, ...] = ()) -> str:
    """A folder name for a sequence: the Waymo segment/context when one is named, else the path's
    name without ``segment-`` and ``.tfrecord`` (so that names stay short and readable)."""
    for flag in ("--segment", "--context-name"):
        if flag in dataparser_args:
            i = dataparser_args.index(flag)
            if i + 1 < len(dataparser_args):
                return _clean(dataparser_args[i + 1])
    return _clean(data.name)


def _clean(name: str) -> str:
    name = name.removesuffix(".tfrecord").removeprefix("segment-").removesuffix("_with_camera_labels")
    return _SAFE_NAME.sub("_", name) or "sequence"


def parse_sequence_file(path: Path) -> list[Sequence]:
    """The sequences listed in ``path`` (format in the module docstring); one-line errors name the line."""
    path = Path(path)
    if not path.is_file():
        raise IDSplatError(f"--sequences {path}: no such file; give a text file of sequence paths or a protocol name "
                           f"({', '.join(PROTOCOL_NAMES)})")
    out: list[Sequence] = []
    for number, raw in enumerate(path.read_text().splitlines(), start=1):
        line = raw.split("#", 1)[0].strip()
        if not line:
            continue
        where = f"--sequences {path}, line {number}"
        try:
            fields = shlex.split(line)
        except ValueError as err:
            raise IDSplatError(f"{where}: cannot split {line!r} ({err}); check the quotes") from None
        data = Path(fields[0]).expanduser()
        if not data.is_absolute():
            data = path.parent / data
        protocol: Optional[str] = None
        rest = fields[1:]
        if rest and not rest[0].startswith("-"):
            protocol = None if rest[0] == "-" else rest[0]
            rest = rest[1:]
        elif rest and rest[0] == "-":
            rest = rest[1:]
        if protocol is not None and protocol not in PROTOCOL_NAMES:
            raise IDSplatError(f"{where}: unknown protocol {protocol!r}; use one of {', '.join(PROTOCOL_NAMES)} or '-'")
        args = tuple(rest)
        if not data.exists():  # found now, before any task starts, not inside one
            raise IDSplatError(f"{where}: {data}: no such file or folder; fix the path or remove the line")
        out.append(Sequence(sequence_name(data, args), data.resolve(), protocol, args))
    if not out:
        raise IDSplatError(f"--sequences {path}: lists no sequence; write one path a line")
    return unique_names(out, str(path))


def protocol_sequences(protocol: str, data_root: Optional[Path]) -> list[Sequence]:
    """The sequences of ``protocol`` under ``data_root`` (see the module docstring)."""
    if data_root is None:
        raise IDSplatError(f"--sequences {protocol}: a protocol name needs --data-root (the folder that holds its sequences)")
    root = Path(data_root).expanduser().resolve()
    if not root.is_dir():
        raise IDSplatError(f"--data-root {root}: no such folder; give the folder that holds the {protocol} sequences")
    if protocol_dataset(protocol) == "pandaset":
        return _all_present([Sequence(seq, root / seq, protocol) for seq in PANDASET_10], root, protocol)

    setting = experiment_settings()["view_density" if protocol.startswith("view-density-") else WAYMO_SETTINGS[protocol]]
    out = []
    for spec in load_split(setting.split):
        if is_v2_root(root):
            out.append(Sequence(spec.context_name, root, protocol, ("--context-name", spec.context_name)))
        else:
            out.append(Sequence(spec.context_name, root / f"{spec.segment}_with_camera_labels.tfrecord", protocol))
    return _all_present(out, root, protocol)


def _all_present(sequences: list[Sequence], root: Path, protocol: str) -> list[Sequence]:
    """``sequences``, once each one's data is found under ``root`` (checked before any task starts)."""
    missing = [s.data.name for s in sequences if not s.data.exists()]
    if missing:
        shown = ", ".join(missing[:3]) + (", ..." if len(missing) > 3 else "")
        raise IDSplatError(f"--data-root {root}: {len(missing)} of the {len(sequences)} {protocol} sequences are not there "
                           f"({shown}); add them, or list the ones you have in a --sequences file")
    return sequences


def unique_names(sequences: list[Sequence], where: str) -> list[Sequence]:
    """``sequences`` with output folder names made unique (``name``, ``name-2``, ...); the same
    data and options twice is refused, since both would write the same results."""
    seen: dict[str, int] = {}
    keys: set[tuple] = set()
    out = []
    for seq in sequences:
        key = (seq.data, seq.protocol, seq.dataparser_args)
        if key in keys:
            raise IDSplatError(f"--sequences {where}: {seq.data} is listed twice with the same options; remove one")
        keys.add(key)
        count = seen.get(seq.name, 0) + 1
        seen[seq.name] = count
        out.append(seq if count == 1 else Sequence(f"{seq.name}-{count}", seq.data, seq.protocol, seq.dataparser_args))
    return out


def load_sequences(spec: str, data_root: Optional[Path]) -> list[Sequence]:
    """``--sequences``: a protocol name (with ``data_root``) or a sequence file."""
    if spec in PROTOCOL_NAMES:
        return unique_names(protocol_sequences(spec, data_root), spec)
    if data_root is not None:
        raise IDSplatError(f"--data-root is only for a protocol name in --sequences; {spec} is a file: put full paths in it")
    return parse_sequence_file(Path(spec))
