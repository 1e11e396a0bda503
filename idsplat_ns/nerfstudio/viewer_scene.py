"""What the viewer draws in its 3D scene for an IDSplat model, and where its camera starts.

* Each instance's trajectory: a polyline through its per-step positions (canonical-frame origin,
  i.e. the box centre for annotated tracks) over its valid span, in the instance's palette colour
  (:mod:`idsplat_ns.model.instance_palette`), labelled with its ID. The IDs are the checkpoint's,
  those of ``idsplat-edit --list`` and of ``ns-eval``'s plots and instance renders.
* A marker (a small sphere in the instance colour) and the ID label at each instance's position
  at the render time: they follow the viewer's time slider. An instance that does not exist at
  that time has no marker, and its label waits at the nearest end of its path.
* The start view: behind and above the ego at the first frame, looking along the front camera's
  (horizontal) viewing direction, with that camera's vertical field of view.

Viser's scene is nerfstudio's world scaled by ``VISER_NERFSTUDIO_SCALE_RATIO`` (10); the geometry
functions here work in world metres and the drawing scales.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

import numpy as np
import torch

from idsplat_ns.model.instance_palette import instance_rgb_u8

ROOT = "/idsplat_instances"
LINE_WIDTH = 2.0  # pixels
HIGHLIGHT_LINE_WIDTH = 5.0
MARKER_RADIUS = 0.35  # metres
LABEL_LIFT = 1.2  # metres above the instance centre, so the label does not sit inside the car


@dataclass(frozen=True)
class StartView:
    """A look-at camera in world metres (z up)."""

    position: np.ndarray  # [3]
    look_at: np.ndarray  # [3]
    up: np.ndarray  # [3]
    fov_y: float  # radians, vertical

    def camera_to_world(self) -> np.ndarray:  # -> [4, 4] OpenCV axes (x right, y down, z forward)
        z = self.look_at - self.position
        z = z / np.linalg.norm(z)
        x = np.cross(z, self.up)
        x = x / np.linalg.norm(x)
        out = np.eye(4)
        out[:3, :3] = np.stack([x, np.cross(z, x), z], axis=1)
        out[:3, 3] = self.position
        return out


def front_camera(camera_names: list[str]) -> str:
    """The camera that looks ahead: the first whose name says front and no side, else the first."""
    for name in camera_names:
        low = name.lower()
        if "front" in low and not any(side in low for side in ("left", "right", "side")):
            return name
    return camera_names[0]


def start_view(scene, back: float = 8.0, above: float = 2.5, ahead: float = 12.0) -> Optional[StartView]:
    """Behind the ego at the first frame: ``back`` metres behind and ``above`` metres above the
    front camera's first image, looking at the point ``ahead`` metres in front of it (at its
    height), with its vertical field of view (within 30..100 degrees). None without images."""
    names = [name for name in scene.camera_names if scene.images_of(name)]
    if not names:
        return None
    first = min(scene.images_of(front_camera(names)), key=lambda im: im.time)
    c2w = np.asarray(first.camera_to_world, dtype=np.float64)
    centre = c2w[:3, 3]
    forward = c2w[:3, 2].copy()
    forward[2] = 0.0  # level: a pitched camera still gives a horizontal chase direction
    if np.linalg.norm(forward) < 1e-6:  # a camera looking straight down: use its up-image axis
        forward = -c2w[:3, 1].copy()
        forward[2] = 0.0
    forward /= np.linalg.norm(forward)
    up = np.array([0.0, 0.0, 1.0])
    fov = 2 * np.arctan(0.5 * first.intrinsics.height / first.intrinsics.fy)
    return StartView(centre - back * forward + above * up, centre + ahead * forward, up,
                     float(np.clip(fov, np.radians(30), np.radians(100))))


@torch.no_grad()
def trajectory_polylines(trajectories) -> dict[int, np.ndarray]:
    """``{instance_id: [S, 3]}``: the positions of each instance's steps over its valid span
    (world metres, float64), in time order. Instances without a valid step are left out."""
    positions = trajectories.positions.detach().double().cpu().numpy()  # [Z, F, 3]
    first = trajectories.span_first.cpu().numpy()
    last = trajectories.span_last.cpu().numpy()
    out = {}
    for z, iid in enumerate(trajectories.instance_ids.cpu().tolist()):
        if first[z] >= 0:
            out[int(iid)] = positions[z, first[z] : last[z] + 1]
    return out


@torch.no_grad()
def marker_positions(trajectories, time: float) -> dict[int, tuple[np.ndarray, bool]]:
    """``{instance_id: (position [3], present)}`` at ``time`` (seconds): the pose's position where
    the instance exists, else its position at the nearest end of its span (``present`` False)."""
    times = trajectories.frame_times.double().cpu().numpy()
    first = trajectories.span_first.cpu().numpy()
    last = trajectories.span_last.cpu().numpy()
    present = trajectories.present_at(float(time)).cpu().numpy()
    _, trans, _ = trajectories.poses_at(float(time))
    trans = trans.double().cpu().numpy()  # [Z, 3]
    positions = trajectories.positions.detach().double().cpu().numpy()
    out = {}
    for z, iid in enumerate(trajectories.instance_ids.cpu().tolist()):
        if first[z] < 0:
            continue
        if present[z]:
            out[int(iid)] = (trans[z], True)
        else:  # the end of the span nearest in time
            k = first[z] if time < times[first[z]] else last[z]
            out[int(iid)] = (positions[z, k], False)
    return out


class TrajectoryLayer:
    """The trajectories, labels and markers of one model in a viser scene."""

    def __init__(self, scene_api, scale: float) -> None:
        self.scene_api = scene_api  # viser's server.scene
        self.scale = scale
        self.labels: dict[int, object] = {}
        self.markers: dict[int, object] = {}
        self.paths: dict[int, object] = {}
        self.visible = True
        self._time: Optional[float] = None

    def draw(self, trajectories, highlight: Optional[int] = None) -> None:
        """(Re)draw every path from the trajectories' current values."""
        self.clear()
        for iid, points in trajectory_polylines(trajectories).items():
            name = f"{ROOT}/id_{iid:04d}"
            colour = instance_rgb_u8(iid)
            if len(points) >= 2:
                # segments = steps - 1: the drawn curve is sampled at the steps only, a polyline.
                self.paths[iid] = self.scene_api.add_spline_catmull_rom(
                    f"{name}/path", points * self.scale, curve_type="catmullrom", tension=0.0,
                    line_width=HIGHLIGHT_LINE_WIDTH if iid == highlight else LINE_WIDTH, color=colour,
                    segments=len(points) - 1, visible=self.visible)
            self.markers[iid] = self.scene_api.add_icosphere(
                f"{name}/marker", radius=MARKER_RADIUS * self.scale, color=colour,
                position=points[0] * self.scale, visible=False)
            self.labels[iid] = self.scene_api.add_label(
                f"{name}/label", f"ID {iid}", position=(points[0] + [0, 0, LABEL_LIFT]) * self.scale,
                visible=self.visible)
        self._time = None

    def move_to_time(self, trajectories, time: float, hidden: frozenset[int] = frozenset()) -> None:
        """Put markers and labels where the instances are at ``time``; hidden instances get no marker."""
        if self._time == time or not self.labels:
            return
        self._time = time
        for iid, (position, present) in marker_positions(trajectories, time).items():
            if iid in self.labels:
                self.labels[iid].position = (position + [0, 0, LABEL_LIFT]) * self.scale
                self.markers[iid].position = position * self.scale
                self.markers[iid].visible = self.visible and present and iid not in hidden

    def forget_time(self) -> None:
        """Place the markers again at the next render, even at the same time."""
        self._time = None

    def set_visible(self, visible: bool) -> None:
        self.visible = visible
        for handles in (self.paths, self.labels):
            for handle in handles.values():
                handle.visible = visible
        if not visible:
            for handle in self.markers.values():
                handle.visible = False
        self._time = None  # the next render time puts the markers back

    def clear(self) -> None:
        for handles in (self.paths, self.labels, self.markers):
            for handle in handles.values():
                handle.remove()
            handles.clear()
