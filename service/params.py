"""`JobParams`: every parameter of a job, grouped by stage, bounds in `Field`.

Out-of-range values are rejected, never clamped. The paper's values are the
defaults where it gives them. Unit suffixes are part of the names.
"""

from __future__ import annotations

from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field


class _Group(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class IngestParams(_Group):
    units: Literal["mm", "inch"] = Field("mm", description="Units of the uploaded coordinates; inch is converted to mm.")


class ReconstructParams(_Group):
    """Filled in by the reconstruct stage when it lands."""


class DenoiseParams(_Group):
    enabled: bool = Field(True, description="Run MeshTGV; when false the mesh is passed on unchanged.")


class RemeshParams(_Group):
    target_faces: int = Field(8000, ge=100, le=1_000_000, description="Quad faces QuadriFlow aims for.")


class SegmentParams(_Group):
    sharp_angle_deg: float = Field(50.0, gt=0, lt=180, description="An edge is sharp when its dihedral angle exceeds this (θ).")
    remove_base: bool = Field(True, description="Remove the setup base found by k-means on face normals.")
    mu: float = Field(0.7, ge=0, le=1, description="Weight of the similarity S in the base objective.")
    gamma: float = Field(0.3, ge=0, le=1, description="Weight of the quantity Γ in the base objective.")
    sc: float = Field(0.1, gt=0, description="SC: weight of sharp edges in the connection graph.")
    nc: float = Field(0.1, gt=0, description="NC: weight factor of NF edges.")
    ac: float = Field(1000.0, gt=0, description="AC: weight factor of auxiliary edges.")


class FitParams(_Group):
    tolerance_mm: float = Field(0.032, gt=0, le=10, description="Max deviation of a fitted surface from the mesh.")


class ToolParams(_Group):
    shape: Literal["ball"] = Field("ball", description="Cutter shape: ball end mill.")
    radius_mm: float = Field(3.0, gt=0, le=50, description="Ball radius.")


class ToolpathParams(_Group):
    scallop_height_mm: float = Field(0.16, gt=0, le=5, description="Scallop height the program must not exceed.")
    dialect: Literal["linuxcnc", "grbl", "fanuc"] = Field("linuxcnc", description="G-code dialect.")


class JobParams(_Group):
    """Parameters of one job; missing groups and fields take their defaults."""

    ingest: IngestParams = Field(default_factory=IngestParams)
    reconstruct: ReconstructParams = Field(default_factory=ReconstructParams)
    denoise: DenoiseParams = Field(default_factory=DenoiseParams)
    remesh: RemeshParams = Field(default_factory=RemeshParams)
    segment: SegmentParams = Field(default_factory=SegmentParams)
    fit: FitParams = Field(default_factory=FitParams)
    tool: ToolParams = Field(default_factory=ToolParams)
    toolpath: ToolpathParams = Field(default_factory=ToolpathParams)


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
