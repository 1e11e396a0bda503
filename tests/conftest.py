"""Shared fixtures: paths to ../shared/data and small generated scenes (cached per session)."""

from __future__ import annotations

import os
from pathlib import Path

import pytest
import torch

# Triton's interpreter runs the CUDA compositor's kernels on CPU tensors (tests/test_triton_composite.py).
# It must be on before Triton is first imported anywhere (transformers imports it while test modules
# are collected), since Triton decides how its own library functions run when it is imported.
if not torch.cuda.is_available():
    os.environ.setdefault("TRITON_INTERPRET", "1")

REPO = Path(__file__).resolve().parents[1]
SHARED_DATA = REPO.parent / "shared" / "data"


@pytest.fixture(scope="session", autouse=True)
def _private_cache(tmp_path_factory):
    """Generated scenes and stage caches go to a per-session folder, never the user's cache."""
    import os

    previous = os.environ.get("IDSPLAT_CACHE")
    os.environ["IDSPLAT_CACHE"] = str(tmp_path_factory.mktemp("idsplat_cache"))
    yield
    if previous is None:
        os.environ.pop("IDSPLAT_CACHE", None)
    else:
        os.environ["IDSPLAT_CACHE"] = previous


@pytest.fixture(scope="session")
def shared_data() -> Path:
    if not SHARED_DATA.is_dir():
        pytest.skip(f"{SHARED_DATA} not present (real test data lives beside the repository)")
    return SHARED_DATA


@pytest.fixture(scope="session")
def tiny_street(tmp_path_factory) -> Path:
    """The synthetic street's ``tiny`` preset, written once per test session."""
    from idsplat_ns.data.synthetic import generate_sequence

    out = tmp_path_factory.mktemp("tiny_street")
    return Path(generate_sequence(out / "tiny-seed0", preset="tiny", seed=0))
