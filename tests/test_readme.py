"""The README a user's clone follows: every relative link in it and in `docs/` resolves inside the clone."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOCUMENTS = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
LINK = re.compile(r"\]\(([^)\s#]+)(?:#[^)]*)?\)")


@pytest.mark.parametrize("document", DOCUMENTS, ids=lambda p: str(p.relative_to(ROOT)))
def test_relative_links_resolve_inside_the_clone(document: Path):
    bad = []
    for target in LINK.findall(document.read_text()):
        if re.match(r"[a-z][a-z0-9+.-]*:", target):  # http:, https:, mailto:
            continue
        resolved = (document.parent / target).resolve()
        if not resolved.is_relative_to(ROOT) or not resolved.exists():
            bad.append(target)
    assert not bad, f"{document.name} links to paths a user's clone does not have: {bad}"


def test_the_configuration_table_states_each_stages_own_time_limit():
    from core.stages import load_stages

    row = next(line for line in (ROOT / "README.md").read_text().splitlines()
               if line.startswith("| `CLOUD2CNC_STAGE_TIME_LIMIT_S` |"))
    stated = {name: float(seconds) for name, seconds in re.findall(r"(\w+) (\d+) s", row.split("|")[2])}
    assert stated == {s.name: s.time_limit_s for s in load_stages()}
