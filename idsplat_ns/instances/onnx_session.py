"""ONNX Runtime sessions for user-given model files (nothing is downloaded)."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

from idsplat_ns.errors import IDSplatError


def open_session(path: Optional[Path], option: str, threads: int = 0):
    """An ONNX Runtime CPU/GPU session for a user-given model file (one-line error when missing)."""
    if path is None:
        raise IDSplatError(f"{option} is not set; give the exported ONNX model file")
    path = Path(path)
    if not path.is_file():
        raise IDSplatError(f"{path}: model file not found; export it as described in docs/instances.md and pass it with {option}")
    import onnxruntime as ort

    opts = ort.SessionOptions()
    if threads:
        opts.intra_op_num_threads = threads
    providers = [p for p in ("CUDAExecutionProvider", "CPUExecutionProvider") if p in ort.get_available_providers()]
    try:
        return ort.InferenceSession(str(path), opts, providers=providers)
    except Exception as err:  # onnxruntime raises its own untyped errors for corrupt files
        raise IDSplatError(f"{path}: ONNX Runtime cannot load it ({str(err).splitlines()[0]}); re-export the model") from None


def model_identity(path: Optional[Path]) -> dict:
    """Size and modification time of a model file, for cache keys."""
    if path is None or not Path(path).is_file():
        return {"path": str(path), "missing": True}
    st = Path(path).stat()
    return {"path": str(Path(path).resolve()), "size": st.st_size, "mtime_ns": st.st_mtime_ns}
