"""The root config of an IDSplat run as its folder holds it (``config.yml``).

Run folders written by an older version keep loading: a ``config.yml`` lacks the settings
added since, and PyYAML rebuilds dataclasses without running ``__init__``, so a missing field
would be an ``AttributeError`` deep inside ``ns-eval`` or ``ns-viewer``. The root config fills
every such field of the project's own configs with its default when it is loaded."""

from __future__ import annotations

import dataclasses
from typing import Any

from nerfstudio.engine.trainer import TrainerConfig

OWN_MODULES = ("idsplat_ns.", "method_configs.")


def _default(f: dataclasses.Field) -> Any:
    if f.default is not dataclasses.MISSING:
        return f.default
    if f.default_factory is not dataclasses.MISSING:  # type: ignore[misc]
        return f.default_factory()  # type: ignore[misc]
    return dataclasses.MISSING


def fill_missing_fields(root: Any) -> list[str]:
    """Give every dataclass of the project's modules under ``root`` (through fields, lists, tuples
    and dicts) its default for each field it lacks; returns the dotted names filled."""
    filled: list[str] = []
    seen: set[int] = set()

    def walk(obj: Any, path: str) -> None:
        if id(obj) in seen:
            return
        seen.add(id(obj))
        if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
            own = type(obj).__module__.startswith(OWN_MODULES)
            for f in dataclasses.fields(obj):
                name = f"{path}.{f.name}" if path else f.name
                if own and f.name not in vars(obj):
                    value = _default(f)
                    if value is dataclasses.MISSING:
                        continue  # a required field: nothing sensible to fill
                    object.__setattr__(obj, f.name, value)  # frozen dataclasses too
                    filled.append(name)
                walk(getattr(obj, f.name, None), name)
        elif isinstance(obj, (list, tuple)):
            for i, item in enumerate(obj):
                walk(item, f"{path}[{i}]")
        elif isinstance(obj, dict):
            for key, item in obj.items():
                walk(item, f"{path}[{key!r}]")

    walk(root, "")
    return filled


class FillsMissingFieldsOnLoad:
    """Mixin for the root config: PyYAML calls ``__setstate__`` with the saved fields after it has
    built everything under them (deep construction), so the whole tree is filled here."""

    def __setstate__(self, state: dict) -> None:
        self.__dict__.update(state)
        fill_missing_fields(self)


@dataclasses.dataclass
class IDSplatRunConfig(FillsMissingFieldsOnLoad, TrainerConfig):
    """What a run folder's reader accepts as an IDSplat run (:func:`~idsplat_ns.runs.run_folder.read_run_config`):
    nerfstudio's TrainerConfig, filled on load. The adapter's ``IDSplatTrainerConfig`` derives from
    it and adds the trainer and the checks made before anything is written."""
