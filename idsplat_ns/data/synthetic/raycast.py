"""Vectorised ray casting against the analytic parts of a `World` (numpy, no per-ray loops).

Rays carry their own time, so a lidar ray fired late in a sweep meets a moving car where the car
is at that instant, and a walker's leg where it has swung to. Objects are culled per chunk of rays
with a cone test against each object's bounding sphere (one matrix product), then only candidate
rays are tested exactly.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from idsplat_ns.data.synthetic.trajectories import Stationary
from idsplat_ns.data.synthetic.shapes import BOX, CYLINDER, ELLIPSOID, yaw_matrix
from idsplat_ns.data.synthetic.world import World

EPS = 1e-6
"""Smallest accepted hit distance (rays start on the sensor, never on a surface)."""


def intersect_box(o: np.ndarray, d: np.ndarray, half: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """First hit of rays `o + t d` (o, d: [N, 3], part frame) with the box [-half, half].

    Returns the distance t [N] (inf where missed) and the outward face normal [N, 3].
    """
    d_safe = np.where(np.abs(d) < 1e-12, 1e-12, d)
    inv = 1.0 / d_safe
    t1 = (-half - o) * inv
    t2 = (half - o) * inv
    t_lo = np.minimum(t1, t2)
    t_hi = np.maximum(t1, t2)
    # Explicit per-axis max/min: much faster than reductions over an axis of length 3.
    t_near = np.maximum(np.maximum(t_lo[:, 0], t_lo[:, 1]), t_lo[:, 2])
    t_far = np.minimum(np.minimum(t_hi[:, 0], t_hi[:, 1]), t_hi[:, 2])
    hit = (t_near <= t_far) & (t_near > EPS)
    axis = np.where(t_lo[:, 0] == t_near, 0, np.where(t_lo[:, 1] == t_near, 1, 2))
    normal = np.zeros_like(o)
    rows = np.arange(len(o))
    normal[rows, axis] = -np.sign(d_safe[rows, axis])
    return np.where(hit, t_near, np.inf), normal


def intersect_cylinder(o: np.ndarray, d: np.ndarray, radius, half_height) -> tuple[np.ndarray, np.ndarray]:
    """First hit of rays (part frame, [N, 3]) with the closed cylinder x^2 + y^2 <= r^2, |z| <= h.

    `radius` and `half_height` are scalars or per-ray arrays [N].
    """
    a = d[:, 0] ** 2 + d[:, 1] ** 2
    b = o[:, 0] * d[:, 0] + o[:, 1] * d[:, 1]
    c = o[:, 0] ** 2 + o[:, 1] ** 2 - radius**2
    disc = b * b - a * c
    with np.errstate(invalid="ignore", divide="ignore"):
        t_side = (-b - np.sqrt(disc)) / a
    z_side = o[:, 2] + t_side * d[:, 2]
    side_ok = (disc >= 0) & (a > 1e-12) & (t_side > EPS) & (np.abs(z_side) <= half_height)
    t_side = np.where(side_ok, t_side, np.inf)
    # The cap facing the ray: top for downward rays, bottom for upward ones.
    cap_z = np.where(d[:, 2] < 0, half_height, -half_height)
    dz = np.where(np.abs(d[:, 2]) < 1e-12, 1e-12, d[:, 2])
    t_cap = (cap_z - o[:, 2]) / dz
    px = o[:, 0] + t_cap * d[:, 0]
    py = o[:, 1] + t_cap * d[:, 1]
    cap_ok = (t_cap > EPS) & (px * px + py * py <= radius**2)
    t_cap = np.where(cap_ok, t_cap, np.inf)
    t = np.minimum(t_side, t_cap)
    p = o + np.where(np.isfinite(t), t, 0.0)[:, None] * d
    side_normal = np.stack([p[:, 0], p[:, 1], np.zeros_like(t)], 1) / np.reshape(radius, (-1, 1))
    cap_normal = np.zeros_like(o)
    cap_normal[:, 2] = np.sign(cap_z)
    normal = np.where((t_side <= t_cap)[:, None], side_normal, cap_normal)
    return t, normal


def intersect_ellipsoid(o: np.ndarray, d: np.ndarray, radii: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """First hit of rays (part frame, [N, 3]) with the axis-aligned ellipsoid of `radii` [3]."""
    os_, ds = o / radii, d / radii  # unit sphere space; t is unchanged by the scaling
    a = (ds * ds).sum(1)
    b = (os_ * ds).sum(1)
    c = (os_ * os_).sum(1) - 1.0
    disc = b * b - a * c
    with np.errstate(invalid="ignore"):
        t = (-b - np.sqrt(disc)) / a
    ok = (disc >= 0) & (t > EPS)
    t = np.where(ok, t, np.inf)
    q = os_ + np.where(ok, t, 0.0)[:, None] * ds
    normal = q / radii
    normal /= np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-12)
    return t, normal


@dataclass
class RayHits:
    """What each ray hit first (local street frame)."""

    distance: np.ndarray  # [N] float64, inf where nothing was hit
    part: np.ndarray  # [N] int64 index into `World.flat_parts`, -1 where nothing was hit
    obj: np.ndarray  # [N] int64 index into `World.objects`, -1 where nothing was hit
    point: np.ndarray  # [N, 3] hit point, local street frame (0 where missed)
    normal: np.ndarray  # [N, 3] unit surface normal, local street frame
    point_part: np.ndarray  # [N, 3] hit point in the part's own frame (texture coordinates)
    normal_part: np.ndarray  # [N, 3] normal in the part's frame

    @staticmethod
    def empty(n: int) -> "RayHits":
        """N rays that hit nothing (yet)."""
        return RayHits(
            distance=np.full(n, np.inf),
            part=np.full(n, -1, dtype=np.int64),
            obj=np.full(n, -1, dtype=np.int64),
            point=np.zeros((n, 3)),
            normal=np.zeros((n, 3)),
            point_part=np.zeros((n, 3)),
            normal_part=np.zeros((n, 3)),
        )

    @property
    def hit(self) -> np.ndarray:
        """[N] bool, True where a surface was hit."""
        return self.part >= 0


@dataclass
class _StaticParts:
    """Parts of one kind that never move, with their street-frame placement (batched tests)."""

    pid: np.ndarray  # [P] index into RayCaster.parts
    centre: np.ndarray  # [P, 3] street frame
    rotation: np.ndarray  # [P, 3, 3] street-from-part
    size: np.ndarray  # [P, 3]
    aligned: bool  # every rotation is the identity (no transform needed)


def _intersect(kind: int, o: np.ndarray, d: np.ndarray, size: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Dispatch to the intersection of `kind`; `size` [3] or [N, 3] as in `Part.size`."""
    if kind == BOX:
        return intersect_box(o, d, size)
    if kind == CYLINDER:
        return intersect_cylinder(o, d, size[..., 0], size[..., 2])
    if kind == ELLIPSOID:
        return intersect_ellipsoid(o, d, size)
    raise ValueError(f"unknown part kind {kind}")


