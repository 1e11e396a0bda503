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
import sys
from dataclasses import dataclass
from pathlib import Path

import torch
import yaml
from nerfstudio.engine.trainer import TrainerConfig

from idsplat_ns.atomic import atomic_path, removed_on_failure
from idsplat_ns.errors import IDSplatError
from idsplat_ns.runs.checkpoints import folder_problem, load_latest
from idsplat_ns.runs.run_config import IDSplatRunConfig

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


def read_run_config(config_path: Path):
    """The TrainerConfig in an IDSplat run's ``config.yml``; one line naming the file otherwise
    (missing, not YAML, not a nerfstudio run, another method's run)."""
    config_path = Path(config_path)
    if not config_path.is_file():
        raise IDSplatError(f"--load-config {config_path}: no such file; give a run's config.yml")
    try:  # the YAML names the config classes by module: the loader imports them itself
        config = yaml.load(config_path.read_text(), Loader=yaml.Loader)
    except (yaml.YAMLError, ImportError, AttributeError, TypeError) as err:
        raise IDSplatError(f"--load-config {config_path}: not a readable config ({type(err).__name__}); give a run's config.yml") from None
    if not isinstance(config, TrainerConfig):
        raise IDSplatError(f"--load-config {config_path}: not a nerfstudio run's config; give the config.yml that ns-train wrote")
    if not isinstance(config, IDSplatRunConfig):
        raise IDSplatError(f"--load-config {config_path}: a run of method {getattr(config, 'method_name', '?')!r}, "
                           "not of IDSplat; give the config.yml of an idsplat run")
    return config


def checkpoint_folder(config, config_path: Path) -> Path:
    """Where the run's checkpoints are: where the config says, else beside the config (a run
    folder that was moved or copied after training)."""
    try:
        said = Path(config.get_checkpoint_dir())
    except Exception:  # an incomplete config: fall back to the folder layout
        said = None
    if said is not None and said.is_dir():
        return said
    beside = Path(config_path).parent / "nerfstudio_models"
    if beside.is_dir():
        return beside
    raise IDSplatError(f"{config_path}: no checkpoint folder ({said} or {beside}); train the run first")


def check_run(config_path: Path):
    """Before a command builds the run's pipeline through nerfstudio's loader (which reads the
    folder the config names): the config is an IDSplat run's and its checkpoint folder holds
    checkpoints and nothing else (read without loading one; a checkpoint that then does not load
    is explained by :func:`~idsplat_ns.cli.command_failures.explain_checkpoint_load`).
    Returns the config."""
    config = read_run_config(config_path)
    problem = folder_problem(Path(config.get_checkpoint_dir()), strays=True)
    if problem is not None:
        raise IDSplatError(problem)
    return config


def load_run(config_path: Path) -> TrainedRun:
    """The config and newest loadable checkpoint of a run (CPU tensors); a newer checkpoint that
    does not load is named on stderr and skipped."""
    config_path = Path(config_path)
    config = read_run_config(config_path)
    loaded = load_latest(checkpoint_folder(config, config_path))
    for reason in loaded.reasons:
        print(f"note: {reason}: using {loaded.path.name}", file=sys.stderr)
    if f"{SCENE_PREFIX}gaussians.means" not in loaded.state["pipeline"]:
        raise IDSplatError(f"{loaded.path}: not an IDSplat checkpoint (no Gaussians); give an idsplat run's config.yml")
    return TrainedRun(config_path, config, loaded.path, loaded.state)


def write_run(run: TrainedRun, pipeline_state: dict, out_dir: Path, note: dict) -> Path:
    """Write ``pipeline_state`` as a run in ``out_dir`` (config, checkpoint, ``edits.json``);
    returns the new config path. The optimiser state is left out: it belongs to the old tensor
    sizes, and an edited scene is for rendering, evaluation and viewing, not for resuming training."""
    out_dir = Path(out_dir).resolve()
    if out_dir == run.config_path.parent.resolve():
        raise IDSplatError(f"--output-dir {out_dir}: is the source run's folder; give a new folder")
    with removed_on_failure(out_dir):  # a failed write leaves nothing it created
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
