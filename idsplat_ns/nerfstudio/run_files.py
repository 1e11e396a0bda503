"""Read a trained run (config.yml + latest checkpoint) without building its pipeline, and write a
derived run (an edited scene) in nerfstudio's layout, ``DIR/config.yml`` and
``DIR/nerfstudio_models/step-XXXXXXXXX.ckpt``, that ``ns-eval``, ``ns-render`` and ``ns-viewer``
load like any run.

nerfstudio finds a run's checkpoints at ``output_dir/experiment/method/timestamp/relative_model_dir``
and the method name must stay a registered one, so the written config keeps its experiment and
method names, empties the timestamp and sets ``relative_model_dir`` to an absolute path inside
``DIR`` (an absolute right-hand side wins in a path join). The base folder
``DIR/<experiment>/<method>`` is created because ``ns-viewer`` writes its log file there. The
written run refers to ``DIR`` by its absolute path; to move it, run ``idsplat-edit`` again.
"""

from __future__ import annotations

import copy
import json
from dataclasses import dataclass
from pathlib import Path

import torch
import yaml

from idsplat_ns.atomic import atomic_path
from idsplat_ns.errors import IDSplatError

SCENE_PREFIX = "_model.scene_model."  # state-dict prefix of the SceneModel inside a pipeline


@dataclass
class TrainedRun:
    config_path: Path
    config: object  # nerfstudio TrainerConfig
    checkpoint_path: Path
    checkpoint: dict  # {"step", "pipeline", ...}

    @property
    def step(self) -> int:
        return int(self.checkpoint["step"])

    @property
    def pipeline_state(self) -> dict:
        return self.checkpoint["pipeline"]


def _checkpoint_dir(config, config_path: Path) -> Path:
    """Where the run's checkpoints are: where the config says, else beside the config (a run
    folder that was moved or copied after training)."""
    try:
        said = Path(config.get_checkpoint_dir())
    except Exception:  # an incomplete config: fall back to the folder layout
        said = None
    if said is not None and said.is_dir():
        return said
    beside = config_path.parent / "nerfstudio_models"
    if beside.is_dir():
        return beside
    raise IDSplatError(f"{config_path}: no checkpoint folder ({said} or {beside}); train the run first")


def load_run(config_path: Path) -> TrainedRun:
    """The config and latest checkpoint of a run (CPU tensors)."""
    config_path = Path(config_path)
    if not config_path.is_file():
        raise IDSplatError(f"--load-config {config_path}: no such file; give a run's config.yml")
    import method_configs.idsplat  # noqa: F401  (registers the classes the YAML names)

    try:
        config = yaml.load(config_path.read_text(), Loader=yaml.Loader)
    except yaml.YAMLError as err:
        raise IDSplatError(f"--load-config {config_path}: not a readable config ({type(err).__name__}); give a run's config.yml") from None
    ckpt_dir = _checkpoint_dir(config, config_path)
    ckpts = sorted(ckpt_dir.glob("step-*.ckpt"), key=lambda p: int(p.stem.split("-")[1]))
    if not ckpts:
        raise IDSplatError(f"{ckpt_dir}: no step-*.ckpt checkpoint; train the run first")
    checkpoint = torch.load(ckpts[-1], map_location="cpu", weights_only=False)
    if f"{SCENE_PREFIX}gaussians.means" not in checkpoint.get("pipeline", {}):
        raise IDSplatError(f"{ckpts[-1]}: not an IDSplat checkpoint (no Gaussians); give an idsplat run's config.yml")
    return TrainedRun(config_path, config, ckpts[-1], checkpoint)


def write_run(run: TrainedRun, pipeline_state: dict, out_dir: Path, note: dict) -> Path:
    """Write ``pipeline_state`` as a run in ``out_dir`` (config, checkpoint, ``edits.json``);
    returns the new config path. The optimiser state is left out: it belongs to the old tensor
    sizes, and an edited scene is for rendering, evaluation and viewing, not for resuming training."""
    out_dir = Path(out_dir).resolve()
    if out_dir == run.config_path.parent.resolve():
        raise IDSplatError(f"--output-dir {out_dir}: is the source run's folder; give a new folder")
    config = copy.deepcopy(run.config)
    config.output_dir = out_dir
    config.timestamp = ""
    config.relative_model_dir = out_dir / "nerfstudio_models"
    config.load_dir = None
    Path(config.get_base_dir()).mkdir(parents=True, exist_ok=True)  # ns-viewer's log goes there
    data = config.pipeline.datamanager.dataparser.data
    if data is not None and not Path(data).is_absolute() and Path(data).exists():
        config.pipeline.datamanager.dataparser.data = Path(data).resolve()  # valid from any folder
    ckpt_dir = out_dir / "nerfstudio_models"
    ckpt_dir.mkdir(parents=True, exist_ok=True)
    for old in ckpt_dir.glob("step-*.ckpt"):  # loaders take the latest step: leave only ours
        old.unlink()
    with atomic_path(ckpt_dir / f"step-{run.step:09d}.ckpt") as tmp:
        torch.save({"step": run.step, "pipeline": pipeline_state}, tmp)
    with atomic_path(out_dir / "config.yml") as tmp:
        tmp.write_text(yaml.dump(config), "utf8")
    record = {"source_config": str(run.config_path.resolve()), "source_checkpoint": str(run.checkpoint_path.resolve()), **note}
    with atomic_path(out_dir / "edits.json") as tmp:
        tmp.write_text(json.dumps(record, indent=2))
    return out_dir / "config.yml"
