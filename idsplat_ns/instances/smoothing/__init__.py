"""Iterative robust coordinated-turn (CT) trajectory smoothing in GTSAM (paper Sec. 3.4 and the
supplementary "Trajectory smoothing")."""

from idsplat_ns.instances.smoothing.config import SmoothingConfig
from idsplat_ns.instances.smoothing.smoother import SmoothedTrajectory, smooth_trajectory

__all__ = ["SmoothingConfig", "SmoothedTrajectory", "smooth_trajectory"]
