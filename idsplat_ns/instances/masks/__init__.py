"""Instance-mask sources (Grounded-SAM-2 through ONNX Runtime, precomputed folders, ground-truth
boxes as an oracle) and the folder format they share."""
