"""Per-point features for registration correspondences: DINOv3 (ONNX), RGB, DAISY, FPFH."""
