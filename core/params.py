"""`JobParams`: every parameter of a job, grouped by stage (the groups are `cam.params`'s).

Out-of-range values are rejected, never clamped. A value derived from several groups is computed
here, once: `fit_tolerance_mm`, and `effective(group)`, the group a stage is given and its cache key
hashes, with such values filled in.
"""

from __future__ import annotations

from typing import Any

from pydantic import BaseModel, ConfigDict, Field

from cam.params import (
    DenoiseParams,
    FitParams,
    IngestParams,
    ReconstructParams,
    RemeshParams,
    SegmentParams,
    ToolParams,
    ToolpathParams,
)

#: The fit's default tolerance is the scallop height divided by this: a fifth, the rest left to the tool path.
FIT_TOLERANCE_DIVISOR = 5.0


class JobParams(BaseModel):
    """Parameters of one job; missing groups and fields take their defaults."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    ingest: IngestParams = Field(default_factory=IngestParams)
    reconstruct: ReconstructParams = Field(default_factory=ReconstructParams)
    denoise: DenoiseParams = Field(default_factory=DenoiseParams)
    remesh: RemeshParams = Field(default_factory=RemeshParams)
    segment: SegmentParams = Field(default_factory=SegmentParams)
    fit: FitParams = Field(default_factory=FitParams)
    tool: ToolParams = Field(default_factory=ToolParams)
    toolpath: ToolpathParams = Field(default_factory=ToolpathParams)

    @property
    def fit_tolerance_mm(self) -> float:
        """fit.tolerance_mm, or a fifth of toolpath.scallop_height_mm when it is unset (0.032 mm at 0.16 mm)."""
        if self.fit.tolerance_mm is not None:
            return float(self.fit.tolerance_mm)
        return float(self.toolpath.scallop_height_mm) / FIT_TOLERANCE_DIVISOR

    def effective(self, group: str) -> BaseModel:
        """The parameter group a stage is given, with the values derived from other groups filled in."""
        if group == "fit":
            return self.fit.model_copy(update={"tolerance_mm": self.fit_tolerance_mm})
        return getattr(self, group)


def merge_params(base: dict[str, Any], changes: dict[str, Any]) -> dict[str, Any]:
    """Deep-merge `changes` into `base` (both plain dicts) without touching either."""
    out = dict(base)
    for key, value in changes.items():
        if isinstance(value, dict) and isinstance(out.get(key), dict):
            out[key] = merge_params(out[key], value)
        else:
            out[key] = value
    return out


def parse_assignment(text: str) -> dict[str, Any]:
    """Turn `group.name=value` (CLI --set) into `{"group": {"name": value}}`.

    The value is read as JSON when it parses (numbers, true/false), else kept as a string.
    """
    import json

    key, sep, raw = text.partition("=")
    parts = key.strip().split(".")
    if not sep or len(parts) != 2 or not all(parts):
        raise ValueError(f"--set expects group.name=value, got {text!r}")
    try:
        value: Any = json.loads(raw)
    except json.JSONDecodeError:
        value = raw
    return {parts[0]: {parts[1]: value}}
