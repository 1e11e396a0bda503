"""The training-run config of the IDSplat methods: nerfstudio's, validated before anything is written.

``ns-train`` calls ``config.save_config()`` (which creates the run folder and its config.yml)
before it reads any data, and that is the first thing it does with the parsed options. So this
override is the earliest point where the project sees the final settings: it checks every numeric
option's range and that the camera backend can run on the training device (one line naming the
option, :mod:`idsplat_ns.runs.settings_checks`) and
registers the new run folder so that a run failing before its first checkpoint leaves nothing
behind (:func:`idsplat_ns.errors.register_run_dir`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Type

from idsplat_ns.atomic import first_created
from idsplat_ns.errors import register_run_dir
from idsplat_ns.nerfstudio.trainer import IDSplatTrainer
from idsplat_ns.runs.run_config import IDSplatRunConfig
from idsplat_ns.runs.settings_checks import check_camera_backend, check_lidar_compositor, validate_settings


@dataclass
class IDSplatTrainerConfig(IDSplatRunConfig):
    """nerfstudio's TrainerConfig whose ``save_config`` validates the settings first, and whose
    ``config.yml`` from an older version loads with the defaults of the settings added since."""

    _target: Type = field(default_factory=lambda: IDSplatTrainer)

    def save_config(self) -> None:
        validate_settings(self)
        check_camera_backend(self.pipeline.model.camera_backend, self.machine.device_type)
        check_lidar_compositor(self.pipeline.model.lidar.compositor, self.machine.device_type)
        base_dir = self.get_base_dir()
        # An existing folder (a fixed --timestamp) is not ours to remove; otherwise everything
        # save_config makes, --output-dir included when it did not exist, goes if the run fails.
        created = None if base_dir.exists() else first_created(base_dir)
        super().save_config()
        if created is not None:
            register_run_dir(base_dir, created)
