"""What the dataparser read for a split and what the datamanager adds to it, as typed records.

nerfstudio carries a dataparser's results to the dataset, and the training dataset's to the
model, in one ``metadata`` dict (deep-copied per dataset). The project puts two records there, one
key each: :class:`SplitData` (the dataparser's) and :class:`InstanceInputs` (the datamanager's:
where instances come from and the tracks). Readers take them through :func:`split_data` and
:func:`instance_inputs`, which name what is missing instead of a ``KeyError`` deep inside.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal, Optional

from idsplat_ns.data.camera import CameraImage
from idsplat_ns.data.scene import Scene
from idsplat_ns.instances.tracks import InstanceTracks

SPLIT_KEY = "idsplat_split"
INSTANCES_KEY = "idsplat_instances"


@dataclass
class SplitData:
    """One split of a sequence as the dataparser read it."""

    scene: Scene
    """The whole sequence (every frame, image, sweep and annotation), in the parser's world frame."""
    images: list[CameraImage]
    """The split's images, in the dataset's image order."""
    image_scale: float
    """The scale of the images as loaded (the dataparser's downscale), before nerfstudio's own."""
    camera_names: list[str]
    """The rig's cameras; a camera's index here is its sensor index in the model."""
    split: str
    """nerfstudio's split name: ``train``, ``val``, ``test``."""
    protocol: Optional[str] = None
    """The paper's protocol that chose the frames, cameras and split, if any."""

    @property
    def frames(self) -> set[int]:
        """Dataset frame indices of the split's images."""
        return {int(im.frame_index) for im in self.images}


@dataclass
class InstanceInputs:
    """Where the instances come from, and their tracks, as the datamanager hands them to the model."""

    mode: Literal["self-supervised", "oracle", "static", "imported"]
    """The instance mode, or ``imported`` for ``--pipeline.datamanager.import-tracks``."""
    tracks: Optional[InstanceTracks]
    """The instance tracks on the training frames; None without instances."""
    test_mode: Literal["val", "test", "inference"] = "val"
    """nerfstudio's: ``val`` trains (the model initialises its Gaussians), ``test`` and
    ``inference`` (ns-eval, ns-viewer) load a checkpoint next."""

    @property
    def training(self) -> bool:
        return self.test_mode == "val"


def split_data(metadata: dict) -> SplitData:
    """The dataparser's record in a nerfstudio ``metadata`` dict."""
    data = metadata.get(SPLIT_KEY)
    if not isinstance(data, SplitData):
        raise ValueError(f"metadata has no {SPLIT_KEY!r} SplitData: not an IDSplat dataparser's output")
    return data


def instance_inputs(metadata: dict) -> InstanceInputs:
    """The datamanager's record in the training dataset's ``metadata`` dict."""
    inputs = metadata.get(INSTANCES_KEY)
    if not isinstance(inputs, InstanceInputs):
        raise ValueError(f"metadata has no {INSTANCES_KEY!r} InstanceInputs: not an IDSplat datamanager's dataset")
    return inputs
