"""Evaluation: image, lidar and tracking metrics, per-object diagnosis, plots.

Layer: above ``model``; it may import ``model``, ``instances``, ``data``, ``render`` and the
lowest layer, never ``runs``, the adapter or anything above.
"""
