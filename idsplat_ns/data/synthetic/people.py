"""Pedestrians and cyclists of the synthetic street: articulated bodies and where they go.

A person is a `SceneObject` that follows a trajectory like a vehicle, but some of its parts also
move inside the object frame (`Part.motion`): a pedestrian's legs and arms swing with the gait and
the body bobs; a cyclist's legs follow the pedals, the cranks turn and the wheels roll. The cuboid
holds the body at every time, so the motion is non-rigid inside a rigid box, as in real
annotations: a method that models people as rigid bodies is tested, not flattered.

Object frame: x forward, y left, z up, origin on the ground under the body. Limbs are cylinders
along the segment between two joints (`LimbBone`). Where people go: `people_placement.py`.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from idsplat_ns.data.synthetic import materials as mat
from idsplat_ns.data.synthetic.shapes import BOX, CYLINDER, ELLIPSOID, Part

SKIN_TONES = np.array([[0.93, 0.76, 0.64], [0.84, 0.64, 0.50], [0.69, 0.49, 0.35], [0.50, 0.34, 0.23], [0.33, 0.22, 0.15]])
HAIR_COLORS = np.array([[0.08, 0.06, 0.05], [0.25, 0.16, 0.09], [0.55, 0.40, 0.22], [0.70, 0.62, 0.45], [0.55, 0.55, 0.55]])
SHIRT_COLORS = np.array(
    [[0.75, 0.12, 0.10], [0.12, 0.30, 0.65], [0.90, 0.88, 0.84], [0.15, 0.15, 0.16], [0.20, 0.52, 0.30],
     [0.95, 0.70, 0.10], [0.55, 0.25, 0.55], [0.45, 0.65, 0.80], [0.85, 0.45, 0.15], [0.60, 0.58, 0.50]]
)  # fmt: skip
TROUSER_COLORS = np.array([[0.10, 0.12, 0.22], [0.18, 0.18, 0.19], [0.35, 0.30, 0.22], [0.55, 0.52, 0.45], [0.22, 0.30, 0.45]])
BIKE_COLORS = np.array([[0.70, 0.08, 0.08], [0.08, 0.20, 0.55], [0.92, 0.92, 0.90], [0.10, 0.10, 0.10], [0.10, 0.45, 0.25]])

ROLE_PLAIN, ROLE_SHOE, ROLE_HAND = 0, 1, 2
"""Cloth part roles, `Part.style & 3`: plain cloth, a lower leg ending in a shoe, an arm ending in a
hand; `style >> 2` is the skin-tone index (the hand's colour) or, on a head, the hair-colour index."""

EGO_HALF_SIZE = (2.35, 0.95)
"""Half length and half width of the ego vehicle's footprint (it has no geometry of its own)."""
CLEARANCE = 0.6
"""Smallest gap (m) kept between a person's footprint and any vehicle, the ego or another person."""


def _down(angle: np.ndarray) -> np.ndarray:
    """Unit vectors [N, 3] pointing down, turned forward (towards +x) by `angle` [N] about y."""
    return np.stack([np.sin(angle), np.zeros_like(angle), -np.cos(angle)], -1)


def _points(x: float | np.ndarray, y: float | np.ndarray, z: float | np.ndarray, n: int) -> np.ndarray:
    """Points [n, 3] from coordinates that are scalars or [n] arrays."""
    return np.stack([np.broadcast_to(np.asarray(v, float), (n,)) for v in (x, y, z)], -1)


def bone_frame(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Centre [N, 3] and rotation [N, 3, 3] of a segment from joints `a` to `b` ([N, 3] each).

    The part's z runs from `a` to `b`; its x is perpendicular to z and to the object's y (bones of
    legs and arms lie in planes of constant y), falling back to z x (object x) for sideways bones.
    """
    z = b - a
    z = z / np.linalg.norm(z, axis=-1, keepdims=True)
    x = np.cross(np.array([0.0, 1.0, 0.0]), z)
    sideways = np.linalg.norm(x, axis=-1) < 1e-6
    x[sideways] = np.cross(z[sideways], np.array([1.0, 0.0, 0.0]))
    x = x / np.linalg.norm(x, axis=-1, keepdims=True)
    y = np.cross(z, x)
    return 0.5 * (a + b), np.stack([x, y, z], -1)


@dataclass(frozen=True)
class Gait:
    """Walking: legs and arms swing in the object's x-z plane; the hips rise and fall with the legs.

    Left leg phase `2 pi frequency t + phase`, right leg half a cycle later. The thigh swings by
    `swing` either way; the knee bends most as the leg swings through (mid swing). The hips sit as
    high as the straighter leg allows, so the standing foot stays on the ground.
    """

    thigh: float
    """Hip-to-knee length, m."""
    shin: float
    """Knee-to-ankle length, m."""
    sole: float
    """Height of the ankle above the ground under a straight leg (shoe), m."""
    hip_half_width: float
    """|y| of the hip joints."""
    shoulder_height: float
    """Shoulder height when the legs are straight, m."""
    shoulder_half_width: float
    """|y| of the shoulder joints."""
    arm_length: float
    """Shoulder-to-fingertip length, m."""
    swing: float
    """Thigh swing amplitude, radians."""
    frequency: float
    """Strides (two steps) per second."""
    phase: float
    """Phase of the left leg at t = 0, radians."""

    @property
    def hip_height(self) -> float:
        """Hip height when both legs are straight (the highest the hips get)."""
        return self.sole + self.thigh + self.shin

    def _phi(self, t: np.ndarray, side: int) -> np.ndarray:
        return 2 * np.pi * self.frequency * t + self.phase + (0.0 if side > 0 else np.pi)

    def _leg_angles(self, phi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Thigh angle (forward positive) and knee bend [N], radians."""
        return self.swing * np.sin(phi), 0.06 + 0.9 * np.maximum(np.cos(phi), 0.0) ** 2

    def bob(self, t: np.ndarray) -> np.ndarray:
        """Vertical offset [N] (<= 0) of the hips and everything above them."""
        reach = []
        for side in (1, -1):
            theta, knee = self._leg_angles(self._phi(t, side))
            reach.append(self.thigh * np.cos(theta) + self.shin * np.cos(theta - knee))
        return self.sole + np.maximum(*reach) - self.hip_height

    def joints(self, chain: str, side: int, t: np.ndarray) -> list[np.ndarray]:
        """Joint positions ([N, 3] each) of the `leg` (hip, knee, ankle) or `arm` (shoulder, hand)."""
        phi, bob, n = self._phi(t, side), self.bob(t), len(t)
        if chain == "leg":
            theta, knee = self._leg_angles(phi)
            hip = _points(0.0, side * self.hip_half_width, self.hip_height + bob, n)
            k = hip + self.thigh * _down(theta)
            return [hip, k, k + self.shin * _down(theta - knee)]
        if chain == "arm":  # swings against the leg of its side
            shoulder = _points(0.0, side * self.shoulder_half_width, self.shoulder_height + bob, n)
            return [shoulder, shoulder + self.arm_length * _down(0.04 - 0.75 * self.swing * np.sin(phi))]
        raise ValueError(f"a walker has no {chain!r}")


@dataclass(frozen=True)
class Pedalling:
    """A rider on a bicycle: cranks turn at `frequency`; each leg reaches from the hip to its pedal.

    The knee is placed by two-link inverse kinematics (thigh and shin of fixed length), bent forward.
    """

    bottom_bracket: tuple[float, float]
    """(x, z) of the crank axle."""
    crank: float
    """Crank length, m."""
    hip: tuple[float, float]
    """(x, z) of the hip joints."""
    half_width: float
    """|y| of the legs and pedals."""
    thigh: float
    """Hip-to-knee length, m."""
    shin: float
    """Knee-to-pedal length, m."""
    frequency: float
    """Crank revolutions per second."""
    phase: float
    """Angle of the left crank at t = 0 (from +x towards +z), radians."""

    def pedal(self, side: int, t: np.ndarray) -> np.ndarray:
        """Pedal positions [N, 3]; riding forward turns the cranks clockwise seen from the left."""
        angle = self.phase - 2 * np.pi * self.frequency * t + (0.0 if side > 0 else np.pi)
        bx, bz = self.bottom_bracket
        return _points(bx + self.crank * np.cos(angle), side * self.half_width, bz + self.crank * np.sin(angle), len(t))

    def joints(self, chain: str, side: int, t: np.ndarray) -> list[np.ndarray]:
        """Joint positions ([N, 3] each) of the `leg` (hip, knee, pedal) or `crank` (axle, pedal)."""
        pedal = self.pedal(side, t)
        if chain == "crank":
            axle = _points(self.bottom_bracket[0], side * self.half_width, self.bottom_bracket[1], len(t))
            return [axle, pedal]
        if chain != "leg":
            raise ValueError(f"a rider has no {chain!r}")
        hip = _points(self.hip[0], side * self.half_width, self.hip[1], len(t))
        v = pedal - hip
        d = np.minimum(np.linalg.norm(v, axis=1), self.thigh + self.shin - 1e-6)
        u = v / np.linalg.norm(v, axis=1, keepdims=True)
        along = (self.thigh**2 - self.shin**2 + d**2) / (2 * d)
        across = np.sqrt(np.maximum(self.thigh**2 - along**2, 0.0))
        forward = np.stack([-u[:, 2], np.zeros(len(t)), u[:, 0]], -1)  # u turned up-forward in x-z
        knee = hip + along[:, None] * u + across[:, None] * forward
        return [hip, knee, pedal]


@dataclass(frozen=True)
class LimbBone:
    """Motion of the cylinder between joints `segment` and `segment + 1` of a rig's chain."""

    rig: Gait | Pedalling
    """The walker's gait or the rider's pedalling."""
    chain: str
    """"leg", "arm" (walker) or "crank" (rider)."""
    side: int
    """+1 left, -1 right."""
    segment: int
    """0 for the first bone of the chain (thigh, upper arm, crank arm), 1 for the second (shin)."""

    def pose(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Centre [N, 3] and object-from-part rotation [N, 3, 3] at times `t` [N]."""
        joints = self.rig.joints(self.chain, self.side, np.asarray(t, float))
        return bone_frame(joints[self.segment], joints[self.segment + 1])


@dataclass(frozen=True)
class Carried:
    """Motion of a part that rides on the walker's hips (torso, head): up and down with the gait."""

    gait: Gait
    """The walker's gait."""
    centre: np.ndarray = field(compare=False)  # [3]
    """Centre when the legs are straight."""

    def pose(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Centre [N, 3] and rotation [N, 3, 3] at times `t` [N]."""
        t = np.asarray(t, float)
        centre = np.tile(self.centre, (len(t), 1))
        centre[:, 2] += self.gait.bob(t)
        return centre, np.broadcast_to(np.eye(3), (len(t), 3, 3))


@dataclass(frozen=True)
class Pedal:
    """Motion of a pedal block: it follows the crank's end and stays level."""

    rig: Pedalling
    """The rider's pedalling."""
    side: int
    """+1 left, -1 right."""

    def pose(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Centre [N, 3] and rotation [N, 3, 3] at times `t` [N]."""
        t = np.asarray(t, float)
        return self.rig.pedal(self.side, t), np.broadcast_to(np.eye(3), (len(t), 3, 3))


@dataclass(frozen=True)
class Rolling:
    """Motion of a wheel: turns about the object's y axis through `centre` at `rate` rad/s."""

    centre: np.ndarray = field(compare=False)  # [3]
    """Axle position."""
    base_rotation: np.ndarray = field(compare=False)  # [3, 3]
    """Object-from-part rotation at t = 0 (puts the cylinder's axis along y)."""
    rate: float = 0.0
    """Angular speed, rad/s (speed / radius: rolling without slip)."""

    def pose(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Centre [N, 3] and rotation [N, 3, 3] at times `t` [N]."""
        a = self.rate * np.asarray(t, float)
        c, s = np.cos(a), np.sin(a)
        rot_y = np.zeros((len(a), 3, 3))
        rot_y[:, 0, 0], rot_y[:, 0, 2], rot_y[:, 1, 1], rot_y[:, 2, 0], rot_y[:, 2, 2] = c, s, 1.0, -s, c
        return np.tile(self.centre, (len(a), 1)), rot_y @ self.base_rotation


def _limb(rig: Gait | Pedalling, chain: str, side: int, segment: int, radius: float, length: float, material: int,
          color: np.ndarray, style: int) -> Part:
    """A cylinder of `radius` and `length` moving with bone `segment` of the rig's `chain`."""
    motion = LimbBone(rig, chain, side, segment)
    centre, rot = motion.pose(np.zeros(1))
    return Part(CYLINDER, material, centre[0], np.array([radius, radius, length / 2]), rot[0],
                np.asarray(color, float), style, motion)


def _static_bone(a: np.ndarray, b: np.ndarray, radius: float, material: int, color: np.ndarray, style: int = 0) -> Part:
    """A cylinder from `a` to `b` ([3] each) fixed in the object (bicycle tubes, a rider's arms)."""
    a, b = np.asarray(a, float)[None], np.asarray(b, float)[None]
    centre, rot = bone_frame(a, b)
    length = float(np.linalg.norm(b - a))
    return Part(CYLINDER, material, centre[0], np.array([radius, radius, length / 2]), rot[0], np.asarray(color, float), style)


def _looks(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, int, int]:
    """Shirt colour, trouser colour, skin-tone index and hair-colour index of one person."""
    shirt = np.clip(SHIRT_COLORS[rng.integers(len(SHIRT_COLORS))] * rng.uniform(0.85, 1.1), 0, 1)
    trousers = np.clip(TROUSER_COLORS[rng.integers(len(TROUSER_COLORS))] * rng.uniform(0.85, 1.1), 0, 1)
    return shirt, trousers, int(rng.integers(len(SKIN_TONES))), int(rng.integers(len(HAIR_COLORS)))


def walker_parts(rng: np.random.Generator, speed: float) -> tuple[list[Part], Gait]:
    """Parts of a walking pedestrian (torso, head, two arms, two two-bone legs) and its gait."""
    height = rng.uniform(1.58, 1.88)
    s = height / 1.75
    head = np.array([0.10, 0.085, 0.115]) * s
    leg = 0.47 * height
    swing = rng.uniform(0.42, 0.48)
    torso_hw = 0.17 * s
    gait = Gait(
        thigh=0.5 * leg,
        shin=0.5 * leg,
        sole=0.04,
        hip_half_width=0.085 * s,
        shoulder_height=height - 2 * head[2] - 0.07 * s,
        shoulder_half_width=torso_hw + 0.05 * s,
        arm_length=0.42 * height,
        swing=swing,
        # A step is the foot's travel from back to front (2 leg sin swing); a stride is two steps.
        frequency=speed / (4 * leg * np.sin(swing)),
        phase=rng.uniform(0, 2 * np.pi),
    )
    shirt, trousers, skin, hair = _looks(rng)
    z_lo, z_hi = gait.hip_height - 0.08 * s, gait.shoulder_height + 0.04 * s
    torso_c = np.array([0.0, 0.0, 0.5 * (z_lo + z_hi)])
    head_c = np.array([0.01, 0.0, gait.shoulder_height + 0.07 * s + head[2]])
    parts = [
        Part(BOX, mat.PERSON_CLOTH, torso_c, np.array([0.11 * s, torso_hw, 0.5 * (z_hi - z_lo)]),
             color=shirt, style=ROLE_PLAIN, motion=Carried(gait, torso_c)),
        Part(ELLIPSOID, mat.PERSON_SKIN, head_c, head, color=SKIN_TONES[skin], style=hair << 2,
             motion=Carried(gait, head_c)),
    ]
    for side in (1, -1):
        parts.append(_limb(gait, "leg", side, 0, 0.07 * s, gait.thigh, mat.PERSON_CLOTH, trousers, ROLE_PLAIN))
        parts.append(_limb(gait, "leg", side, 1, 0.055 * s, gait.shin, mat.PERSON_CLOTH, trousers, ROLE_SHOE))
        parts.append(_limb(gait, "arm", side, 0, 0.045 * s, gait.arm_length, mat.PERSON_CLOTH, shirt,
                           ROLE_HAND | skin << 2))
    return parts, gait


# Wheel cylinders have their axis along the object's y: part z -> object -y.
_AXLE_ROTATION = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])


def cyclist_parts(rng: np.random.Generator, speed: float) -> tuple[list[Part], Pedalling]:
    """Parts of a bicycle (wheels, frame, cranks, pedals, bars, saddle) and its rider, and the pedalling."""
    height = rng.uniform(1.62, 1.88)
    s = height / 1.75
    wheel_r, half_base = 0.34, 0.52
    crank = 0.17
    thigh = shin = 0.245 * height
    bb = np.array([-0.05, 0.0, 0.29])
    # Saddle on a 73 deg seat tube, high enough that the leg is nearly straight at the bottom.
    seat_dir = np.array([-np.cos(np.radians(73)), 0.0, np.sin(np.radians(73))])
    hip = bb + (0.95 * (thigh + shin) - crank) * seat_dir
    saddle = hip - np.array([0.0, 0.0, 0.06])
    head_top = np.array([0.36, 0.0, saddle[2] - 0.10])
    head_bottom = np.array([0.42, 0.0, saddle[2] - 0.30])
    bar = head_top + np.array([-0.02, 0.0, 0.08])
    rear, front = np.array([-half_base, 0.0, wheel_r]), np.array([half_base, 0.0, wheel_r])
    pedalling = Pedalling(
        bottom_bracket=(float(bb[0]), float(bb[2])),
        crank=crank,
        hip=(float(hip[0]), float(hip[2])),
        half_width=0.11,
        thigh=thigh,
        shin=shin,
        frequency=speed / rng.uniform(4.2, 5.0),  # metres travelled per crank turn (gearing)
        phase=rng.uniform(0, 2 * np.pi),
    )
    paint = np.clip(BIKE_COLORS[rng.integers(len(BIKE_COLORS))] * rng.uniform(0.85, 1.1), 0, 1)
    grey, black = np.array([0.55, 0.56, 0.58]), np.array([0.06, 0.06, 0.06])
    parts = [
        Part(CYLINDER, mat.BIKE_WHEEL, c, np.array([wheel_r, wheel_r, 0.018]), _AXLE_ROTATION, black,
             motion=Rolling(c, _AXLE_ROTATION, speed / wheel_r))
        for c in (rear, front)
    ]
    tubes = [(bb, saddle - [0, 0, 0.05]), (bb, head_bottom), (saddle - [0, 0, 0.10], head_top), (head_bottom, head_top),
             (bb, rear), (saddle - [0, 0, 0.10], rear), (head_bottom, front), (head_top, bar)]
    parts += [_static_bone(a, b, 0.018, mat.BIKE_FRAME, paint) for a, b in tubes]
    parts.append(_static_bone(bar + [0, -0.25, 0], bar + [0, 0.25, 0], 0.014, mat.BIKE_FRAME, grey))
    parts.append(Part(BOX, mat.BIKE_FRAME, saddle + [0.0, 0, 0.02], np.array([0.13, 0.07, 0.025]), color=black))
    parts.append(Part(CYLINDER, mat.BIKE_FRAME, bb + [0, -0.06, 0], np.array([0.10, 0.10, 0.006]), _AXLE_ROTATION, grey))
    for side in (1, -1):
        parts.append(_limb(pedalling, "crank", side, 0, 0.014, crank, mat.BIKE_FRAME, grey, 0))
        parts.append(Part(BOX, mat.BIKE_FRAME, np.zeros(3), np.array([0.05, 0.05, 0.012]), color=black,
                          motion=Pedal(pedalling, side)))
    # The rider: leaning torso, head, arms to the grips (fixed on the bicycle), legs to the pedals.
    shirt, trousers, skin, hair = _looks(rng)
    shoulder = hip + 0.30 * height * np.array([np.cos(np.radians(48)), 0.0, np.sin(np.radians(48))])
    centre, rot = bone_frame(hip[None] - [0, 0, 0.04], shoulder[None] + [0, 0, 0.04])
    torso_half = np.array([0.10 * s, 0.17 * s, 0.5 * float(np.linalg.norm(shoulder - hip)) + 0.04])
    parts.append(Part(BOX, mat.PERSON_CLOTH, centre[0], torso_half, rot[0], shirt, ROLE_PLAIN))
    head = np.array([0.10, 0.085, 0.115]) * s
    parts.append(Part(ELLIPSOID, mat.PERSON_SKIN, shoulder + [0.07, 0, 0.07 * s + head[2]], head,
                      color=SKIN_TONES[skin], style=hair << 2))
    for side in (1, -1):
        grip = bar + [0.0, side * 0.22, 0.0]
        parts.append(_static_bone(shoulder + [0, side * 0.2 * s, 0], grip, 0.045 * s, mat.PERSON_CLOTH, shirt,
                                  ROLE_HAND | skin << 2))
        parts.append(_limb(pedalling, "leg", side, 0, 0.07 * s, thigh, mat.PERSON_CLOTH, trousers, ROLE_PLAIN))
        parts.append(_limb(pedalling, "leg", side, 1, 0.055 * s, shin, mat.PERSON_CLOTH, trousers, ROLE_SHOE))
    return parts, pedalling
