"""The stage registry: which stages exist, in DESIGN order, and how a stage's cache key is made.

This module holds metadata only: the API, the worker and the command line read it. Implementations
belong to the worker (`worker.stages`), which alone imports the geometry stack.
"""

from __future__ import annotations

import hashlib
import importlib
import json
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from core.params import JobParams

if TYPE_CHECKING:
    from core.config import Settings

#: Program files plan may write: one per setup (at most 4) and per ball (the rest ball's end in -rest); the
#: names `cam.plan.program_name` gives (core loads no geometry code, so they are listed here; a test compares).
PROGRAMS = tuple(("program" if k == 1 else f"program-setup{k}") + suffix + ".nc"
                 for suffix in ("", "-rest") for k in range(1, 5))

#: The pipeline of DESIGN.md, in order.
DESIGN_ORDER = ("ingest", "reconstruct", "denoise", "remesh", "segment", "fit", "plan", "verify")


@dataclass(frozen=True)
class StageSpec:
    name: str
    version: str
    """Bumped whenever a code change alters the stage's outputs; it is part of the cache key."""
    inputs: tuple[str, ...]
    """Artifact names the stage may read; those a job has are hashed into the cache key."""
    outputs: tuple[str, ...]
    """Artifact names the stage may write."""
    param_groups: tuple[str, ...]
    """`JobParams` groups the stage reads; only these enter its cache key."""
    settings: tuple[str, ...] = field(default=())
    """Operator settings (from `Settings`) the stage reads; they enter the cache key too."""
    time_limit_s: float | None = None
    """Hard time limit of this stage unless the operator sets `Settings.stage_time_limit_s`; None: 3600 s."""
    faster: str = ""
    """What a user can change to make the stage faster (named in the message of a stage out of time)."""


STAGES: tuple[StageSpec, ...] = (
    StageSpec(
        name="ingest",
        version="1",
        inputs=("input",),
        outputs=("cloud.ply", "mesh_raw.ply", "ingest.json"),
        param_groups=("ingest",),
        settings=("min_points", "max_points"),
        time_limit_s=900.0,
    ),
    StageSpec(
        name="reconstruct",
        version="2",
        inputs=("cloud.ply",),
        outputs=("mesh_raw.ply",),
        param_groups=("reconstruct",),
        settings=("blas_threads", "stage_processes"),
        time_limit_s=1800.0,
        faster="a lower reconstruct.resolution or reconstruct.iterations, or the `fast` reconstruct.preset",
    ),
    StageSpec(
        name="denoise",
        version="3",
        inputs=("mesh_raw.ply",),
        outputs=("mesh.ply", "denoise.json"),
        param_groups=("denoise",),
        settings=("stage_processes",),
        time_limit_s=1800.0,
        faster="fewer denoise.max_iterations, or denoise.enabled = false for a clean mesh",
    ),
    StageSpec(
        name="remesh",
        version="4",
        inputs=("mesh.ply",),
        outputs=("quads.obj", "remesh.json"),
        param_groups=("remesh",),
        settings=("stage_processes",),
        time_limit_s=1200.0,
        faster="a lower remesh.target_faces, fewer remesh.attempts or remesh.candidates",
    ),
    StageSpec(
        name="segment",
        version="1",
        inputs=("quads.obj",),
        outputs=("patches.json", "segments.ply", "setup.json"),
        param_groups=("segment",),
        time_limit_s=900.0,
    ),
    StageSpec(
        name="fit",
        version="4",
        inputs=("quads.obj", "patches.json", "mesh.ply"),
        outputs=("surfaces.json", "surfaces.igs", "surfaces.step"),
        param_groups=("fit",),  # with its tolerance resolved (JobParams.effective)
        settings=("stage_processes",),
        time_limit_s=1800.0,
        faster="a larger fit.tolerance_mm or fit.knot_spacing_quads, fewer fit.max_refinements, "
               "a lower remesh.target_faces",
    ),
    StageSpec(
        name="plan",
        version="2",
        inputs=("mesh.ply", "surfaces.json", "setup.json"),
        outputs=("toolpath.json", "toolpath.csv", "setup.json") + PROGRAMS,
        param_groups=("tool", "toolpath"),
        settings=("stage_processes",),
        time_limit_s=1800.0,
        faster="a larger toolpath.scallop_height_mm or tool.radius_mm, toolpath.patch_passes = false, "
               "fewer toolpath.max_setups, no tool.rest_radius_mm",
    ),
    StageSpec(
        name="verify",
        version="3",
        inputs=("mesh.ply", "setup.json") + PROGRAMS,
        outputs=("verify.json", "scallop.ply", "report.html"),
        param_groups=("tool", "toolpath"),
        time_limit_s=1800.0,
        faster="a lower toolpath.verify_samples_per_interval or a larger toolpath.scallop_height_mm",
    ),
)


