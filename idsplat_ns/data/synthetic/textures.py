"""Procedural textures: colour (albedo) and lidar reflectivity of every material at a hit point.

All patterns are pure functions of position (hashed value noise), so they are identical from every
view and every run: a fair, multi-view-consistent target for reconstruction.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from idsplat_ns.data.synthetic import materials as mat
from idsplat_ns.data.synthetic.people import HAIR_COLORS, ROLE_HAND, ROLE_SHOE, SKIN_TONES
from idsplat_ns.data.synthetic.shapes import StreetLayout

_M1, _M2 = np.uint64(0xFF51AFD7ED558CCD), np.uint64(0xC4CEB9FE1A85EC53)
_PRIMES = (np.uint64(0x9E3779B97F4A7C15), np.uint64(0xBF58476D1CE4E5B9), np.uint64(0x94D049BB133111EB))


def hash01(cells: np.ndarray, seed: int) -> np.ndarray:
    """Uniform [0, 1) value per integer cell `cells` [N, k] (k <= 3), deterministic in `seed`."""
    h = np.full(len(cells), np.uint64(seed * 7919 + 12345))
    for k in range(cells.shape[1]):
        h ^= cells[:, k].astype(np.uint64) * _PRIMES[k]
        h ^= h >> np.uint64(31)
        h *= _M1
    h ^= h >> np.uint64(33)
    h *= _M2
    h ^= h >> np.uint64(33)
    return (h >> np.uint64(11)).astype(np.float64) * (1.0 / float(1 << 53))


def value_noise(p: np.ndarray, seed: int) -> np.ndarray:
    """Smooth value noise in [0, 1] at points `p` [N, k], k in {2, 3} (lattice spacing 1)."""
    base = np.floor(p)
    f = p - base
    w = f * f * (3.0 - 2.0 * f)
    base = base.astype(np.int64)
    if p.shape[1] == 2:
        (bx, by), (wx, wy) = base.T, w.T
        h = [hash01(np.stack([bx + i, by + j], 1), seed) for j in (0, 1) for i in (0, 1)]
        lo = h[0] + (h[1] - h[0]) * wx
        hi = h[2] + (h[3] - h[2]) * wx
        return lo + (hi - lo) * wy
    (bx, by, bz), (wx, wy, wz) = base.T, w.T
    h = [hash01(np.stack([bx + i, by + j, bz + k], 1), seed) for k in (0, 1) for j in (0, 1) for i in (0, 1)]
    x00 = h[0] + (h[1] - h[0]) * wx
    x10 = h[2] + (h[3] - h[2]) * wx
    x01 = h[4] + (h[5] - h[4]) * wx
    x11 = h[6] + (h[7] - h[6]) * wx
    y0 = x00 + (x10 - x00) * wy
    y1 = x01 + (x11 - x01) * wy
    return y0 + (y1 - y0) * wz


def fbm(p: np.ndarray, seed: int, octaves: int = 3) -> np.ndarray:
    """Fractal sum of value noise, in [0, 1], at points `p` [N, k]."""
    total, amp, norm = np.zeros(len(p)), 1.0, 0.0
    for octave in range(octaves):
        total += amp * value_noise(p * (2.0**octave), seed + 101 * octave)
        norm += amp
        amp *= 0.5
    return total / norm


def _band(x: np.ndarray, lo: float, hi: float) -> np.ndarray:
    return (x >= lo) & (x <= hi)


@dataclass
class Surface:
    """Texture output for M hits."""

    albedo: np.ndarray  # [M, 3] in [0, 1]
    reflectivity: np.ndarray  # [M] lidar reflectivity 0..255 before the incidence falloff
    glass: np.ndarray  # [M] bool: mirror-like (sky reflection in images, drop-outs in lidar)
    emissive: np.ndarray  # [M] bool: not lit by the sun (lamps)
    retro: np.ndarray  # [M] bool: retro-reflective (plates, signs): no incidence falloff


def _surface(m: int) -> Surface:
    return Surface(np.zeros((m, 3)), np.zeros(m), np.zeros(m, bool), np.zeros(m, bool), np.zeros(m, bool))


def ground(p: np.ndarray, layout: StreetLayout, s: Surface) -> None:
    """Road (asphalt, lane paint, crosswalk), side street and verge, from local positions [M, 3]."""
    x, y = p[:, 0], p[:, 1]
    ay = np.abs(y)
    lane, r = layout.lane_width, layout.road_half_width
    sx, sw = layout.side_street_x, layout.side_street_half_width
    side_street = (np.abs(x - sx) <= sw) & (y > 0)
    road = (ay <= r + 0.01) | side_street
    xy = p[:, :2]
    grain = fbm(xy * 3.0, 11) - 0.5
    patch = fbm(xy * 0.15, 12) - 0.5
    speck = hash01(np.floor(xy * 25).astype(np.int64), 13) > 0.985
    grey = 0.27 + 0.10 * grain + 0.07 * patch + 0.12 * speck
    grey = np.where(ay > 2 * lane, grey + 0.03, grey)  # parking strip: lighter, less worn
    asphalt = grey[:, None] * np.array([1.0, 0.99, 0.96])
    s.albedo[:] = asphalt
    if (~road).any():
        verge_n = fbm(xy[~road] * 0.8, 14)
        s.albedo[~road] = np.stack([0.30 + 0.15 * verge_n, 0.32 + 0.2 * verge_n, 0.16 + 0.06 * verge_n], 1)
    s.reflectivity[:] = np.where(road, 10.0 + 8.0 * grain + 30.0 * speck, 25.0)

    near_junction = np.abs(x - sx) <= sw + 1.0
    white = np.zeros(len(p), bool)
    white |= (np.abs(ay - lane) < 0.075) & (np.mod(x, 9.0) < 3.0)  # dashed lane dividers
    white |= (np.abs(ay - 2 * lane) < 0.075) & ~((y > 0) & near_junction)  # edge lines
    cross_lo = sx + sw + 1.5
    white |= _band(x, cross_lo, cross_lo + 3.0) & (ay < 2 * lane) & (np.mod(y, 1.0) < 0.5)  # crosswalk
    white |= side_street & _band(y, r + 0.6, r + 1.0) & (x < sx)  # stop line
    yellow = (np.abs(ay - 0.15) < 0.06) & ~near_junction  # double centre line
    yellow |= side_street & (np.abs(x - sx) < 0.06) & (y > r + 1.0)
    wear = value_noise(xy * 4.0, 15)
    paint = (white | yellow) & road & (wear > 0.22)
    colour = np.where(yellow[:, None], np.array([0.86, 0.70, 0.18]), np.array([0.88, 0.88, 0.86]))
    mix = (0.75 + 0.25 * wear)[:, None]
    s.albedo[paint] = (colour * mix + s.albedo * (1 - mix))[paint]
    s.reflectivity[paint] = 170.0 + 60.0 * wear[paint]


def sidewalk(p: np.ndarray, n_part: np.ndarray, s: Surface) -> None:
    """Paving slabs on top, curb stone on the sides."""
    xy = p[:, :2]
    slab = np.floor(xy / 1.5).astype(np.int64)
    joint = (np.mod(xy[:, 0], 1.5) < 0.035) | (np.mod(xy[:, 1], 1.5) < 0.035)
    tint = 0.9 + 0.15 * hash01(slab, 21) + 0.12 * (fbm(xy * 4.0, 22) - 0.5)
    top = np.where(joint, 0.42, 0.62 * tint)[:, None] * np.array([1.0, 0.99, 0.96])
    curb = (0.70 + 0.1 * (fbm(p[:, [0, 2]] * 5.0, 23) - 0.5))[:, None] * np.ones(3)
    is_top = n_part[:, 2] > 0.5
    s.albedo[:] = np.where(is_top[:, None], top, curb)
    s.reflectivity[:] = np.where(is_top, 45.0, 60.0)


def building(q: np.ndarray, n_part: np.ndarray, half: np.ndarray, color: np.ndarray, style: np.ndarray, s: Surface) -> None:
    """Facades with window grids, ground-floor shop windows, brick or plaster; dark roofs.

    `q` [M, 3] part-frame points, `half` [M, 3] box half sizes, `color` [M, 3], `style` [M].
    """
    along_x = np.abs(n_part[:, 1]) > 0.5  # face normal along y: the face spans x
    u = np.where(along_x, q[:, 0] + half[:, 0], q[:, 1] + half[:, 1])
    v = q[:, 2] + half[:, 2]  # height above ground
    height = 2 * half[:, 2]
    wall_kind = style % 3
    spacing = 2.4 + 0.2 * ((style // 3) % 5)
    win_w = 1.1 + 0.1 * ((style // 15) % 4)
    floor_h = 3.1 + 0.15 * ((style // 60) % 3)
    ground_h = 4.2

    fu = np.mod(u, spacing)
    fv = np.mod(v - ground_h, floor_h)
    upper = (v > ground_h) & (v < height - 0.9)
    win = upper & _band(fu, (spacing - win_w) / 2, (spacing + win_w) / 2) & _band(fv, 0.9, 2.55)
    frame = win & ~(_band(fu, (spacing - win_w) / 2 + 0.07, (spacing + win_w) / 2 - 0.07) & _band(fv, 0.97, 2.48))
    # Mullion splitting each window in two.
    frame |= win & (np.abs(fu - spacing / 2) < 0.03)
    shop_fu = np.mod(u, 5.0)
    shop = (v > 0.5) & (v < 3.3) & _band(shop_fu, 0.4, 4.2)
    door = (v < 2.5) & _band(shop_fu, 4.35, 4.95)
    shop_frame = shop & ~(_band(shop_fu, 0.48, 4.12) & _band(v, 0.58, 3.22))

    cell = np.stack([np.floor(u / spacing), np.floor((v - ground_h) / floor_h), style], 1).astype(np.int64)
    pane = hash01(cell, 31)
    glass_col = np.stack([0.10 + 0.10 * pane, 0.13 + 0.10 * pane, 0.17 + 0.12 * pane], 1)
    curtain = (pane > 0.72) & (fv > 1.7)
    glass_col = np.where(curtain[:, None], np.array([0.62, 0.56, 0.45]) * (0.8 + 0.3 * pane[:, None]), glass_col)

    noise = fbm(np.stack([u, v], 1) * 1.5, 32) - 0.5
    wall = color * (1.0 + 0.22 * noise)[:, None]
    row = np.floor(v / 0.25)
    mortar = (np.mod(v, 0.25) < 0.03) | (np.mod(u + 0.25 * np.mod(row, 2), 0.5) < 0.03)
    wall = np.where(((wall_kind == 0) & mortar)[:, None], np.array([0.72, 0.70, 0.66]), wall)
    slab_line = (wall_kind == 2) & ((np.mod(v - ground_h, floor_h) < 0.18) | (np.mod(u, 6.0) < 0.05))
    wall = np.where(slab_line[:, None], wall * 0.78, wall)
    wall = np.where((v > height - 0.55)[:, None], wall * 0.8, wall)  # cornice
    wall = np.where((v < ground_h)[:, None] & ~shop[:, None], wall * 0.85, wall)  # darker base

    frame_col = np.where((style % 2 == 0)[:, None], np.array([0.85, 0.84, 0.8]), np.array([0.2, 0.2, 0.21]))
    alb = wall
    is_glass = (win & ~frame) | (shop & ~shop_frame)
    alb = np.where(is_glass[:, None], glass_col, alb)
    alb = np.where((frame | shop_frame)[:, None], frame_col, alb)
    alb = np.where(door[:, None], np.array([0.25, 0.17, 0.12]), alb)
    roof = n_part[:, 2] > 0.5
    roof_col = (0.3 + 0.1 * (fbm(q[:, :2] * 2.0, 33) - 0.5))[:, None] * np.ones(3)
    s.albedo[:] = np.where(roof[:, None], roof_col, alb)
    s.glass[:] = is_glass & ~roof & ~curtain
    s.reflectivity[:] = np.where(s.glass, 8.0, np.where(frame, 70.0, 40.0 + 30.0 * color.mean(1)))


def sign(q: np.ndarray, n_part: np.ndarray, half: np.ndarray, color: np.ndarray, style: np.ndarray, s: Surface) -> None:
    """Sign panels: coloured face with a white border and a white symbol; grey back and edges."""
    a, b = q[:, 1] / half[:, 1], q[:, 2] / half[:, 2]
    border = np.maximum(np.abs(a), np.abs(b)) > 0.84
    rad = np.hypot(a, b)
    symbol = np.where(style == 0, (np.abs(b) < 0.16) & (np.abs(a) < 0.6), _band(rad, 0.4, 0.58))
    face = np.abs(n_part[:, 0]) > 0.5
    alb = np.where((border | symbol)[:, None], np.array([0.92, 0.92, 0.9]), color)
    s.albedo[:] = np.where(face[:, None], alb, np.array([0.5, 0.5, 0.5]))
    s.reflectivity[:] = np.where(face, 235.0, 60.0)
    s.retro[:] = face


def car_body(q: np.ndarray, n_part: np.ndarray, half: np.ndarray, color: np.ndarray, s: Surface) -> None:
    """Painted lower body: door seams, dark sills, head/tail lights, grille, number plates."""
    hx, hy, hz = half[:, 0], half[:, 1], half[:, 2]
    v = q[:, 2] + hz  # height above the body's bottom
    paint = color * (1.0 + 0.08 * (fbm(q * 3.0, 41) - 0.5))[:, None]
    alb = paint.copy()
    refl = 15.0 + 90.0 * color.mean(1)
    retro = np.zeros(len(q), bool)
    side = np.abs(n_part[:, 1]) > 0.5
    front = n_part[:, 0] > 0.5
    back = n_part[:, 0] < -0.5
    sill = v < 0.11
    seams = (np.abs(q[:, 0] + 0.05 * hx) < 0.012) | (np.abs(q[:, 0] - 0.45 * hx) < 0.012)
    handle = _band(v, 0.5 * 2 * hz, 0.58 * 2 * hz) & (
        _band(q[:, 0], 0.2 * hx, 0.3 * hx) | _band(q[:, 0], -0.4 * hx, -0.3 * hx)
    )
    alb = np.where((side & (sill | seams))[:, None], paint * 0.35, alb)
    alb = np.where((side & handle)[:, None], paint * 0.6 + 0.15, alb)
    lamp_y = _band(np.abs(q[:, 1]), hy - 0.42, hy - 0.08)
    lamp_z = v > 0.55 * 2 * hz
    head = front & lamp_y & lamp_z
    tail = back & lamp_y & lamp_z
    grille = front & (np.abs(q[:, 1]) < hy - 0.5) & _band(v, 0.3 * 2 * hz, 0.72 * 2 * hz)
    plate = (front | back) & (np.abs(q[:, 1]) < 0.26) & _band(v, 0.12, 0.25)
    bumper = (front | back) & (v < 0.1)
    alb = np.where(head[:, None], np.array([0.95, 0.95, 0.88]), alb)
    alb = np.where(tail[:, None], np.array([0.72, 0.06, 0.05]), alb)
    alb = np.where(grille[:, None], np.array([0.08, 0.08, 0.09]), alb)
    alb = np.where(bumper[:, None], np.array([0.16, 0.16, 0.17]), alb)
    alb = np.where(plate[:, None], np.array([0.92, 0.92, 0.86]), alb)
    refl = np.where(head | tail, 200.0, refl)
    refl = np.where(plate, 250.0, refl)
    retro |= plate | head | tail
    alb = np.where((n_part[:, 2] < -0.5)[:, None], 0.05, alb)  # underside
    s.albedo[:] = alb
    s.reflectivity[:] = refl
    s.retro[:] = retro


def car_cabin(q: np.ndarray, n_part: np.ndarray, half: np.ndarray, color: np.ndarray, s: Surface) -> None:
    """Glasshouse: windows between pillars on the sides, wind- and rear screens, painted roof."""
    hx, hz = half[:, 0], half[:, 2]
    v = q[:, 2] + hz
    side = np.abs(n_part[:, 1]) > 0.5
    ends = np.abs(n_part[:, 0]) > 0.5
    pillar = (np.abs(q[:, 0]) > hx - 0.1) | (np.abs(q[:, 0] - 0.1 * hx) < 0.06)
    glass = (side & ~pillar & (v > 0.05) & (v < 2 * hz - 0.06)) | (
        ends & (np.abs(q[:, 1]) < half[:, 1] - 0.08) & (v > 0.04) & (v < 2 * hz - 0.06)
    )
    glass_col = np.array([0.06, 0.08, 0.10]) + 0.04 * fbm(q * 2.0, 51)[:, None]
    s.albedo[:] = np.where(glass[:, None], glass_col, color)
    s.glass[:] = glass
    s.reflectivity[:] = np.where(glass, 8.0, 15.0 + 90.0 * color.mean(1))


def bus_body(q: np.ndarray, n_part: np.ndarray, half: np.ndarray, color: np.ndarray, s: Surface) -> None:
    """Bus: window band with pillars, front door, windscreen, destination display, lights."""
    hx, hy, hz = half[:, 0], half[:, 1], half[:, 2]
    v = q[:, 2] + hz
    side = np.abs(n_part[:, 1]) > 0.5
    front = n_part[:, 0] > 0.5
    back = n_part[:, 0] < -0.5
    band = _band(v, 1.0, 2.35)
    win = side & band & (np.mod(q[:, 0], 1.4) > 0.12) & (np.abs(q[:, 0]) < hx - 0.5)
    door = side & (q[:, 1] < 0) & _band(q[:, 0], hx - 2.2, hx - 1.1) & (v < 2.35)
    screen = front & (np.abs(q[:, 1]) < hy - 0.12) & _band(v, 1.0, 2.45)
    display = front & (np.abs(q[:, 1]) < hy - 0.3) & _band(v, 2.5, 2.72)
    rear = back & (np.abs(q[:, 1]) < hy - 0.25) & _band(v, 1.6, 2.4)
    lights = (front | back) & _band(np.abs(q[:, 1]), hy - 0.45, hy - 0.1) & _band(v, 0.35, 0.6)
    stripe = _band(v, 0.45, 0.7)
    alb = color * (1.0 + 0.06 * (fbm(q * 2.0, 61) - 0.5))[:, None]
    alb = np.where(stripe[:, None], np.array([0.85, 0.85, 0.84]), alb)
    glass = win | door | screen | rear
    alb = np.where(glass[:, None], np.array([0.07, 0.09, 0.11]), alb)
    alb = np.where(display[:, None], np.array([0.95, 0.6, 0.1]), alb)
    alb = np.where(lights[:, None], np.where(front[:, None], 0.95, np.array([0.7, 0.06, 0.05])), alb)
    alb = np.where((n_part[:, 2] > 0.5)[:, None], np.array([0.8, 0.8, 0.8]), alb)
    s.albedo[:] = alb
    s.glass[:] = glass
    s.emissive[:] = display
    s.reflectivity[:] = np.where(glass, 8.0, np.where(lights, 200.0, 70.0))
    s.retro[:] = lights


def wheel(q: np.ndarray, n_part: np.ndarray, half: np.ndarray, s: Surface) -> None:
    """Tyre (black) and a spoked alloy rim on the caps."""
    rho = np.hypot(q[:, 0], q[:, 1]) / half[:, 0]
    angle = np.arctan2(q[:, 1], q[:, 0])
    cap = np.abs(n_part[:, 2]) > 0.5
    rim = cap & (rho < 0.64)
    spoke = np.cos(5 * angle) > 0.1
    rim_col = np.where((spoke | (rho < 0.2) | (rho > 0.58))[:, None], np.array([0.58, 0.59, 0.6]), np.array([0.12, 0.12, 0.12]))
    s.albedo[:] = np.where(rim[:, None], rim_col, np.array([0.045, 0.045, 0.05]))
    s.reflectivity[:] = np.where(rim, 50.0, 5.0)


def foliage(p: np.ndarray, color: np.ndarray, style: np.ndarray, s: Surface) -> None:
    """Leafy crown: clumpy 3D noise around the base green."""
    n1 = fbm(p * 2.5 + style[:, None] * 0.01, 71)
    n2 = value_noise(p * 9.0, 72)
    s.albedo[:] = np.clip(color * (0.45 + 0.9 * n1 + 0.3 * (n2 - 0.5))[:, None], 0, 1)
    s.reflectivity[:] = 15.0 + 15.0 * n1


def bark(p: np.ndarray, color: np.ndarray, s: Surface) -> None:
    """Tree trunk: vertical streaks."""
    n = fbm(np.stack([np.arctan2(p[:, 1], p[:, 0]) * 3.0, p[:, 2] * 0.7], 1), 81)
    s.albedo[:] = color * (0.7 + 0.6 * n)[:, None]
    s.reflectivity[:] = 25.0


def pole(p: np.ndarray, color: np.ndarray, s: Surface) -> None:
    """Painted metal with slight grime towards the bottom."""
    grime = np.clip(1.0 - p[:, 2] / 3.0, 0, 1)
    s.albedo[:] = color * (1.0 - 0.25 * grime + 0.06 * (value_noise(p * 4.0, 91) - 0.5))[:, None]
    s.reflectivity[:] = 70.0


def cloth(q: np.ndarray, half: np.ndarray, color: np.ndarray, style: np.ndarray, s: Surface) -> None:
    """Clothes with a woven grain; a lower leg ends in a dark shoe, an arm in a hand (part z runs to the end)."""
    alb = color * (0.9 + 0.2 * fbm(q * 25.0, 111))[:, None]
    end = q[:, 2] > half[:, 2] - 0.075
    shoe = end & ((style & 3) == ROLE_SHOE)
    hand = end & ((style & 3) == ROLE_HAND)
    alb = np.where(shoe[:, None], np.array([0.07, 0.06, 0.06]), alb)
    alb = np.where(hand[:, None], SKIN_TONES[np.clip(style >> 2, 0, len(SKIN_TONES) - 1)], alb)
    s.albedo[:] = alb
    s.reflectivity[:] = np.where(shoe, 10.0, np.where(hand, 35.0, 15.0 + 60.0 * color.mean(1)))


def head(q: np.ndarray, n_part: np.ndarray, color: np.ndarray, style: np.ndarray, s: Surface) -> None:
    """Face in the skin colour, hair on top and at the back (part x is forward)."""
    hair = (n_part[:, 2] > 0.35) | ((n_part[:, 0] < -0.3) & (n_part[:, 2] > -0.45))
    hair_col = HAIR_COLORS[np.clip(style >> 2, 0, len(HAIR_COLORS) - 1)] * (0.85 + 0.3 * fbm(q * 40.0, 121))[:, None]
    s.albedo[:] = np.where(hair[:, None], hair_col, color)
    s.reflectivity[:] = np.where(hair, 15.0, 35.0)


def bike_wheel(q: np.ndarray, n_part: np.ndarray, half: np.ndarray, s: Surface) -> None:
    """Bicycle wheel seen as a disc: black tyre, silver rim, spokes over a dark hub area."""
    rho = np.hypot(q[:, 0], q[:, 1]) / half[:, 0]
    angle = np.arctan2(q[:, 1], q[:, 0])
    cap = np.abs(n_part[:, 2]) > 0.5
    rim = cap & _band(rho, 0.82, 0.9)
    spoke = cap & (rho < 0.82) & ((np.cos(16 * angle) > 0.93) | (rho < 0.12))
    alb = np.where((rim | spoke)[:, None], np.array([0.62, 0.63, 0.65]), np.array([0.16, 0.16, 0.17]))
    tyre = ~cap | (rho >= 0.9)
    s.albedo[:] = np.where(tyre[:, None], np.array([0.04, 0.04, 0.045]), alb)
    s.reflectivity[:] = np.where(rim | spoke, 60.0, np.where(tyre, 6.0, 15.0))


def evaluate(caster, hits, rows: np.ndarray) -> Surface:
    """Texture of hits `rows` [M] of a `RayHits` from `caster` (a `RayCaster`)."""
    s = _surface(len(rows))
    pid = hits.part[rows]
    material = caster.part_material[pid]
    layout = caster.world.layout
    part_size = caster.part_size
    for m in np.unique(material):
        sel = np.flatnonzero(material == m)
        sub = _surface(len(sel))
        r = rows[sel]
        q, n_p, p = hits.point_part[r], hits.normal_part[r], hits.point[r]
        half, color, style = part_size[pid[sel]], caster.part_color[pid[sel]], caster.part_style[pid[sel]]
        if m == mat.GROUND:
            ground(p, layout, sub)
        elif m == mat.SIDEWALK:
            sidewalk(p, n_p, sub)
        elif m == mat.BUILDING:
            building(q, n_p, half, color, style, sub)
        elif m == mat.POLE:
            pole(p, color, sub)
        elif m == mat.LAMP:
            sub.albedo[:] = color
            sub.reflectivity[:] = 120.0
            sub.emissive[:] = True
        elif m == mat.SIGN:
            sign(q, n_p, half, color, style, sub)
        elif m == mat.CAR_BODY:
            car_body(q, n_p, half, color, sub)
        elif m == mat.CAR_CABIN:
            car_cabin(q, n_p, half, color, sub)
        elif m == mat.WHEEL:
            wheel(q, n_p, half, sub)
        elif m == mat.BUS_BODY:
            bus_body(q, n_p, half, color, sub)
        elif m == mat.TRUNK:
            bark(q, color, sub)
        elif m == mat.FOLIAGE:
            foliage(p, color, style, sub)
        elif m == mat.PERSON_CLOTH:
            cloth(q, half, color, style, sub)
        elif m == mat.PERSON_SKIN:
            head(q, n_p, color, style, sub)
        elif m == mat.BIKE_FRAME:
            sub.albedo[:] = color * (0.95 + 0.1 * value_noise(q * 30.0, 131))[:, None]
            sub.reflectivity[:] = 20.0 + 80.0 * color.mean(1)
        elif m == mat.BIKE_WHEEL:
            bike_wheel(q, n_p, half, sub)
        else:
            raise ValueError(f"unknown material {m}")
        s.albedo[sel] = sub.albedo
        s.reflectivity[sel] = sub.reflectivity
        s.glass[sel] = sub.glass
        s.emissive[sel] = sub.emissive
        s.retro[sel] = sub.retro
    np.clip(s.albedo, 0.0, 1.0, out=s.albedo)
    return s
