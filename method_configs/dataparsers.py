"""The dataparsers ``idsplat-pandaset`` and ``idsplat-waymo`` (nerfstudio entry points).

Kept apart from the method specifications: nerfstudio loads dataparser entry points while its
datamanager module is still importing, so this module must not import the trainer or pipeline.
"""

from __future__ import annotations

from nerfstudio.plugins.registry_dataparser import DataParserSpecification

import idsplat_ns._compat.startup as _startup
from idsplat_ns.errors import install_excepthook
from idsplat_ns.nerfstudio.dataparser import PandaSetDataParserConfig, WaymoDataParserConfig

_startup.install()
install_excepthook()

pandaset_dataparser = DataParserSpecification(
    config=PandaSetDataParserConfig(), description="PandaSet sequence folder (default: the built-in synthetic street)"
)
waymo_dataparser = DataParserSpecification(
    config=WaymoDataParserConfig(), description="Waymo Open Dataset v1 segment or v2 root + context name"
)
