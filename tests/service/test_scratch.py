"""Scratch folders a killed worker left: a starting worker removes those of runs that are over, only those."""

from __future__ import annotations

import uuid

from core import jobs
from core.config import Settings
from core.db import get_sessionmaker
from worker.scratch import remove_stale_scratch


def test_only_the_scratch_folders_of_runs_that_are_over_go(tmp_path):
    settings = Settings(data_dir=tmp_path / "d")
    settings.data_dir.mkdir()
    Session = get_sessionmaker(settings.resolved_database_url)
    with Session.begin() as session:
        job_id = jobs.create_job(session, input_name="a.xyz", input_sha256="0" * 64, input_size=1,
                                 input_format="xyz", params={}, stage_names=["ingest", "fit"]).id
    with Session.begin() as session:
        held = jobs.claim_stage(session, job_id, "ingest", lease_s=60, worker="here:1")
    work = settings.data_dir / "work"
    live = work / f"{job_id}-ingest-{held.token}"       # a run in progress
    stale = work / f"{job_id}-fit-{uuid.uuid4().hex}"   # a run whose worker was killed, since re-queued
    for folder in (live, stale):
        (folder / "out").mkdir(parents=True)
        (folder / "out" / "partial.ply").write_bytes(b"ply\n")
    (work / "README").write_text("not a scratch folder")

    assert remove_stale_scratch(settings) == [stale]
    assert live.is_dir() and not stale.exists() and (work / "README").exists()

    with Session.begin() as session:
        assert jobs.finish_stage(session, job_id, held.token, status="succeeded")
    assert remove_stale_scratch(settings) == [live]  # had its runner died before removing it
    assert remove_stale_scratch(settings) == []


def test_no_work_folder_is_nothing_to_do(tmp_path):
    assert remove_stale_scratch(Settings(data_dir=tmp_path / "none")) == []
