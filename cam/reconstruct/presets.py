"""Presets of the reconstruction and how explicit options override them.

``fast`` is the default: the grid pyramid of :class:`~cam.reconstruct.fields.GridField`
started from the oriented-plane distance, sized to finish a 50k-point part in
about a minute on two CPU cores. ``mlp`` is the paper's network at a size a CPU
can train in minutes; ``paper`` is the paper's 8x512 network, sampling and a
long schedule, meant for a GPU.
"""

from __future__ import annotations

from typing import Any

from cam.params import ReconstructParams

__all__ = ["PRESETS", "resolve_options"]

# Keys: field ("grid" | "mlp"); grid_cells and levels (grid: finest cells along the longest side,
# number of levels); width and depth (mlp); prior_k (neighbours blended by the grid's start: 16 so that
# at a corner every face around it has samples among them);
# iterations, batch_size (cloud points per step; as many Gaussian samples plus 1/8 uniform ones);
# learning_rate (mlp: Adam's step; grid: the step as a fraction of each level's cell);
# lr_final_ratio and schedule ("cosine" to lr*ratio, or the paper's "step": halve every 2000);
# sigma_k (the Gaussian samples' sigma is the distance to the k-th neighbour); resolution
# (marching-cubes cells along the longest side).
PRESETS: dict[str, dict[str, Any]] = {
    "fast": {
        "field": "grid", "grid_cells": 192, "levels": 4, "width": None, "depth": None, "prior_k": 16,
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

_OVERRIDES = ("iterations", "batch_size", "grid_cells", "width", "depth", "resolution", "learning_rate")


def resolve_options(params: ReconstructParams) -> dict[str, Any]:
    """The options of a group's preset, with the group's explicit values applied.

    Parameters
    ----------
    params : ReconstructParams
        ``preset`` names the option set; ``iterations``, ``batch_size``, ``grid_cells``,
        ``width``, ``depth``, ``resolution`` and ``learning_rate`` replace the preset's value
        when not None (the group has checked their bounds, and that width and depth are only
        given to a preset with a network).

    Returns
    -------
    dict
        A fresh copy of ``PRESETS[params.preset]`` with the overrides applied (keys as
        described above :data:`PRESETS`).
    """
    opts = dict(PRESETS[params.preset])
    for name in _OVERRIDES:
        value = getattr(params, name)
        if value is not None:
            opts[name] = value
    return opts
