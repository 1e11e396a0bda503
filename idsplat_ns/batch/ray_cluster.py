"""Getting a Ray cluster for a batch: a local one sized for the command, or an existing one by its
address, with one line that says why a connection failed.

Token authentication: since Ray 2.59, ``ray start --head`` turns it on when a token exists
(``~/.ray/auth_token``, written by any earlier local ``ray.init``), but a driver given an explicit
address never turns it on by itself (Ray's rule: a token is not sent to an address unless asked).
Such a cluster refuses the driver with ``InvalidAuthToken`` retries until the connection times out;
that is recognised and named, with the setting that fixes it (``RAY_AUTH_MODE=token``).
"""

from __future__ import annotations

import contextlib
import os
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Iterator, Optional

from idsplat_ns.errors import IDSplatError


@dataclass(frozen=True)
class RayStart:
    """How the driver gets a Ray cluster."""

    address: Optional[str] = None
    """An existing cluster's address (``ray://host:10001``, ``host:6379`` or ``auto``); None: start
    a local one for this command."""
    num_cpus: Optional[int] = None
    """Local cluster: CPU cores Ray may use (default: all)."""
    num_gpus: Optional[int] = None
    """Local cluster: GPUs Ray may use (default: those it finds)."""
    object_store_mb: int = 128
    """Local cluster: object store size; the tasks exchange only small results."""


STARTUP_ATTEMPTS = 3
"""Tries to start a local Ray before giving up."""


def start_ray(start: RayStart) -> None:
    """Connect to ``start.address`` or start a local Ray instance sized for this command."""
    import logging

    import ray

    # Read at start-up by this process and the Ray processes it spawns: no usage report is sent.
    os.environ["RAY_USAGE_STATS_ENABLED"] = "0"
    common = {"logging_level": logging.WARNING, "log_to_driver": False, "configure_logging": True}
    if start.address is not None:
        with _stderr_kept() as said:  # Ray's core writes its retries there (once a second, ~20 s)
            try:
                ray.init(address=start.address, **common)
                return
            except ConnectionError as err:
                failure = err
        raise IDSplatError(_connection_failure(start.address, failure, said())) from None
    # A local Ray gives its raylet a fixed 30 s to register; on a loaded machine that can run out,
    # and a second start usually makes it.
    for attempt in range(STARTUP_ATTEMPTS):
        try:
            # "local": a new instance even where RAY_ADDRESS is set or `ray start` left a cluster on this
            # machine (ray.init with no address would join that one, or fail on a stale record of it).
            ray.init(address="local", num_cpus=start.num_cpus or os.cpu_count(), num_gpus=start.num_gpus,
                     include_dashboard=False, object_store_memory=start.object_store_mb * 2**20, **common)
            return
        except Exception as err:  # Ray raises a bare Exception for this timeout
            if "timed out during startup" not in str(err):
                raise
            ray.shutdown()
            if attempt == STARTUP_ATTEMPTS - 1:
                raise IDSplatError(f"a local Ray did not start in {STARTUP_ATTEMPTS} tries (its raylet has 30 s to "
                                   "register; the machine is overloaded); run again when it is less busy, or "
                                   "start one with `ray start --head` and pass --address auto") from None


@contextlib.contextmanager
def _stderr_kept() -> Iterator[Callable[[], str]]:
    """Hold what is written to file descriptor 2 (Ray's C++ core logs there) inside the block;
    yields a reader of it. Replayed to stderr afterwards unless it only said what the one-line
    error will say."""
    sys.stderr.flush()
    saved = os.dup(2)
    held = tempfile.TemporaryFile()
    os.dup2(held.fileno(), 2)
    text: list[str] = []

    def read() -> str:
        if not text:
            sys.stderr.flush()
            held.seek(0)
            text.append(held.read().decode("utf8", "replace"))
        return text[0]

    try:
        yield read
    finally:
        os.dup2(saved, 2)
        os.close(saved)
        said = read()
        if said and "InvalidAuthToken" not in said:
            sys.stderr.write(said)
        held.close()


def _token_source() -> Optional[str]:
    """Where Ray would read a token from if token authentication were on, or None."""
    if os.environ.get("RAY_AUTH_TOKEN"):
        return "RAY_AUTH_TOKEN"
    if os.environ.get("RAY_AUTH_TOKEN_PATH"):
        return f"RAY_AUTH_TOKEN_PATH={os.environ['RAY_AUTH_TOKEN_PATH']}"
    default = Path.home() / ".ray" / "auth_token"
    return str(default) if default.is_file() else None


def _connection_failure(address: str, err: Exception, said: str) -> str:
    """The one line for a failed connection to ``address``; ``said``: what Ray logged meanwhile."""
    mode = os.environ.get("RAY_AUTH_MODE")
    if "InvalidAuthToken" in said:
        if (mode or "").lower() != "token":
            source = _token_source()
            where = f" (this machine has one: {source})" if source else " (the token that ray start used: RAY_AUTH_TOKEN or RAY_AUTH_TOKEN_PATH)"
            return (f"--address {address}: the cluster uses Ray token authentication and refused this driver, which sent "
                    f"no token; run with RAY_AUTH_MODE=token and the cluster's token{where} (docs/batch.md)")
        return (f"--address {address}: the cluster refused the token this driver sent ({_token_source() or 'none found'}); "
                "give the cluster's token in RAY_AUTH_TOKEN or RAY_AUTH_TOKEN_PATH (docs/batch.md)")
    return (f"--address {address}: cannot connect to a Ray cluster ({err}); start one with `ray start --head` "
            "or drop --address")
