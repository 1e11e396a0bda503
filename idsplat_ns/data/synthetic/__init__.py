"""Built-in procedural synthetic driving street, rendered by ray casting, written as PandaSet.

`generate_sequence(out_dir, preset="small", seed=0)` writes `out_dir/synth_<preset>_<seed>/`
(three front cameras, or five with the side ones, a spinning 64-beam lidar, cuboid tracks, instance masks). See
docs/synthetic.md. Needs only numpy, pandas, pillow, scipy and tqdm.
"""

from idsplat_ns.data.synthetic.config import (
    CAMERA_NAMES,
    PRESETS,
    SIDE_CAMERA_NAMES,
    CameraRigConfig,
    LidarConfig,
    SyntheticConfig,
    get_preset,
)
from idsplat_ns.data.synthetic.generate import GENERATOR_VERSION, generate_sequence, is_current, sequence_name

__all__ = [
    "is_current",
    "CAMERA_NAMES",
    "SIDE_CAMERA_NAMES",
    "PRESETS",
    "CameraRigConfig",
    "LidarConfig",
    "SyntheticConfig",
    "get_preset",
    "generate_sequence",
    "sequence_name",
    "GENERATOR_VERSION",
]