class RayCaster:
    """Casts rays against a world.

    Static parts (the street and parked cars) are placed in the street frame once and tested in
    batches per kind, culled per part; moving vehicles are culled per object and tested in their
    own frame at each ray's time.
    """

    def __init__(self, world: World, chunk_size: int = 32768):
        self.world = world
        self.chunk_size = chunk_size
        self.parts = []
        self.part_object: list[int] = []
        self.object_parts: list[list[int]] = []
        for oi, obj in enumerate(world.objects):
            ids = []
            for part in obj.parts:
                ids.append(len(self.parts))
                self.parts.append(part)
                self.part_object.append(oi)
            self.object_parts.append(ids)
        self.part_material = np.array([p.material for p in self.parts])
        self.part_color = np.array([p.color for p in self.parts])
        self.part_style = np.array([p.style for p in self.parts])
        self.part_size = np.array([p.size for p in self.parts])
        self.part_rotation = np.array([p.rotation for p in self.parts])  # object-from-part
        self.part_object_arr = np.array(self.part_object)
        self.instance_of_object = np.array([o.instance_id for o in world.objects])

        # Street-from-part rotation of every static part (identity for moving ones: unused).
        self.part_street_rotation = np.tile(np.eye(3), (len(self.parts), 1, 1))
        groups: dict[tuple[int, bool], list[tuple[int, np.ndarray, np.ndarray]]] = {}
        self.dynamic: list[int] = []
        for oi, obj in enumerate(world.objects):
            if oi == 0:
                continue
            if obj.trajectory is not None and (not isinstance(obj.trajectory, Stationary) or obj.articulated):
                self.dynamic.append(oi)
                continue
            if obj.trajectory is None:
                obj_rot, obj_pos = np.eye(3), np.zeros(3)
            else:
                heading, pos = self.object_pose(oi, np.zeros(1))
                obj_rot, obj_pos = yaw_matrix(heading)[0], pos[0]
            for pid in self.object_parts[oi]:
                part = self.parts[pid]
                rot = obj_rot @ part.rotation
                self.part_street_rotation[pid] = rot
                aligned = bool(np.allclose(rot, np.eye(3)))
                groups.setdefault((part.kind, aligned), []).append((pid, obj_pos + obj_rot @ part.center, rot))
        self.static = [
            _StaticParts(
                pid=np.array([g[0] for g in items]),
                centre=np.array([g[1] for g in items]),
                rotation=np.array([g[2] for g in items]),
                size=self.part_size[[g[0] for g in items]],
                aligned=aligned,
            )
            for (kind, aligned), items in sorted(groups.items())
        ]
        self.static_kind = [kind for (kind, _aligned) in sorted(groups)]
        spheres = [world.objects[oi].bounding_sphere() for oi in self.dynamic]
        self.dyn_centre = np.array([c for c, _ in spheres]).reshape(-1, 3)  # object frame
        self.dyn_radius = np.array([r for _, r in spheres])

    # -- object poses ---------------------------------------------------------------------------
    def object_pose(self, oi: int, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Heading [N] and position [N, 3] of object `oi` at times `t` [N] (identity if static)."""
        traj = self.world.objects[oi].trajectory
        if traj is None:
            return np.zeros(len(t)), np.zeros((len(t), 3))
        xy, heading = traj.pose(t)
        return heading, np.concatenate([xy, traj.height(t)[:, None]], 1)

    def _dynamic_bounds(self, t_lo: float, t_hi: float) -> tuple[np.ndarray, np.ndarray]:
        """Street-frame spheres [D, 3], [D] holding each moving object over [t_lo, t_hi]."""
        centres = np.zeros((len(self.dynamic), 3))
        radii = self.dyn_radius.copy()
        times = np.array([t_lo, 0.5 * (t_lo + t_hi), t_hi])
        for g, oi in enumerate(self.dynamic):
            heading, pos = self.object_pose(oi, times)
            c = pos + np.einsum("nij,j->ni", yaw_matrix(heading), self.dyn_centre[g])
            # Mid-time centre; radius grows by how far the centre travels (plus slack for curvature).
            centres[g] = c[1]
            radii[g] += 1.25 * np.linalg.norm(c - c[1], axis=1).max() + 0.05
        return centres, radii

    # -- casting ---------------------------------------------------------------------------------
    def cast(self, origins: np.ndarray, directions: np.ndarray, times: np.ndarray) -> RayHits:
        """First hits of rays `origins + s * directions` ([N, 3], unit directions) at times [N]."""
        out = RayHits.empty(len(origins))
        for start in range(0, len(origins), self.chunk_size):
            sl = slice(start, min(len(origins), start + self.chunk_size))
            o, d, t = origins[sl], directions[sl], times[sl]
            self._cast_chunk(o, d, t, out, sl, lambda c, r, o=o, d=d: _cone_candidates(o, d, c, r))
        self._finish(out, origins, directions, times)
        return out

    def occluded(self, origins: np.ndarray, direction: np.ndarray, times: np.ndarray) -> np.ndarray:
        """[N] bool: whether rays from `origins` [N, 3] along one `direction` [3] (the sun) hit anything."""
        out = RayHits.empty(len(origins))
        directions = np.broadcast_to(direction, origins.shape)
        for start in range(0, len(origins), self.chunk_size):
            sl = slice(start, min(len(origins), start + self.chunk_size))
            o, t = origins[sl], times[sl]
            self._cast_chunk(
                o, directions[sl], t, out, sl, lambda c, r, o=o: _parallel_candidates(o, direction, c, r)
            )
        return out.part >= 0

    def _cast_chunk(self, o: np.ndarray, d: np.ndarray, t: np.ndarray, out: RayHits, sl: slice, candidates) -> None:
        """Nearest hits of one chunk into `out[sl]`.

        `candidates(centres [G, 3], radii [G]) -> [G, N] bool` marks the rays that may meet each sphere.
        """
        best = out.distance[sl]
        part = out.part[sl]
        point_part = out.point_part[sl]
        normal_part = out.normal_part[sl]

        def update(idx, dist, pid, o_p, d_p, n_p):
            """Keep hits (rows `idx` [M], distances [M], part ids scalar or [M]) nearer than the best."""
            better = dist < best[idx]
            if not better.any():
                return
            rows = idx[better]
            best[rows] = dist[better]
            part[rows] = pid if np.isscalar(pid) else pid[better]
            point_part[rows] = o_p[better] + dist[better, None] * d_p[better]
            normal_part[rows] = n_p[better]

        # Ground plane z = 0 (part 0): every downward ray.
        with np.errstate(divide="ignore"):
            tg = np.where(d[:, 2] < -1e-9, -o[:, 2] / d[:, 2], np.inf)
        update(np.arange(len(o)), tg, 0, o, d, np.broadcast_to(np.array([0.0, 0.0, 1.0]), o.shape))

        # Static parts: all (part, ray) candidate pairs of one kind in one vectorised test.
        for kind, tab in zip(self.static_kind, self.static):
            pi, ri = np.nonzero(candidates(tab.centre, np.linalg.norm(tab.size, axis=1)))
            if len(ri) == 0:
                continue
            o_p, d_p = o[ri] - tab.centre[pi], d[ri]
            if not tab.aligned:
                rot = tab.rotation[pi]
                o_p = np.einsum("mji,mj->mi", rot, o_p)
                d_p = np.einsum("mji,mj->mi", rot, d_p)
            dist, n_p = _intersect(kind, o_p, d_p, tab.size[pi])
            ok = np.flatnonzero(np.isfinite(dist))
            if len(ok) == 0:
                continue
            # Nearest pair per ray: sort by (ray, distance) and keep each ray's first.
            ok = ok[np.lexsort((dist[ok], ri[ok]))]
            first = ok[np.r_[True, ri[ok][1:] != ri[ok][:-1]]]
            update(ri[first], dist[first], tab.pid[pi[first]], o_p[first], d_p[first], n_p[first])

        # Moving vehicles: per object, rays moved into the object's frame at their own time.
        if not self.dynamic:
            return
        centres, radii = self._dynamic_bounds(float(t.min()), float(t.max()))
        cand = candidates(centres, radii)
        for g, oi in enumerate(self.dynamic):
            idx = np.flatnonzero(cand[g])
            if len(idx) == 0:
                continue
            heading, pos = self.object_pose(oi, t[idx])
            rot_t = yaw_matrix(heading)  # object-to-street
            o_g = np.einsum("nji,nj->ni", rot_t, o[idx] - pos)
            d_g = np.einsum("nji,nj->ni", rot_t, d[idx])
            for pid in self.object_parts[oi]:
                p = self.parts[pid]
                if p.motion is None:
                    o_p = (o_g - p.center) @ p.rotation
                    d_p = d_g @ p.rotation
                else:  # a limb, crank or wheel: its pose in the object at each ray's time
                    centre, rot = p.motion.pose(t[idx])
                    o_p = np.einsum("nji,nj->ni", rot, o_g - centre)
                    d_p = np.einsum("nji,nj->ni", rot, d_g)
                dist, n_p = _intersect(p.kind, o_p, d_p, p.size)
                update(idx, dist, pid, o_p, d_p, n_p)

    def _finish(self, out: RayHits, o: np.ndarray, d: np.ndarray, t: np.ndarray) -> None:
        """Fill object ids, street-frame points and normals of the hits."""
        hit = out.part >= 0
        out.obj[hit] = self.part_object_arr[out.part[hit]]
        dist = np.where(hit, out.distance, 0.0)
        out.point[:] = o + dist[:, None] * d
        pid = np.maximum(out.part, 0)
        # Static parts (and the ground, whose rotation is the identity): one batched rotation.
        out.normal[:] = np.einsum("nij,nj->ni", self.part_street_rotation[pid], out.normal_part)
        for oi in self.dynamic:
            rows = np.flatnonzero(out.obj == oi)
            if len(rows) == 0:
                continue
            n_obj = np.einsum("nij,nj->ni", self.part_rotation[out.part[rows]], out.normal_part[rows])
            for pid in self.object_parts[oi]:  # parts that move in the object: their rotation at each time
                motion = self.parts[pid].motion
                sub = np.flatnonzero(out.part[rows] == pid) if motion is not None else np.zeros(0, int)
                if len(sub):
                    _, rot = motion.pose(t[rows[sub]])
                    n_obj[sub] = np.einsum("nij,nj->ni", rot, out.normal_part[rows[sub]])
            heading, _ = self.object_pose(oi, t[rows])
            out.normal[rows] = np.einsum("nij,nj->ni", yaw_matrix(heading), n_obj)


def _cone_candidates(o: np.ndarray, d: np.ndarray, centres: np.ndarray, radii: np.ndarray) -> np.ndarray:
    """[G, N] bool: rays (origins `o` [N, 3] close together, directions `d` [N, 3]) that may meet spheres."""
    o_ref = o.mean(0)
    spread = np.linalg.norm(o - o_ref, axis=1).max()
    to_c = centres - o_ref
    dist_c = np.linalg.norm(to_c, axis=1)
    reach = radii + spread  # conservative for every origin within `spread` of o_ref
    axis = to_c / np.maximum(dist_c, 1e-9)[:, None]
    cos_lim = np.sqrt(np.clip(1.0 - (reach / np.maximum(dist_c, 1e-9)) ** 2, 0.0, 1.0))
    cand = (axis.astype(np.float32) @ d.T.astype(np.float32)) >= (cos_lim - 1e-3).astype(np.float32)[:, None]
    cand[dist_c <= reach] = True
    return cand


def _parallel_candidates(o: np.ndarray, direction: np.ndarray, centres: np.ndarray, radii: np.ndarray) -> np.ndarray:
    """[G, N] bool: parallel rays (any origins `o` [N, 3], one `direction` [3]) that may meet spheres."""
    e1 = np.cross(direction, [0.0, 0.0, 1.0] if abs(direction[2]) < 0.9 else [1.0, 0.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(direction, e1)
    basis = np.stack([e1, e2], 1)  # [3, 2]: coordinates across the ray direction
    # Distances in float32 after removing the mean (local coordinates are small).
    ref = o.mean(0)
    u = ((o - ref) @ basis).astype(np.float32)
    c = ((centres - ref) @ basis).astype(np.float32)
    dist2 = (c * c).sum(1)[:, None] + (u * u).sum(1)[None, :] - 2.0 * (c @ u.T)
    reach = (radii + 0.01).astype(np.float32)
    along = ((o - ref) @ direction).astype(np.float32)
    ahead = ((centres - ref) @ direction).astype(np.float32)[:, None] - along[None, :] >= -reach[:, None]
    return (dist2 <= (reach**2)[:, None]) & ahead
