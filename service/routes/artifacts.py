"""/v1/jobs/{id}/artifacts: the list and streamed downloads with ETag / If-None-Match."""

from __future__ import annotations

from pathlib import PurePath
from typing import Annotated

from fastapi import APIRouter, Header, Response
from fastapi.responses import FileResponse

from service.deps import SessionDep, StoreDep
from service.present import artifact_out, media_type
from service.problems import Problem
from service.routes.jobs import _ERRORS, _get_job
from service.schemas import ArtifactOut

router = APIRouter(prefix="/v1/jobs", tags=["artifacts"])

#: Artifacts a browser shows in place rather than saves (the setup sheet, report.html): sandboxed, with no
#: script and nothing fetched, since the page is the service's own origin.
_SHOWN_CSP = {".html": "default-src 'none'; style-src 'unsafe-inline'; img-src data:; sandbox"}


@router.get("/{job_id}/artifacts", response_model=list[ArtifactOut], responses=_ERRORS,
            summary="The job's artifacts so far")
def list_artifacts(job_id: str, session: SessionDep) -> list[ArtifactOut]:
    job = _get_job(session, job_id)
    return [artifact_out(job.id, a) for a in job.artifacts]


def _etag_matches(header: str | None, etag: str) -> bool:
    if not header:
        return False
    candidates = [t.strip().removeprefix("W/") for t in header.split(",")]
    return "*" in candidates or etag in candidates


@router.get("/{job_id}/artifacts/{name}", responses={
    200: {"content": {"application/octet-stream": {}}, "description": "The file"},
    304: {"description": "Not modified (If-None-Match matched the ETag)"}, **_ERRORS},
    response_class=Response, summary="Download an artifact")
def download_artifact(job_id: str, name: str, session: SessionDep, store: StoreDep,
                      if_none_match: Annotated[str | None, Header()] = None) -> Response:
    job = _get_job(session, job_id)
    artifact = next((a for a in job.artifacts if a.name == name), None)
    if artifact is None:
        raise Problem(404, "artifact-not-found", "Artifact not found",
                      f"job {job_id} has no artifact {name!r} (yet); GET /v1/jobs/{job_id}/artifacts lists them")
    etag = f'"{artifact.sha256}"'
    headers = {"ETag": etag, "Cache-Control": "private, max-age=0, must-revalidate"}
    if _etag_matches(if_none_match, etag):
        return Response(status_code=304, headers=headers)
    path = store.path(artifact.sha256)
    if not path.is_file():
        raise Problem(410, "artifact-gone", "Artifact gone",
                      f"the file behind {name!r} is no longer in the store; rerun the job")
    csp = _SHOWN_CSP.get(PurePath(name).suffix.lower())
    if csp:
        headers.update({"Content-Security-Policy": csp, "X-Content-Type-Options": "nosniff"})
    return FileResponse(path, media_type=media_type(name), filename=name, headers=headers,
                        content_disposition_type="inline" if csp else "attachment")
