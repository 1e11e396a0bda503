"""The dataparsers ``idsplat-auto``, ``idsplat-builtin``, ``idsplat-pandaset`` and ``idsplat-waymo`` (nerfstudio entry points).

Kept apart from the method specifications: nerfstudio loads dataparser entry points while its
datamanager module is still importing, so this module must not import the trainer or pipeline.
"""

from __future__ import annotations

from nerfstudio.plugins.registry_dataparser import DataParserSpecification

import idsplat_ns._compat.startup as _startup
from idsplat_ns.errors import install_excepthook
from idsplat_ns.nerfstudio.dataparser import (
    AutoDataParserConfig,
    BuiltinDataParserConfig,
    PandaSetDataParserConfig,
    WaymoDataParserConfig,
)

_startup.install()
install_excepthook()

auto_dataparser = DataParserSpecification(
    config=AutoDataParserConfig(), description="recognises --data (PandaSet folder, Waymo v1 or v2); without it the built-in street"
)
builtin_dataparser = DataParserSpecification(
    config=BuiltinDataParserConfig(), description="the built-in synthetic street (--preset, --seed)"
)
pandaset_dataparser = DataParserSpecification(
    config=PandaSetDataParserConfig(), description="PandaSet sequence folder (or a street written by idsplat-synth)"
)
waymo_dataparser = DataParserSpecification(
    config=WaymoDataParserConfig(), description="Waymo Open Dataset v1 segment or v2 root + context name"
)
