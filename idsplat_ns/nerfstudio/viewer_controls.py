"""The IDSplat panel of nerfstudio's viewer: show, hide, isolate and highlight instances, their
trajectories in the 3D scene, the start view behind the ego, and saving what is hidden as an
edited run (like ``idsplat-edit --remove``).

nerfstudio (1.1.5) collects the :class:`ViewerControl` objects of a model and calls ``_setup``
with the viewer once it runs (``ns-viewer`` and ``ns-train --vis viewer`` alike); the panel is
built there, with nerfstudio's viewer elements, as a folder above the Control/Render/Export tabs.
What the panel changes applies only to renders of the viewer's own render threads: training
steps and the evaluation images of a run being trained never see a hidden instance.

The maths is elsewhere: hiding in :mod:`idsplat_ns.model.instance_visibility`, colours in
:mod:`idsplat_ns.model.instance_palette`, drawing and the start view in
:mod:`idsplat_ns.nerfstudio.viewer_scene`, the edit itself in :mod:`idsplat_ns.model.editing`.
"""

from __future__ import annotations

import argparse
import contextlib
import threading
from pathlib import Path
from typing import TYPE_CHECKING, Dict, List, Optional

import torch
from nerfstudio.viewer.render_state_machine import RenderStateMachine
from nerfstudio.viewer.viewer_elements import ViewerButton, ViewerCheckbox, ViewerControl, ViewerDropdown, ViewerText
from torch import Tensor

from idsplat_ns.errors import IDSplatError
from idsplat_ns.model.editing import EditError, SceneTensors
from idsplat_ns.model.instance_visibility import highlight
from idsplat_ns.runs.run_folder import SCENE_PREFIX, TrainedRun, read_run_config, write_run
from idsplat_ns.nerfstudio.viewer_scene import StartView, TrajectoryLayer
from idsplat_ns.runs.checkpoints import latest_complete
from idsplat_ns.runs.edits import apply_edits

if TYPE_CHECKING:
    from nerfstudio.viewer.viewer import Viewer

STATIC_ID = 0


def in_viewer_render() -> bool:
    """Whether the caller runs in one of the viewer's render threads (one per browser)."""
    return isinstance(threading.current_thread(), RenderStateMachine)


def config_candidates(viewer: Viewer) -> List[Path]:
    """Where the viewed run's config.yml can be: the trainer's run folder when training; else
    beside the viewer's log (a trained run), or two folders above it (a run that
    ``idsplat-edit`` wrote keeps its log in ``DIR/<experiment>/<method>``)."""
    trainer = getattr(viewer, "trainer", None)
    if trainer is not None:
        return [Path(trainer.base_dir) / "config.yml"]
    log = Path(viewer.log_filename)
    return [log.parent / "config.yml", log.parent.parent.parent / "config.yml"]


def read_config(config_path: str | Path):
    """The TrainerConfig of a run's config.yml (:func:`~idsplat_ns.runs.run_folder.read_run_config`);
    one line naming the file when it cannot be read."""
    path = Path(str(config_path).strip()).expanduser()
    if not str(config_path).strip() or not path.is_file():
        raise IDSplatError(f"Save edits: Run config {str(config_path)!r} is not a file; give the config.yml of the run in the viewer")
    try:
        return read_run_config(path)
    except IDSplatError as err:
        raise IDSplatError(f"Save edits: {err}") from None


