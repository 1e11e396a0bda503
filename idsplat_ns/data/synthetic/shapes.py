"""Shapes of the synthetic street: analytic parts (boxes, vertical-axis cylinders, ellipsoids)
grouped into objects, the street's fixed dimensions, and yaw rotations. Everything is in the
street's local frame (metres, z up, ground at z = 0)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from idsplat_ns.data.synthetic.trajectories import Trajectory

PLANE, BOX, CYLINDER, ELLIPSOID = 0, 1, 2, 3
"""Part kinds. Cylinders have their axis along the part's z; ellipsoids are axis aligned."""


class PartMotion(Protocol):
    """Pose of a part in its object's frame over time (a swinging limb, a turning crank)."""

    def pose(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Centre [N, 3] and object-from-part rotation [N, 3, 3] at times `t` [N]."""
        ...


@dataclass
class Part:
    """One analytic shape, placed in its object's frame."""

    kind: int
    """PLANE, BOX, CYLINDER or ELLIPSOID."""
    material: int
    """Material id (see `materials`)."""
    center: np.ndarray  # [3]
    """Centre in the object frame."""
    size: np.ndarray  # [3]
    """Box: half extents; cylinder: (radius, radius, half height); ellipsoid: radii."""
    rotation: np.ndarray = field(default_factory=lambda: np.eye(3))  # [3, 3]
    """Object-from-part rotation (columns are the part axes in the object frame)."""
    color: np.ndarray = field(default_factory=lambda: np.full(3, 0.5))  # [3]
    """Base colour, linear-ish RGB in [0, 1]."""
    style: int = 0
    """Texture variant (facade style, hash seed of a window pattern, ...)."""
    motion: PartMotion | None = None
    """Pose in the object frame over time; None for parts fixed in their object (`center`, `rotation`)."""


@dataclass
class SceneObject:
    """A group of parts; vehicles and people are instances with cuboid ground truth."""

    name: str
    """Readable name (`building_3`, `parked_car_0`, `turning_car`)."""
    parts: list[Part]
    """The shapes, in the object frame (x forward, y left, z up for vehicles)."""
    trajectory: Trajectory | None = None
    """Pose over time in the local frame; None for the static street."""
    instance_id: int = 0
    """0 for background, k >= 1 for vehicles and people (the value in the instance masks)."""
    label: str = ""
    """PandaSet cuboid label ("Car", "Pickup Truck", "Bus", "Pedestrian", "Bicycle")."""
    moving: bool = False
    """True for road users that move during the sequence."""
    dimensions: tuple[float, float, float] | None = None
    """(width, length, height) of the cuboid; it stands on the ground, centred on the object origin in
    x and y, and holds every part at every time (moving limbs included)."""
    uuid: str = ""
    """Track id in the cuboid annotations."""
    attributes: dict[str, str] = field(default_factory=dict)
    """Extra cuboid columns (`attributes.pedestrian_behavior`, `attributes.rider_status`, ...)."""

    @property
    def articulated(self) -> bool:
        """Whether some part moves inside the object (then it is not a rigid body)."""
        return any(part.motion is not None for part in self.parts)

    def bounding_sphere(self) -> tuple[np.ndarray, float]:
        """Centre [3] (object frame) and radius of a sphere that holds every part (at every time)."""
        if self.articulated:  # moving parts: the cuboid holds them at every time
            width, length, height = self.dimensions
            return np.array([0.0, 0.0, height / 2]), float(np.linalg.norm([length / 2, width / 2, height / 2]))
        corners = []
        for part in self.parts:
            signs = np.array(np.meshgrid([-1, 1], [-1, 1], [-1, 1], indexing="ij")).reshape(3, -1).T
            corners.append(part.center + (signs * part.size) @ part.rotation.T)
        pts = np.concatenate(corners)
        centre = 0.5 * (pts.min(0) + pts.max(0))
        return centre, float(np.linalg.norm(pts - centre, axis=1).max())


@dataclass(frozen=True)
class StreetLayout:
    """Fixed dimensions of the street (local frame)."""

    lane_width: float = 3.5
    """Width of each of the four driving lanes (two per direction)."""
    parking_width: float = 2.0
    """Parking strip between the outer lane and the curb, both sides."""
    sidewalk_width: float = 4.0
    """Sidewalk from the curb to the building line."""
    curb_height: float = 0.15
    """Height of the sidewalks above the road."""
    side_street_x: float = 45.0
    """Local x of the side street's centre line (it joins from the left, +y)."""
    side_street_half_width: float = 4.0
    """Half width of the side street's road."""
    x_min: float = -50.0
    """Start of the built-up street."""
    x_max: float = 200.0
    """End of the built-up street."""

    @property
    def road_half_width(self) -> float:
        """Curb position |y|."""
        return 2 * self.lane_width + self.parking_width

    @property
    def building_line(self) -> float:
        """|y| of the sidewalk's outer edge, where facades start."""
        return self.road_half_width + self.sidewalk_width


def yaw_matrix(yaw: np.ndarray) -> np.ndarray:
    """Rotations [N, 3, 3] about z by `yaw` [N] radians."""
    c, s = np.cos(yaw), np.sin(yaw)
    out = np.zeros(np.shape(yaw) + (3, 3))
    out[..., 0, 0], out[..., 0, 1] = c, -s
    out[..., 1, 0], out[..., 1, 1] = s, c
    out[..., 2, 2] = 1.0
    return out


def box_part(material: int, lo, hi, color=(0.5, 0.5, 0.5), style: int = 0) -> Part:
    """A box part between corners ``lo`` and ``hi`` (object frame)."""
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    return Part(BOX, material, 0.5 * (lo + hi), 0.5 * (hi - lo), color=np.asarray(color, float), style=style)


# Wheel cylinders have their axis along the vehicle's y: part z -> object -y.