def load_stages(plugins: str = "", only: str = "") -> tuple[StageSpec, ...]:
    """The built-in stages plus those of each comma-separated plugin module's `STAGES` (a plugin module
    also maps each of its stage names to its implementation in `IMPLEMENTATIONS`, which the worker reads).

    `only`, when not empty, is a comma-separated subset of their names: the pipeline a job runs
    (an operator's meshing-only service runs `ingest,reconstruct,denoise`). Order stays DESIGN's.
    """
    stages = list(STAGES)
    for module_name in filter(None, (p.strip() for p in plugins.split(","))):
        stages.extend(importlib.import_module(module_name).STAGES)
    names = [s.name for s in stages]
    if len(set(names)) != len(names):
        raise ValueError(f"duplicate stage names in the pipeline: {names}")
    wanted = [n.strip() for n in only.split(",") if n.strip()]
    if wanted:
        unknown = sorted(set(wanted) - set(names))
        if unknown:
            raise ValueError(f"CLOUD2CNC_PIPELINE names unknown stages {unknown}; known: {', '.join(names)}")
        stages = [s for s in stages if s.name in wanted]
    return tuple(stages)


#: The hard limit of a stage that names none, and of Celery tasks in general, s.
DEFAULT_STAGE_LIMIT_S = 3600.0


def time_limit_s(spec: StageSpec, settings: Settings) -> float:
    """The hard time limit of a stage in seconds: the operator's for this stage or for every stage
    (`Settings.time_limit_s`), else the stage's own, else `DEFAULT_STAGE_LIMIT_S`."""
    return settings.time_limit_s(spec.name, spec.time_limit_s if spec.time_limit_s is not None
                                 else DEFAULT_STAGE_LIMIT_S)


def stage_names_until(stages: tuple[StageSpec, ...], until: str | None) -> list[str]:
    """Names of the stages up to and including `until` (all when None)."""
    names = [s.name for s in stages]
    if until is None:
        return names
    if until not in names:
        raise ValueError(f"unknown stage {until!r}; implemented stages are {', '.join(names)}")
    return names[: names.index(until) + 1]


#: Settings that change how fast a stage runs, never what it writes (`cam.map_forked`): not in the cache key.
SPEED_ONLY_SETTINGS = frozenset({"stage_processes"})


def cache_key(spec: StageSpec, params: JobParams, input_hashes: dict[str, str],
              settings: dict[str, Any], *, code: str) -> str:
    """hash(stage, stage code version, its params, its input artifact hashes) as in DESIGN.

    The code version is the declared `version` and `code`, the `code_digest` of the implementation's
    module: a changed deployment does not reuse what older code stored, whether or not someone bumped
    the version. The params hashed are the stage's groups as it is given them (`JobParams.effective`):
    what it reads, derived values included, and nothing else.
    """
    material = {
        "stage": spec.name,
        "version": spec.version,
        "code": code,
        "params": {g: params.effective(g).model_dump(mode="json") for g in spec.param_groups},
        "settings": {k: settings[k] for k in spec.settings if k not in SPEED_ONLY_SETTINGS},
        "inputs": {k: input_hashes[k] for k in sorted(input_hashes) if k in spec.inputs},
    }
    text = json.dumps(material, sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(text.encode()).hexdigest()


def code_digest(module: str) -> str:
    """sha256 over the source of `module` and of every module of its own top-level package, or of
    cam, core and worker, that it imports, directly or through them (any import statement,
    function-level ones too).

    Read from the files each time (tens of files, tens to hundreds of milliseconds), so a file changed
    under a running process counts; what has no Python source (a compiled extension, or a name that
    is an attribute, not a module) is left out.
    """
    roots = {"cam", "core", "worker", module.split(".")[0]}
    digest = hashlib.sha256()
    todo, seen = [module], set()
    while todo:
        name = todo.pop()
        if name in seen:
            continue
        seen.add(name)
        path = _source_path(name)
        if path is None:
            continue
        source = path.read_bytes()
        digest.update(name.encode() + b"\0" + source + b"\0")
        for found in _imports(name, source, is_package=path.name == "__init__.py"):
            parts = found.split(".")
            if parts[0] in roots:
                # The package __init__ files on the way run on import too.
                todo += [".".join(parts[:i]) for i in range(1, len(parts) + 1)]
    return digest.hexdigest()


def _source_path(name: str):
    from importlib.util import find_spec
    from pathlib import Path

    try:
        found = find_spec(name)
    except (ImportError, ValueError):  # `from pkg import attribute`: not a module
        return None
    if found is None or not found.origin or not found.origin.endswith(".py"):
        return None
    return Path(found.origin)


def _imports(name: str, source: bytes, *, is_package: bool) -> list[str]:
    """Absolute names of what a module's import statements name (for `from a import b`: a and a.b)."""
    import ast

    package = name if is_package else name.rpartition(".")[0]
    out = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            out += [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = package.split(".")[: len(package.split(".")) - node.level + 1]
                base = ".".join(anchor + ([base] if base else []))
            out += [base] + [f"{base}.{alias.name}" for alias in node.names if alias.name != "*"]
    return out