def save_hidden_as_run(config_path: str | Path, pipeline_state: Dict[str, Tensor], step: int, hidden: frozenset,
                       out_dir: str | Path, config=None) -> tuple[Path, List[str]]:
    """Write ``pipeline_state`` (the live pipeline's, at ``step``) with the hidden instances removed
    as a new run in ``out_dir``, as ``idsplat-edit --remove`` does. ``config``: the run's
    TrainerConfig when at hand (a run being trained), else read from ``config_path``. No
    checkpoint file is needed: a run being trained may have none yet. The static background is
    always kept. Returns the new config.yml and the edit lines."""
    removed = sorted(int(i) for i in hidden if int(i) != STATIC_ID)
    if not removed:
        raise IDSplatError("Save edits: no instance is hidden; untick the instances to remove first")
    if not str(out_dir).strip():
        raise IDSplatError("Save edits: Output folder is empty; give a new folder")
    config = read_config(config_path) if config is None else config
    config_path = Path(str(config_path).strip()).expanduser()
    try:
        scene = SceneTensors.from_state_dict(pipeline_state, SCENE_PREFIX)
    except EditError as err:
        raise IDSplatError(f"Save edits: {err}") from None
    args = argparse.Namespace(load_config=config_path, remove=removed, retime=[], move=[], duplicate=[],
                              frame="instance")
    done = apply_edits(scene, args)
    state = scene.to_state_dict(pipeline_state, SCENE_PREFIX)
    checkpoint = latest_complete(Path(config.get_checkpoint_dir()))
    # write_run records the run's checkpoint; the note says what was saved: the live model.
    run = TrainedRun(config_path, config, checkpoint or config_path, {"step": int(step), "pipeline": state})
    note = {"source_checkpoint": None if checkpoint is None else str(checkpoint.resolve()),
            "saved_from": f"the viewer's live model at step {int(step)}", "edits": done}
    written = write_run(run, state, Path(str(out_dir).strip()).expanduser(), note)
    return written, done


