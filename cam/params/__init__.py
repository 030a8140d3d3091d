"""Typed parameter groups of the stages (`groups`): what `core.params.JobParams` is made of."""

from cam.params.groups import (
    DenoiseParams,
    FitParams,
    IngestParams,
    ReconstructParams,
    RemeshParams,
    SegmentParams,
    ToolParams,
    ToolpathParams,
)

__all__ = ["DenoiseParams", "FitParams", "IngestParams", "ReconstructParams", "RemeshParams", "SegmentParams",
           "ToolParams", "ToolpathParams"]
