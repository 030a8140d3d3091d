"""Stage implementations: load artifacts, call `cam`, write artifacts. One module per stage.

`implementation` finds the function that runs a stage: a built-in one here, or one a plugin module
(see `core.stages.load_stages`) names in its `IMPLEMENTATIONS`.
"""

from __future__ import annotations

import importlib
from pathlib import Path
from typing import TYPE_CHECKING, Callable

if TYPE_CHECKING:
    from worker.context import StageContext

Implementation = Callable[["StageContext"], dict[str, Path]]

#: module:function of each built-in stage, imported when the stage first runs (reconstruct pulls in torch).
BUILT_IN = {name: f"worker.stages.{name}:run_{name}"
            for name in ("ingest", "reconstruct", "denoise", "remesh", "segment", "fit", "plan", "verify")}


def implementation(stage: str, plugins: str = "") -> Implementation:
    """The function that runs `stage`, from the built-in stages or the comma-separated plugin modules."""
    if stage in BUILT_IN:
        module, _, func = BUILT_IN[stage].partition(":")
        return getattr(importlib.import_module(module), func)
    for module_name in filter(None, (p.strip() for p in plugins.split(","))):
        found = getattr(importlib.import_module(module_name), "IMPLEMENTATIONS", {}).get(stage)
        if found is not None:
            return found
    raise LookupError(f"no implementation of stage {stage!r} among the built-in stages and plugins {plugins!r}")
