"""Loading a user's checkpoint folder (local only) and writing an ONNX graph atomically."""

from __future__ import annotations

import json
import os
import warnings
from pathlib import Path
from typing import Sequence

import torch

from idsplat_ns.atomic import TMP_MARK, atomic_path
from idsplat_ns.errors import IDSplatError

OPSET = 17  # GridSample (deformable attention) needs >= 16; 17 has LayerNormalization


def checkpoint_config(folder: Path, model_types: Sequence[str], what: str) -> dict:
    """``config.json`` of a checkpoint folder, checked to be one of ``model_types`` (one-line errors)."""
    folder = Path(folder)
    if not folder.is_dir():
        raise IDSplatError(f"{folder}: checkpoint folder not found; download the {what} checkpoint (docs/onnx_export.md) and give its folder")
    cfg_path = folder / "config.json"
    if not cfg_path.is_file():
        raise IDSplatError(f"{cfg_path}: not found; give a Hugging Face transformers checkpoint folder of {what} (config.json + weights)")
    try:
        config = json.loads(cfg_path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as err:
        raise IDSplatError(f"{cfg_path}: unreadable ({str(err).splitlines()[0]}); download the checkpoint again") from None
    kind = config.get("model_type") if isinstance(config, dict) else None
    if kind not in model_types:
        raise IDSplatError(f"{cfg_path}: model_type is {kind!r}, expected {' or '.join(map(repr, model_types))}; "
                           f"give the {what} checkpoint folder here")
    return config


def load_model(model_class, folder: Path, model_types: Sequence[str], what: str) -> torch.nn.Module:
    """The model of ``folder`` in eval mode and float32, never downloading.

    The attention implementation is transformers' default on purpose: in transformers 5.24 the
    "eager" BERT attention adds a boolean 4D mask instead of masking with it, so Grounding DINO's
    phrase-wise text attention would leak across phrases (the SDPA path, which the legacy ONNX
    exporter converts, masks correctly; tests/test_export_onnx.py compares the two).
    """
    from transformers.utils import logging as hf_logging

    checkpoint_config(folder, model_types, what)
    hf_logging.disable_progress_bar()  # keeps a failing command's stderr to its one error line
    try:
        # No dtype= here: with dtype=torch.float32, transformers 5.24 left SAM 2 giving NaN (tested);
        # half-precision checkpoints are cast after loading instead.
        model = model_class.from_pretrained(str(folder), local_files_only=True)
    except (OSError, ValueError, RuntimeError) as err:  # missing/corrupt weight files, shape mismatches
        raise IDSplatError(f"{folder}: transformers cannot load the {what} checkpoint ({str(err).splitlines()[0]}); "
                           "download it again (docs/onnx_export.md)") from None
    return model.float().eval()


def check_writable(folder: Path) -> Path:
    """Create ``folder`` if needed and make sure files can be written in it (one-line error otherwise)."""
    folder = Path(folder)
    try:
        folder.mkdir(parents=True, exist_ok=True)
        probe = folder / f"{TMP_MARK}probe-{os.getpid()}"
        probe.write_bytes(b"")
        probe.unlink()
    except OSError as err:
        raise IDSplatError(f"{folder}: output folder not writable ({err.strerror}); choose another --out or fix its permissions") from None
    return folder


def export_graph(module: torch.nn.Module, args: tuple, path: Path, input_names: Sequence[str],
                 output_names: Sequence[str], dynamic_axes: dict | None = None) -> Path:
    """Trace ``module`` on ``args`` into ``path`` (written under a temporary name, renamed when complete).

    The TorchScript-based exporter is used: it needs no extra package (the dynamo exporter needs
    onnxscript) and handles the transformers models' Python-side shape arithmetic by tracing.
    """
    import onnx

    path = Path(path)
    with atomic_path(path) as tmp, torch.no_grad(), warnings.catch_warnings():
        # Tracer warnings ("converting a tensor to a Python boolean") concern branches whose value
        # is fixed for a given export size; the tests compare the graphs with torch to catch real ones.
        warnings.simplefilter("ignore")
        torch.onnx.export(module, args, str(tmp), dynamo=False, input_names=list(input_names),
                          output_names=list(output_names), dynamic_axes=dynamic_axes or {}, opset_version=OPSET,
                          do_constant_folding=True)
        onnx.checker.check_model(str(tmp))
    return path
