"""Presets of the reconstruction and how explicit options override them.

``fast`` is the default: the grid pyramid of :class:`~cam.reconstruct.fields.GridField`
started from the oriented-plane distance, sized to finish a 50k-point part in
about a minute on two CPU cores. ``mlp`` is the paper's network at a size a CPU
can train in minutes; ``paper`` is the paper's 8x512 network, sampling and a
long schedule, meant for a GPU.
"""

from __future__ import annotations

from typing import Any

from cam import GeometryError

__all__ = ["PRESETS", "resolve_options"]

# Keys: field ("grid" | "mlp"); grid_cells and levels (grid: finest cells along the longest side,
# number of levels); width and depth (mlp); prior_k (neighbours blended by the grid's start);
# iterations, batch_size (cloud points per step; as many Gaussian samples plus 1/8 uniform ones);
# learning_rate (mlp: Adam's step; grid: the step as a fraction of each level's cell);
# lr_final_ratio and schedule ("cosine" to lr*ratio, or the paper's "step": halve every 2000);
# sigma_k (the Gaussian samples' sigma is the distance to the k-th neighbour); resolution
# (marching-cubes cells along the longest side).
PRESETS: dict[str, dict[str, Any]] = {
    "fast": {
        "field": "grid", "grid_cells": 192, "levels": 4, "width": None, "depth": None, "prior_k": 8,
        "iterations": 50, "batch_size": 65536, "learning_rate": 0.02, "lr_final_ratio": 0.01,
        "schedule": "cosine", "sigma_k": 10, "resolution": 384,
    },
    "mlp": {
        "field": "mlp", "grid_cells": None, "levels": None, "width": 256, "depth": 4, "prior_k": None,
        "iterations": 2000, "batch_size": 8192, "learning_rate": 5e-3, "lr_final_ratio": 0.01,
        "schedule": "cosine", "sigma_k": 50, "resolution": 256,
    },
    "paper": {
        "field": "mlp", "grid_cells": None, "levels": None, "width": 512, "depth": 8, "prior_k": None,
        "iterations": 20000, "batch_size": 16384, "learning_rate": 5e-3, "lr_final_ratio": 0.01,
        "schedule": "step", "sigma_k": 50, "resolution": 512,
    },
}

_BOUNDS = {
    "iterations": (1, 1_000_000),
    "batch_size": (16, 1_000_000),
    "grid_cells": (8, 1024),
    "width": (8, 2048),
    "depth": (2, 16),
    "resolution": (16, 1024),
    "learning_rate": (1e-7, 1.0),
}


def resolve_options(preset: str, **overrides: Any) -> dict[str, Any]:
    """The preset's options with every non-None override applied, bounds checked.

    An unknown preset or an override out of bounds is ``ValueError`` (`ReconstructParams` rules both
    out); a width given to the grid preset is a :class:`~cam.GeometryError` (the parameters allow it,
    the preset does not).
    """
    if preset not in PRESETS:
        raise ValueError(f"unknown reconstruction preset {preset!r}; use one of {', '.join(PRESETS)}")
    opts = dict(PRESETS[preset])
    for name, value in overrides.items():
        if value is None:
            continue
        low, high = _BOUNDS[name]
        if not low <= value <= high:
            raise ValueError(f"{name} must lie in [{low}, {high}], got {value}")
        opts[name] = int(value) if isinstance(low, int) else float(value)
    if opts["field"] == "grid" and overrides.get("width") is not None:
        raise GeometryError(f"width and depth apply to the mlp and paper presets, not to {preset!r}")
    return opts
