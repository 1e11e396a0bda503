"""Benchmarks: each module a command that prints a table, run from the repository root as
``.venv/bin/python -m bench.<name>`` (the GPU scripts ``bench/gpu_*.sh`` run them the same way on a
lent machine). Shared parts: ``streets`` (built-in streets and settings variants), ``train_variants``
(ns-train/ns-eval runs, their command lines built by :mod:`idsplat_ns.batch.commands`),
``revisions`` (another revision's engine beside this checkout's), ``box_errors`` (poses against
annotated boxes), ``tracking_quality`` (a preprocessing run's tracking and box errors). Not part of the installed package; nothing in ``idsplat_ns`` imports it.
"""
