"""The `ingest` stage: an upload's points or mesh, converted to millimetres, cleaned, with a report of what was dropped."""

from cam.ingest.clean import (
    MM_PER_UNIT,
    CleanCloud,
    CleanMesh,
    IngestError,
    clean_cloud,
    clean_mesh,
)

__all__ = ["MM_PER_UNIT", "CleanCloud", "CleanMesh", "IngestError", "clean_cloud", "clean_mesh"]
