"""Evaluation: image, lidar and tracking metrics, plots."""
