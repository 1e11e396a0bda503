"""The paper's evaluation protocols by name: which frames, cameras, resolution and train/eval split
a sequence gets (``--protocol``).

The Waymo protocols read the split files and settings in ``waymo/splits/`` (supplementary
tables); PandaSet follows SplatAD (10 sequences, all six cameras, full resolution, 50 % train).

| name | data | sequences | cameras | resolution | split |
|---|---|---|---|---|---|
| ``streetgs`` | Waymo | StreetGS split (8), start/end frames | FRONT | full | every 4th frame held out (AD-GS) |
| ``notr-dynamic`` | Waymo | dynamic NOTR (32), first 50 frames | FRONT, FRONT_LEFT, FRONT_RIGHT | half | every 10th held out (DeSiRe-GS) |
| ``pvg`` | Waymo | PVG split (4), start/end frames | FRONT, FRONT_LEFT, FRONT_RIGHT | half | 75 %, every 4th held out (SplatFlow) |
| ``view-density-{25,50,75,100}`` | Waymo | dynamic NOTR, first 50 frames | FRONT | full | that share trains, linearly spaced; 100: all frames both |
| ``pandaset-10`` | PandaSet | 001 011 016 028 053 063 084 106 123 158 | all six | full | 50 %, linearly spaced |
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal, Optional

from idsplat_ns.data.waymo.splits import experiment_settings, load_split
from idsplat_ns.errors import IDSplatError

PANDASET_10 = ("001", "011", "016", "028", "053", "063", "084", "106", "123", "158")
# Protocol name -> the experiment setting of experiment_settings.json it follows.
WAYMO_SETTINGS = {"streetgs": "adgs", "notr-dynamic": "desiregs", "pvg": "splatflow"}
VIEW_DENSITIES = (25, 50, 75, 100)
PROTOCOL_NAMES = (*WAYMO_SETTINGS, *(f"view-density-{d}" for d in VIEW_DENSITIES), "pandaset-10")
WAYMO_FULL_HEIGHT = 1280  # front cameras are 1920 x 1280


@dataclass(frozen=True)
class ProtocolSelection:
    """What a protocol fixes for one sequence."""

    protocol: str
    """Protocol name (as passed to ``--protocol``)."""
    sequence_id: str
    """The benchmark's number of the sequence (StreetGS ``006``, PandaSet ``001``)."""
    cameras: Optional[tuple[str, ...]]
    """Cameras to load (None: all the sequence has)."""
    start_frame: int
    """First frame."""
    end_frame: Optional[int]
    """One past the last frame (None: to the end)."""
    downscale_factor: float
    """Image downscale relative to the dataset's full resolution."""
    train_fraction: float
    """Share of frames that train (when ``eval_every`` is None)."""
    eval_every: Optional[int]
    """Every k-th frame held out (None: linearly spaced by ``train_fraction``)."""

    def describe(self) -> str:
        cams = ", ".join(self.cameras) if self.cameras else "all cameras"
        end = "end" if self.end_frame is None else self.end_frame
        split = f"every {self.eval_every}th frame held out" if self.eval_every else f"{self.train_fraction:.0%} of frames train"
        return (f"protocol {self.protocol}, sequence {self.sequence_id}: frames [{self.start_frame}, {end}), {cams}, "
                f"downscale {self.downscale_factor:g}, {split}")


def protocol_dataset(name: str) -> Literal["waymo", "pandaset"]:
    """Which dataset a protocol is defined on."""
    if name not in PROTOCOL_NAMES:
        raise IDSplatError(f"--protocol {name}: unknown; choose one of {', '.join(PROTOCOL_NAMES)}")
    return "pandaset" if name == "pandaset-10" else "waymo"


def select_protocol(name: str, sequence: str) -> ProtocolSelection:
    """The protocol's settings for ``sequence`` (a Waymo context name or a PandaSet folder name).

    One-line error when the protocol does not contain the sequence.
    """
    if protocol_dataset(name) == "pandaset":
        if sequence not in PANDASET_10:
            raise IDSplatError(f"--protocol pandaset-10: sequence {sequence!r} is not one of its ten ({' '.join(PANDASET_10)})")
        return ProtocolSelection(name, sequence, None, 0, None, 1.0, 0.5, None)

    if name.startswith("view-density-"):
        setting = experiment_settings()["view_density"]
        train_fraction = int(name.rsplit("-", 1)[1]) / 100.0
    else:
        setting = experiment_settings()[WAYMO_SETTINGS[name]]
        train_fraction = float(setting.train_fraction)
    specs = {spec.context_name: spec for spec in load_split(setting.split)}
    context = sequence.removeprefix("segment-")
    if context not in specs:
        raise IDSplatError(
            f"--protocol {name}: segment {context} is not in its split ({setting.split}, {len(specs)} segments); "
            "choose a listed segment or drop --protocol"
        )
    spec = specs[context]
    start, end = spec.frame_range(setting.use_split_frame_range, setting.max_frames)
    return ProtocolSelection(
        protocol=name, sequence_id=spec.sequence_id, cameras=tuple(setting.cameras), start_frame=start, end_frame=end,
        downscale_factor=WAYMO_FULL_HEIGHT / setting.image_size[0], train_fraction=train_fraction,
        eval_every=setting.eval_every,
    )