class InstanceControls(ViewerControl):
    """Instance visibility, highlight, trajectories, start view and saving, for one model."""

    def __init__(self, model, start: Optional[StartView]) -> None:
        self.model = model
        self.start = start
        self.hidden: frozenset = frozenset()  # IDs not rendered (0: the static background)
        self.highlighted: Optional[int] = None
        self.layer: Optional[TrajectoryLayer] = None
        self.boxes: Dict[int, ViewerCheckbox] = {}

    # -- what the model asks during a render ---------------------------------------------------

    def hidden_now(self) -> frozenset:
        """The IDs to leave out of the current render: the panel's, in a viewer render only."""
        return self.hidden if self.hidden and in_viewer_render() else frozenset()

    def after_render(self, outputs: Dict[str, Tensor], time: Optional[float]) -> Dict[str, Tensor]:
        """Highlight the selected instance and move the markers to the render time."""
        if self.highlighted is not None and "instance_id" in outputs:
            outputs["rgb"] = highlight(outputs["rgb"], outputs["instance_id"], self.highlighted)
        trajectories = self.model.scene_model.trajectories
        if self.layer is not None and trajectories is not None and time is not None:
            self.layer.move_to_time(trajectories, float(time), self.hidden)
        return outputs

    # -- the panel -------------------------------------------------------------------------------

    def _setup(self, viewer: Viewer) -> None:
        super()._setup(viewer)
        from nerfstudio.viewer.viewer import VISER_NERFSTUDIO_SCALE_RATIO

        self.scale = VISER_NERFSTUDIO_SCALE_RATIO
        server = self.viser_server
        if self.start is not None:
            server.on_client_connect(self._go_to_start)
        trajectories = self.model.scene_model.trajectories
        ids = [] if trajectories is None else sorted(int(i) for i in trajectories.instance_ids.tolist())
        # Above the tabs, below the step/resolution lines: the panel of this method.
        with server.gui.add_folder("IDSplat instances", order=viewer.stats_markdown.order + 0.5):
            if not ids:
                server.gui.add_markdown("This model has no instances (a static scene).")
                return
            server.gui.add_markdown(f"{len(ids)} instances; IDs as in `idsplat-edit --list`. "
                                    "The Time slider (Control tab) moves them.")
            self.static_box = self._install(ViewerCheckbox(
                "Static background", True, cb_hook=lambda _: self._visibility_changed(),
                hint="Render the static scene (ID 0)"))
            self.selected = self._install(ViewerDropdown(
                "Instance", str(ids[0]), [str(i) for i in ids], cb_hook=lambda _: self._highlight_changed(),
                hint="The instance that Isolate and Highlight act on"))
            self._install(ViewerButton("Isolate", cb_hook=lambda _: self._isolate()))
            self._install(ViewerButton("Show all", cb_hook=lambda _: self._show_all()))
            self.highlight_box = self._install(ViewerCheckbox(
                "Highlight", False, cb_hook=lambda _: self._highlight_changed(),
                hint="Tint the selected instance in its colour and thicken its path"))
            self.paths_box = self._install(ViewerCheckbox(
                "Trajectories", True, cb_hook=lambda _: self._paths_changed(),
                hint="Draw paths, IDs and markers; ticking it again re-reads the paths (they change while training)"))
            with server.gui.add_folder("Show", expand_by_default=len(ids) <= 12):
                hints = self._instance_hints(trajectories)
                for iid in ids:
                    self.boxes[iid] = self._install(ViewerCheckbox(
                        f"ID {iid}", True, cb_hook=lambda _: self._visibility_changed(), hint=hints[iid]))
            with server.gui.add_folder("Save edits", expand_by_default=False):
                found = next((p for p in config_candidates(viewer) if p.is_file()), None)
                self.config_text = self._install(ViewerText(
                    "Run config", str(found or ""), hint="config.yml of the run in the viewer"))
                default_out = "" if found is None else str(found.parent.with_name(found.parent.name + "_viewer_edit"))
                self.out_text = self._install(ViewerText(
                    "Output folder", default_out, hint="A new folder for the edited run (config.yml + checkpoint)"))
                self._install(ViewerButton("Save edits", cb_hook=lambda _: self._save()))
                self.status = server.gui.add_markdown("Hidden instances are removed; the static scene is kept.")
        self.layer = TrajectoryLayer(server.scene, self.scale)
        with self._lock():
            self.layer.draw(trajectories)

    def _install(self, element):
        element.install(self.viser_server)
        return element

    def _lock(self):
        lock = getattr(self.viewer, "train_lock", None)
        return lock if lock is not None else contextlib.nullcontext()

    @staticmethod
    def _instance_hints(trajectories) -> Dict[int, str]:
        times = trajectories.frame_times.double().cpu()
        out = {}
        for z, iid in enumerate(trajectories.instance_ids.tolist()):
            first, last = int(trajectories.span_first[z]), int(trajectories.span_last[z])
            span = "no valid step" if first < 0 else f"present {float(times[first]):.2f}-{float(times[last]):.2f} s"
            out[int(iid)] = f"Render instance {iid} ({span})"
        return out

    def _go_to_start(self, client) -> None:
        v = self.start
        with client.atomic():
            client.camera.fov = v.fov_y
            client.camera.up_direction = tuple(v.up)
            client.camera.position = tuple(v.position * self.scale)
            client.camera.look_at = tuple(v.look_at * self.scale)

    def _rerender(self) -> None:
        self.viewer._trigger_rerender()

    def _visibility_changed(self) -> None:
        hidden = {iid for iid, box in self.boxes.items() if not box.value}
        if not self.static_box.value:
            hidden.add(STATIC_ID)
        if frozenset(hidden) != self.hidden:
            self.hidden = frozenset(hidden)
            if self.layer is not None:
                self.layer.forget_time()  # hidden instances lose their markers at the next render
            self._rerender()

    def _set_shown(self, shown: set, static: bool) -> None:
        for iid, box in self.boxes.items():
            if box.value != (iid in shown):
                box.value = iid in shown
        if self.static_box.value != static:
            self.static_box.value = static
        self._visibility_changed()

    def _isolate(self) -> None:
        """Only the selected instance: every other instance and the static background hidden."""
        self._set_shown({int(self.selected.value)}, static=False)

    def _show_all(self) -> None:
        self._set_shown(set(self.boxes), static=True)

    def _highlight_changed(self) -> None:
        target = int(self.selected.value) if self.highlight_box.value else None
        if target != self.highlighted:
            self.highlighted = target
            if self.paths_box.value:
                self._redraw()
            self._rerender()

    def _paths_changed(self) -> None:
        if self.paths_box.value:
            self._redraw()
        self.layer.set_visible(self.paths_box.value)
        self._rerender()

    def _redraw(self) -> None:
        with self._lock():
            self.layer.draw(self.model.scene_model.trajectories, self.highlighted)

    def _save(self) -> None:
        self.status.content = "Saving..."
        try:
            with self._lock(), torch.no_grad():
                state = {k: v.detach().cpu().clone() for k, v in self.viewer.pipeline.state_dict().items()}
            trainer = getattr(self.viewer, "trainer", None)
            written, done = save_hidden_as_run(self.config_text.value, state, int(self.viewer.step), self.hidden,
                                               self.out_text.value, None if trainer is None else trainer.config)
        except IDSplatError as err:
            self.status.content = f"**Not saved:** {err}"
            return
        self.status.content = f"Saved ({'; '.join(done)}): `{written}`"
