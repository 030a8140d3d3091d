"""Scratch folders of stage runs that ended without cleaning up (their worker was killed).

A run computes in `data_dir/work/{job}-{stage}-{lease token}` and removes it when it ends, whatever the
outcome; a worker killed mid-stage (kill -9, OOM, its `serve` gone) leaves it behind. Before each stage
run a worker removes those whose lease is no longer held: the stage was re-queued (the re-queued run is
about to start under a new token) or finished, so nothing will read them again.
"""

from __future__ import annotations

import logging
import shutil
from pathlib import Path

from sqlalchemy import select

from core.config import Settings
from core.db import Stage, get_sessionmaker

log = logging.getLogger(__name__)


def remove_stale_scratch(settings: Settings) -> list[Path]:
    """Remove the scratch folders under `settings.data_dir / "work"` whose lease token no running stage
    holds; returns the folders removed.

    The folders are listed before the database is read: a folder is made only after its stage was claimed,
    so one listed while its token is not running belongs to a run that is over (a folder made after the
    listing is not looked at).
    """
    work = settings.data_dir / "work"
    if not work.is_dir():
        return []
    folders = {p.name.rsplit("-", 1)[-1]: p for p in work.iterdir() if p.is_dir() and "-" in p.name}
    if not folders:
        return []
    with get_sessionmaker(settings.resolved_database_url)() as session:
        held = set(session.execute(select(Stage.lease_token).where(Stage.status == "running",
                                                                    Stage.lease_token.in_(list(folders))))
                   .scalars())
    removed = []
    for token, path in folders.items():
        if token not in held:
            shutil.rmtree(path, ignore_errors=True)
            removed.append(path)
    if removed:
        log.info("removed %d scratch folder(s) of stage runs that ended without cleaning up", len(removed))
    return removed
