"""``idsplat-export-onnx``: Grounding DINO, SAM 2 and DINOv3 checkpoints (Hugging Face
``transformers`` folders) to the ONNX files that the mask and feature stages read
(:mod:`idsplat_ns.instances.masks.grounded_sam2_onnx`, :mod:`idsplat_ns.instances.features.dinov3_onnx`).

One module per model, each a thin torch wrapper whose ``forward`` has exactly the project's input
and output names and layout; :mod:`.common` loads checkpoints and writes graphs atomically;
:mod:`.cli` is the command. See docs/onnx_export.md.
"""
