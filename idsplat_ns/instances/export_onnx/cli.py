"""idsplat-export-onnx: write the Grounding DINO, SAM 2 and DINOv3 ONNX files that IDSplat's mask
and feature stages read, from Hugging Face transformers checkpoint folders (local; nothing downloads).

Writes into --out (each file under a temporary name, renamed when complete):
  grounding_dino.onnx, bert_vocab.txt    from --grounding-dino
  sam2_encoder.onnx, sam2_decoder.onnx   from --sam2
  dinov3_layer<K>.onnx                   from --dinov3
and prints the options that make ns-train / idsplat-preprocess use them. See docs/onnx_export.md.
"""

from __future__ import annotations

import argparse
import shutil
from pathlib import Path

from idsplat_ns.atomic import atomic_path
from idsplat_ns.errors import IDSplatError, run_cli
from idsplat_ns.instances.export_onnx import dinov3, grounding_dino, sam2
from idsplat_ns.instances.export_onnx.common import check_writable, checkpoint_config

PREFIX = "--pipeline.datamanager.preprocess"  # ns-train's; idsplat-preprocess takes --preprocess.*
VOCAB = "bert_vocab.txt"


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    p = argparse.ArgumentParser(prog="idsplat-export-onnx", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--out", type=Path, required=True, help="folder for the ONNX files (created if needed)")
    p.add_argument("--grounding-dino", type=Path, help="checkpoint folder of GroundingDinoForObjectDetection (e.g. IDEA-Research/grounding-dino-tiny)")
    p.add_argument("--sam2", type=Path, help="checkpoint folder of Sam2Model (e.g. facebook/sam2.1-hiera-large)")
    p.add_argument("--dinov3", type=Path, help="checkpoint folder of DINOv3ViTModel (e.g. facebook/dinov3-vitb16-pretrain-lvd1689m)")
    p.add_argument("--detector-size", type=int, nargs=2, default=(800, 1333), metavar=("H", "W"),
                   help="fixed Grounding DINO input size; match the cameras' aspect (default 800 1333)")
    p.add_argument("--dinov3-layer", type=int, default=dinov3.PAPER_LAYER, help="DINOv3 block whose tokens are output (paper: 7)")
    p.add_argument("--sam2-multimask", action="store_true", help="three SAM 2 mask candidates per box instead of one")
    return p.parse_args(argv)


def run(args: argparse.Namespace) -> dict[str, Path]:
    """Check every input first (nothing is written on a bad one), then export; returns the files written."""
    given = [(args.grounding_dino, grounding_dino.MODEL_TYPES, "Grounding DINO"), (args.sam2, sam2.MODEL_TYPES, "SAM 2"),
             (args.dinov3, dinov3.MODEL_TYPES, "DINOv3 ViT")]
    if not any(folder for folder, _, _ in given):
        raise IDSplatError("no checkpoint folder given; pass at least one of --grounding-dino, --sam2, --dinov3")
    for folder, types, what in given:
        if folder is not None:
            checkpoint_config(folder, types, what)
    if args.dinov3 is not None:
        dinov3.check_layer(args.dinov3, args.dinov3_layer)
    h, w = args.detector_size
    grounding_dino.check_size(h, w)
    out = check_writable(args.out)
    written: dict[str, Path] = {}
    if args.grounding_dino is not None:
        written["detector-path"] = grounding_dino.export_grounding_dino(args.grounding_dino, out / "grounding_dino.onnx", h, w)
        vocab = args.grounding_dino / "vocab.txt"
        if vocab.is_file():  # the BERT vocab of the text encoder, for the project's tokenizer
            with atomic_path(out / VOCAB) as tmp:
                shutil.copyfile(vocab, tmp)
            written["tokenizer-vocab"] = out / VOCAB
    if args.sam2 is not None:
        enc, dec = sam2.export_sam2(args.sam2, out / "sam2_encoder.onnx", out / "sam2_decoder.onnx", args.sam2_multimask)
        written["sam2-encoder-path"], written["sam2-decoder-path"] = enc, dec
    if args.dinov3 is not None:
        written["dinov3"] = dinov3.export_dinov3(args.dinov3, out / f"dinov3_layer{args.dinov3_layer}.onnx", args.dinov3_layer)
    return written


def usage_lines(written: dict[str, Path], grounding_dino_given: bool) -> list[str]:
    """The ns-train options that use the written files."""
    lines = []
    for key in ("detector-path", "tokenizer-vocab", "sam2-encoder-path", "sam2-decoder-path"):
        if key in written:
            lines.append(f"{PREFIX}.masks.grounded-sam2.{key} {written[key]}")
    if grounding_dino_given and "tokenizer-vocab" not in written:
        lines.append(f"{PREFIX}.masks.grounded-sam2.tokenizer-vocab <bert-base-uncased vocab.txt> "
                     "(the checkpoint folder has no vocab.txt)")
    if "dinov3" in written:
        lines.append(f"{PREFIX}.features.dinov3.model-path {written['dinov3']}")
    return lines


def main(argv: list[str] | None = None) -> None:
    def _main() -> None:
        args = parse_args(argv)
        written = run(args)
        for path in written.values():
            print(f"wrote {path}")
        print("use them with ns-train (idsplat-preprocess: --preprocess.* instead of --pipeline.datamanager.preprocess.*):")
        for line in usage_lines(written, args.grounding_dino is not None):
            print(f"  {line}")

    run_cli(_main)
