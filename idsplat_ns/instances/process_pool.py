"""Instances worked on side by side: registration and smoothing treat each instance alone, so a
pool of processes gives the same tracks as one process, in about 1/N of the time on N cores.

Processes, not threads: most of an instance's time is numpy and Python between small calls,
which hold the GIL. They are spawned (not forked: the parent may hold torch's OpenMP threads) and
start in 2-3 s, so a small scene's work stays in this process (``REGISTRATION_MIN_OBSERVATIONS``,
``SMOOTHING_MIN_OBSERVATIONS``).
"""

from __future__ import annotations

import concurrent.futures as cf
import multiprocessing
import os
from typing import Callable, Sequence, TypeVar

from threadpoolctl import threadpool_limits
from tqdm import tqdm

from idsplat_ns.errors import IDSplatError

Item = TypeVar("Item")
Shared = TypeVar("Shared")
Result = TypeVar("Result")

REGISTRATION_MIN_OBSERVATIONS = 300
"""With ``workers`` 0, the observations (instance-frames) from which registration runs in
processes: at about 0.1 s each, a pool's start pays from a few hundred."""
SMOOTHING_MIN_OBSERVATIONS = 500
"""The same for smoothing, at 0.01-0.03 s an observation (a small street's 250 took 2.3 s alone
and 5.2 s in two processes; the segment street's first 100 frames, about 700, took 16 s alone)."""


def available_cores() -> int:
    """CPU cores this process may run on."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        return os.cpu_count() or 1


def resolve_workers(workers: int, items: int, observations: int, min_observations: int) -> int:
    """Processes to use for ``items`` instances holding ``observations`` in all: ``workers``, or with
    0 one per core from ``min_observations`` on; never more than the instances."""
    if workers < 0:
        raise IDSplatError(f"preprocess workers={workers}: choose 0 (one per core) or more (--pipeline.datamanager.preprocess.workers)")
    if workers == 0:
        workers = available_cores() if observations >= min_observations else 1
    return max(1, min(workers, items))


_SHARED: dict = {}  # in a worker: what every item of its pool reads (sent once, not per item)


def _start_worker(shared: object) -> None:
    threadpool_limits(1)  # N processes on N cores: more threads each only contend
    _SHARED["value"] = shared


def _call(fn: Callable, item: object) -> object:
    return fn(_SHARED["value"], item)


def map_instances(fn: Callable[[Shared, Item], Result], shared: Shared, items: Sequence[Item], workers: int,
                  sizes: Sequence[int], desc: str, progress: bool = True) -> list[Result]:
    """``[fn(shared, item) for item in items]``, in ``workers`` spawned processes when more than one
    (``shared`` sent once to each; the largest ``sizes`` first, so that no large instance starts
    last). ``fn`` must be a module-level function, ``shared`` and the items picklable."""
    bar = tqdm(total=len(items), desc=desc, disable=not progress)
    try:
        if workers <= 1:
            out = []
            # The workers' thread limit here too: a multi-threaded BLAS sums in another order, and
            # the results must not depend on the number of processes.
            with threadpool_limits(1):
                for item in items:
                    out.append(fn(shared, item))
                    bar.update()
            return out
        order = sorted(range(len(items)), key=lambda k: -sizes[k])
        results: list = [None] * len(items)
        with cf.ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context("spawn"),
                                    initializer=_start_worker, initargs=(shared,)) as pool:
            futures = {pool.submit(_call, fn, items[k]): k for k in order}
            try:
                for future in cf.as_completed(futures):
                    results[futures[future]] = future.result()
                    bar.update()
            except cf.process.BrokenProcessPool:
                raise IDSplatError(f"{desc}: a worker process stopped (out of memory, or a script that calls the "
                                   "preprocessing without `if __name__ == \"__main__\":`); rerun with "
                                   "--pipeline.datamanager.preprocess.workers 1") from None
        return results
    finally:
        bar.close()
