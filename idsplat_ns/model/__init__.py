"""Model maths that does not need nerfstudio: Gaussians, trajectories, decoders, lidar
supervision, densification, exposure and camera corrections, editing.

Layer: above ``instances``, below ``eval``; it may import ``instances``, ``data``, ``render`` and
the lowest layer.
"""
