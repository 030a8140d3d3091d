"""The house plan, checked on the source: which package may import which (an AST scan, no imports run).

- `cam` is the geometry library: no web, queue or database code, and nothing of the service layers.
- Its stage packages import in stage order (a later stage may use an earlier one's public records,
  never the reverse); `verify` imports nothing from `plan`, the planner it checks; the shared packages
  import no stage package; nothing else sits at `cam`'s top level.
- `core` (job state) is shared by `service` (HTTP) and `worker` (Celery), which never import each other,
  not even by module names in strings; the `cloud2cnc` command line sits above both.
"""

from __future__ import annotations

import ast
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
STAGES = ("ingest", "reconstruct", "denoise", "remesh", "segment", "fit", "plan", "verify")
SHARED = ("mesh", "spline", "gcode", "io", "params")
WEB_QUEUE_DB = ("fastapi", "starlette", "uvicorn", "celery", "kombu", "redis", "sqlalchemy", "psycopg", "httpx",
                "multipart", "python_multipart")
LAYERS = ("service", "worker", "core", "cloud2cnc")


def _modules(package: str) -> list[tuple[str, Path]]:
    base = ROOT / package
    out = []
    for path in sorted(base.rglob("*.py")):
        rel = path.relative_to(ROOT).with_suffix("")
        name = ".".join(rel.parts[:-1] if rel.name == "__init__" else rel.parts)
        out.append((name, path))
    return out


def _imports(name: str, path: Path) -> list[str]:
    """Absolute names of everything a module imports (function-level imports too)."""
    tree = ast.parse(path.read_text())
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found += [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                parts = package.split(".")
                base = ".".join(parts[: len(parts) - node.level + 1] + ([base] if base else []))
            found += [base] + [f"{base}.{a.name}" for a in node.names if a.name != "*"]
    return found


def _strings(path: Path) -> list[str]:
    return [n.value for n in ast.walk(ast.parse(path.read_text())) if isinstance(n, ast.Constant)
            and isinstance(n.value, str)]


def _top(name: str) -> str:
    return name.split(".")[0]


def _cam_part(name: str) -> str | None:
    parts = name.split(".")
    return parts[1] if parts[0] == "cam" and len(parts) > 1 else None


def test_cam_top_level_holds_only_the_stage_and_shared_packages():
    entries = {p.name for p in (ROOT / "cam").iterdir() if not p.name.startswith((".", "__pycache__"))}
    assert entries - {"__init__.py"} <= set(STAGES) | set(SHARED), sorted(entries - set(STAGES) - set(SHARED))
    for name in set(STAGES) | set(SHARED):
        assert (ROOT / "cam" / name / "__init__.py").is_file(), f"cam/{name} is not a package"


@pytest.mark.parametrize("name,path", _modules("cam"), ids=lambda x: str(x))
def test_cam_imports_follow_the_stage_order(name, path):
    me = _cam_part(name)
    for imported in _imports(name, path):
        top = _top(imported)
        assert top not in WEB_QUEUE_DB + LAYERS, f"{name} imports {imported}: cam imports no web, queue, db or service code"
        other = _cam_part(imported)
        if other is None or other == me or me is None:
            continue
        if me in SHARED:
            assert other not in STAGES, f"shared package cam.{me} imports the stage cam.{other} ({name})"
        elif other in STAGES:
            assert STAGES.index(other) < STAGES.index(me), f"stage {me} imports the later stage {other} ({name})"
            assert not (me == "verify" and other == "plan"), f"verify imports the planner ({name})"


def test_shared_packages_import_each_other_without_cycles():
    graph: dict[str, set[str]] = {s: set() for s in SHARED}
    for s in SHARED:
        for name, path in _modules(f"cam/{s}"):
            graph[s] |= {o for o in map(_cam_part, _imports(name, path)) if o in SHARED and o != s}
    state: dict[str, int] = {}

    def visit(node: str, trail: list[str]) -> None:
        state[node] = 1
        for nxt in graph[node]:
            assert state.get(nxt) != 1, f"import cycle among shared packages: {' -> '.join(trail + [node, nxt])}"
            if nxt not in state:
                visit(nxt, trail + [node])
        state[node] = 2

    for node in graph:
        if node not in state:
            visit(node, [])


# Who may import whom among the layers (cam is below all of them).
ALLOWED = {"core": {"core", "cam"}, "service": {"service", "core", "cam"}, "worker": {"worker", "core", "cam"},
           "cloud2cnc": {"cloud2cnc", "service", "worker", "core", "cam"}}


@pytest.mark.parametrize("layer", sorted(ALLOWED))
def test_layers_import_downwards_only(layer):
    for name, path in _modules(layer):
        for imported in _imports(name, path):
            top = _top(imported)
            if top in ALLOWED:
                assert top in ALLOWED[layer], f"{name} imports {imported}"
            if layer in ("core", "service"):
                assert top not in ("torch",), f"{name} imports {imported}"
            if layer in ("core", "worker"):
                assert top not in ("fastapi", "starlette", "uvicorn"), f"{name} imports {imported}"


@pytest.mark.parametrize("layer,forbidden", [("service", "worker"), ("core", "worker"), ("worker", "service"),
                                             ("core", "service")])
def test_no_module_names_in_strings_across_layers(layer, forbidden):
    pattern = re.compile(rf"\b{forbidden}\.[a-z_]+(\.[a-z_]+)*(:[a-z_]+)?\b")
    for name, path in _modules(layer):
        for text in _strings(path):
            assert not pattern.fullmatch(text.strip()), f"{name} names {text!r}"


def test_the_api_loads_no_geometry_stack():
    # The service may read cam's upload sniffing and parameter models; nothing that pulls in numpy/torch.
    light = {"cam", "cam.io", "cam.io.formats", "cam.params"}
    for name, path in _modules("service") + _modules("core"):
        for imported in _imports(name, path):
            if _top(imported) == "cam":
                module = imported if imported in light else imported.rpartition(".")[0]
                assert module in light, f"{name} imports {imported}"
