"""One step of one sequence as a Ray task: the step's command in a subprocess, its output in a log.

A subprocess isolates the step: a crash, an out-of-memory kill or a library's global state ends
that process only, and Ray's worker lives on to report it. The step's own one-line error (the
project's ``error: ...``) is read back from its log.
"""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Optional

import ray

ERROR_PREFIX = "error: "
_MAX_ERROR_CHARS = 400


@dataclass(frozen=True)
class StepResult:
    """What a step's task reports back."""

    returncode: int
    """The subprocess's exit status (negative: killed by that signal)."""
    error: Optional[str]
    """One line saying why it failed, None when it succeeded."""
    seconds: float
    """Wall time of the subprocess."""
    node: str
    """The Ray node (IP) that ran it."""


def resolve_program(name: str) -> str:
    """The console script ``name`` of this worker's Python environment (it need not be on PATH:
    Ray workers start with the driver's interpreter, not its shell)."""
    beside = Path(sys.executable).parent / name
    if beside.is_file():
        return str(beside)
    found = shutil.which(name)
    if found is None:
        raise FileNotFoundError(f"{name}: not installed beside {sys.executable} nor on PATH; "
                                "install idsplat_ns on every Ray node (pip install -e .)")
    return found


def one_line_error(log: Path, returncode: int) -> str:
    """Why a step failed, in one line: its last ``error: ...`` line, else its last line (the
    exception of a traceback), else the signal that killed it."""
    lines: list[str] = []
    try:
        with open(log, "rb") as f:
            f.seek(max(0, os.path.getsize(log) - 64_000))  # the end is enough, logs can be long
            lines = [ln.strip() for ln in f.read().decode("utf8", "replace").splitlines() if ln.strip()]
    except OSError:
        pass
    # Progress bars redraw with carriage returns: keep the text after the last one.
    lines = [ln.rsplit("\r", 1)[-1].strip() for ln in lines]
    errors = [ln for ln in lines if ln.startswith(ERROR_PREFIX)]
    boxed = _last_box_message(lines)
    if errors:
        text = errors[-1][len(ERROR_PREFIX):]
    elif boxed is not None:
        text = boxed
    elif returncode < 0:
        try:
            name = signal.Signals(-returncode).name
        except ValueError:
            name = f"signal {-returncode}"
        text = f"killed by {name}" + (" (out of memory? the kernel's OOM killer sends SIGKILL)" if returncode == -9 else "")
    elif lines:
        text = lines[-1]
    else:
        text = f"exit status {returncode} and an empty log"
    text = " ".join(text.split())
    return (text[:_MAX_ERROR_CHARS] + "...") if len(text) > _MAX_ERROR_CHARS else text


_BOX_CHARS = "│╭╮╰╯─┃━┏┓┗┛ "


def _last_box_message(lines: list[str]) -> Optional[str]:
    """The first text line of the last rich box in ``lines`` (how tyro reports a bad ns-train option:
    a box whose last line is only a border, and whose first line says what is wrong)."""
    if not lines or not lines[-1].startswith("╰"):
        return None  # the log does not end with a box: a box earlier on is not the failure
    tops = [i for i, ln in enumerate(lines) if ln.startswith("╭")]
    if not tops:
        return None
    for ln in lines[tops[-1] + 1:]:
        text = ln.strip(_BOX_CHARS)
        if text:
            return text
    return None


def _die_with_parent() -> None:
    """In the child, before exec: be killed when the Ray worker dies (a cancelled or killed batch
    must not leave trainings running that a re-run would race with). Linux only."""
    import ctypes

    PR_SET_PDEATHSIG = 1
    ctypes.CDLL(None, use_errno=True).prctl(PR_SET_PDEATHSIG, signal.SIGKILL)


def run_command(argv: list[str], log: Path, env: Optional[dict[str, str]] = None) -> StepResult:
    """Run ``argv`` (program name first) with stdout and stderr appended to ``log``."""
    log = Path(log)
    log.parent.mkdir(parents=True, exist_ok=True)
    start = time.perf_counter()
    node = ray.util.get_node_ip_address() if ray.is_initialized() else "local"
    full_env = {**os.environ, **(env or {}), "PYTHONUNBUFFERED": "1"}
    with open(log, "ab") as out:
        out.write(f"\n$ {' '.join(argv)}\n".encode())
        out.flush()
        try:
            argv = [resolve_program(argv[0]), *argv[1:]]
        except FileNotFoundError as err:
            out.write(f"{ERROR_PREFIX}{err}\n".encode())
            return StepResult(127, str(err), 0.0, node)
        proc = subprocess.Popen(argv, stdout=out, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL, env=full_env,
                                preexec_fn=_die_with_parent if sys.platform.startswith("linux") else None)
        try:
            code = proc.wait()
        finally:
            # A cancelled task (KeyboardInterrupt raised in the worker) takes its subprocess with it.
            if proc.poll() is None:
                proc.kill()
                proc.wait()
    seconds = time.perf_counter() - start
    return StepResult(code, None if code == 0 else one_line_error(log, code), seconds, node)


@ray.remote(max_retries=0)
def run_step(argv: list[str], log: str, env: Optional[dict[str, str]] = None) -> StepResult:
    """The Ray task: one step's command (resources are set per step with ``.options``). Not
    retried: a failure is the sequence's result, and a retry would repeat an out-of-memory run."""
    return run_command(argv, Path(log), env)
