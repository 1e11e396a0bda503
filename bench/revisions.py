"""Another revision's engine beside this checkout's, for the side-by-side benches.

A revision is a git worktree under /tmp (``--against REV``) or a source tree made elsewhere
(``--against-tree DIR``, e.g. ``git archive REV idsplat_ns | tar -x -C .prev`` where there is no
git history). Each run is a child process whose ``PYTHONPATH`` puts that tree's ``idsplat_ns``
first and this checkout after it, so the other engine runs with this checkout's presets and bench
scripts. A child prints one ``RESULT <json>`` line.
"""

from __future__ import annotations

import hashlib
import json
import os
import subprocess
import sys
from pathlib import Path
from typing import Optional

REPO = Path(__file__).resolve().parents[1]


def worktree(rev: str) -> Path:
    """A git worktree of ``rev`` under /tmp (made once, reused while it is at that commit)."""
    sha = subprocess.run(["git", "rev-parse", rev], cwd=REPO, check=True, capture_output=True, text=True).stdout.strip()
    path = Path("/tmp") / f"idsplat-bench-{sha[:10]}"
    if not path.is_dir():
        subprocess.run(["git", "worktree", "add", "--detach", str(path), sha], cwd=REPO, check=True, capture_output=True)
    return path


def engine_only(tree: Path) -> Path:
    """A folder holding only ``tree``'s engine (``idsplat_ns``, linked): put before this checkout on
    the path, it times that engine with this checkout's presets (``method_configs``), which are
    what nerfstudio's installed entry points name."""
    overlay = Path("/tmp") / f"idsplat-bench-engine-{hashlib.sha1(str(tree.resolve()).encode()).hexdigest()[:10]}"
    overlay.mkdir(exist_ok=True)
    link = overlay / "idsplat_ns"
    if not link.exists():
        link.symlink_to(tree.resolve() / "idsplat_ns")
    return overlay


def trees(script: str, against: Optional[str], against_tree: Optional[Path]) -> dict[str, Path]:
    """The working tree and the revisions to time beside it, by the name their rows get."""
    found = {"working tree": REPO}
    if against:
        found[against] = worktree(against)
    if against_tree:
        if not (against_tree / "idsplat_ns").is_dir():
            raise SystemExit(f"{script}: {against_tree} has no idsplat_ns/; pass a source tree")
        found[str(against_tree)] = against_tree.resolve()
    return found


def run_child(script: str, cmd: list[str], tree: Path, threads: int) -> dict:
    """Run ``cmd`` (this interpreter is prepended) on ``tree``'s engine; returns its RESULT."""
    # The engine first, then this checkout, then what the path held before (a --target install of
    # the dependencies).
    first = [str(REPO)] if tree == REPO else [str(engine_only(tree)), str(REPO)]
    path = os.pathsep.join(first + [p for p in os.environ.get("PYTHONPATH", "").split(os.pathsep) if p])
    env = dict(os.environ, PYTHONPATH=path, OMP_NUM_THREADS=str(threads))
    # Run from the engine's folder: `python -m` puts the working directory first on the path, so an
    # idsplat_ns there would shadow the engine asked for.
    done = subprocess.run([sys.executable] + cmd, env=env, capture_output=True, text=True, cwd=first[0])
    line = [x for x in done.stdout.splitlines() if x.startswith("RESULT ")]
    if done.returncode or not line:
        raise SystemExit(f"{script}: the run on {tree} failed:\n{done.stderr[-3000:]}")
    return json.loads(line[-1][7:])
