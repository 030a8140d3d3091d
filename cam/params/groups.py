"""The typed parameter groups of the stages, one pydantic model per group of `JobParams`.

Each stage's entry point takes its own group (`remesh_quads(..., params=RemeshParams())`); names
carry their units; bounds live in `Field` and out-of-range values are rejected, never clamped. The
paper's values are the defaults where it gives them. Values derived from several groups (the fit
tolerance from the scallop height) are resolved by `core.params.JobParams`, not here.
"""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator

__all__ = ["DenoiseParams", "FitParams", "IngestParams", "ReconstructParams", "RemeshParams", "SegmentParams",
           "ToolParams", "ToolpathParams"]


class _Group(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class IngestParams(_Group):
    units: Literal["mm", "inch"] = Field("mm", description="Units of the uploaded coordinates; inch is converted to mm.")


class ReconstructParams(_Group):
    """IGR. The preset fixes everything; a field left at None takes the preset's value."""

    preset: Literal["fast", "mlp", "paper"] = Field(
        "fast", description="fast: multiresolution grid + IGR loss, about a minute on a laptop CPU; "
        "mlp: the paper's network at CPU size; paper: 8x512 MLP and schedule (for a GPU).")
    iterations: int | None = Field(None, ge=1, le=1_000_000, description="Adam steps.")
    batch_size: int | None = Field(None, ge=16, le=1_000_000, description="Cloud points per step.")
    grid_cells: int | None = Field(None, ge=8, le=1024, description="fast: finest grid cells along the longest side.")
    width: int | None = Field(None, ge=8, le=2048, description="mlp/paper: hidden layer width.")
    depth: int | None = Field(None, ge=2, le=16, description="mlp/paper: hidden layers.")
    resolution: int | None = Field(None, ge=16, le=1024, description="Marching-cubes cells along the longest side.")
    learning_rate: float | None = Field(None, ge=1e-7, le=1.0, description="Adam's initial step.")
    eikonal_weight: float = Field(0.1, ge=0, le=100, description="λ: weight of the eikonal term.")
    normal_weight: float = Field(1.0, ge=0, le=100, description="τ: weight of the normal term.")
    normals_k: int = Field(16, ge=3, le=200, description="Neighbours for normal estimation when the cloud has none "
                           "(grown, up to 4x, in proportion to the noise the first fit measures).")
    max_faces: int | None = Field(
        200_000, ge=1000, le=20_000_000, description="Cap on mesh_raw.ply's triangles: above it the surface is "
        "extracted on a coarser lattice (denoise and remesh time grow with the faces). None: no cap.")
    sharpen: bool = Field(
        True, description="Restore the sharp edges marching cubes bevels: bevel vertices move onto the two face "
        "planes around them and the edges between are split at the crease. False: plain marching cubes.")
    seed: int = Field(0, ge=0, le=2**31 - 1, description="Seed of the sampling and initialisation.")

    @model_validator(mode="after")
    def _network_size_needs_a_network(self) -> ReconstructParams:
        if self.preset == "fast" and (self.width is not None or self.depth is not None):
            raise ValueError("width and depth size the network of the mlp and paper presets; the fast preset "
                             "has none (set reconstruct.preset to mlp or paper, or leave them unset)")
        return self


class DenoiseParams(_Group):
    """MeshTGV; weights are dimensionless (the mesh is measured in mean edge lengths)."""

    enabled: bool = Field(True, description="Run MeshTGV; when false the mesh is passed on unchanged.")
    alpha0: float | None = Field(None, gt=0, le=100, description="Weight of the second-order TGV term. None: chosen "
                                 "from the noise measured on the mesh (denoise.json reports it and the weights).")
    alpha1: float | None = Field(None, gt=0, le=100, description="Weight of the first-order TGV term (normal jumps). "
                                 "None: chosen from the measured noise, like alpha0.")
    penalty0: float = Field(2.0, gt=0, le=1000, description="Augmented-Lagrangian penalty of the second-order split.")
    penalty1: float = Field(2.0, gt=0, le=1000, description="Augmented-Lagrangian penalty of the first-order split.")
    vertex_iterations: int | None = Field(None, ge=0, le=1000, description="Iterations of the vertex update. None: "
                                          "20, up to 300 where the measured noise is correlated from vertex to vertex "
                                          "(a scanner's), chosen with the weights.")
    flip_repair_rounds: int = Field(5, ge=0, le=100, description="Rounds that undo faces flipped by the update.")
    max_iterations: int = Field(100, ge=1, le=10000, description="Outer iterations of the normal filter.")
    tolerance: float = Field(1e-5, ge=0, le=1, description="Stop when the relative change of the normals is below this.")
    noise_reference_deg: float = Field(
        0.0, ge=0, le=180, description="Only with alpha0 and alpha1 set by hand: scale both by min(1, median dihedral "
        "angle / this). 0: use them as given. (Jobs stored before the automatic weights hold 0.15, 0.4 and 15 and "
        "get what they got then.)")


class RemeshParams(_Group):
    layout: Literal["quadriflow", "creases"] = Field("quadriflow", description="quadriflow: QuadriFlow's layout "
                                                     "(several runs, the one following the creases best kept); "
                                                     "creases: a layout made creases first, every crease a chain of "
                                                     "quad edges by construction (QuadriFlow where it cannot be made, "
                                                     "and on a mesh with holes). creases suits clean CAD meshes; on "
                                                     "reconstructed scans it makes many more patches "
                                                     "(bench/results/remesh.md).")
    target_faces: int = Field(3000, ge=100, le=1_000_000, description="Quad faces aimed for "
                              "(about 3,000 on a 50k-point part: finer meshes give segment more, thinner patches).")
    coarse_quads: float = Field(12.0, ge=2, le=32, description="Crease-first layout: the length of its coarse "
                                "mesh's edges, in quads. Longer: fewer extraordinary vertices (and patches), and "
                                "curved faces still get shorter ones.")
    seed: int = Field(0, ge=0, le=2**31 - 1, description="QuadriFlow's seed for the first attempt.")
    attempts: int = Field(3, ge=1, le=10, description="Most seeds tried (seed, seed + 1, ...).")
    candidates: int = Field(3, ge=1, le=10, description="Quad meshes that pass their checks to compare: the one "
                            "whose edges follow the most of the input's creases (over 60°) is kept.")
    timeout_s: float = Field(300.0, ge=10, le=3600, description="Time limit of one QuadriFlow run.")
    preserve_sharp: bool = Field(True, description="Ask QuadriFlow to keep sharp edges.")
    min_cost_flow: bool = Field(False, description="QuadriFlow's min-cost-flow solver (slower, fewer singularities).")
    max_hausdorff_ratio: float = Field(0.05, gt=0, le=1, description="Largest accepted Hausdorff distance to the "
                                       "input, as a fraction of its bounding-box diagonal.")
    snap_creases: bool = Field(False, description="Move each layout's vertices so that its edges run along the "
                               "input's creases (over segment.sharp_angle_deg, and long ones over 35°) before the "
                               "layouts are compared; a quad that a crease crosses from corner to corner is collapsed (two opposite "
                               "corners merged on the crease); a crease no quad edge can follow is left as it is and reported. "
                               "Off by default: the fit gets worse on some parts (bench/results/snap_fit.md).")


class SegmentParams(_Group):
    sharp_angle_deg: float = Field(50.0, gt=0, lt=180, description="An edge is sharp when its dihedral angle exceeds this (θ).")
    remove_base: bool = Field(True, description="Remove the setup base found by k-means on face normals.")
    mu: float = Field(0.7, ge=0, le=1, description="Weight of the similarity S in the base objective.")
    gamma: float = Field(0.3, ge=0, le=1, description="Weight of the quantity Γ in the base objective.")
    sc: float = Field(0.1, gt=0, description="SC: weight of sharp edges in the connection graph.")
    nc: float = Field(0.1, gt=0, description="NC: weight factor of NF edges.")
    ac: float = Field(1000.0, gt=0, description="AC: weight factor of auxiliary edges.")
    base_clusters: int = Field(6, ge=1, le=32, description="k of the k-means on face normals that finds the base.")
    min_sharp_fragment_edges: int = Field(3, ge=0, le=1000, description="Sharp-edge chains shorter than this are "
                                          "treated as noise.")
    seed: int = Field(0, ge=0, le=2**31 - 1, description="Seed of the k-means.")
    method: Literal["mst", "greedy", "motorcycle"] = Field("mst", description="mst: the paper's Kruskal MST of "
                                                             "clipping edges; greedy and motorcycle: baselines.")


class FitParams(_Group):
    tolerance_mm: float | None = Field(None, gt=0, le=10, description="Max deviation of a fitted surface from the "
                                       "mesh. None: a fifth of toolpath.scallop_height_mm (0.032 mm at 0.16 mm).")
    knot_spacing_quads: float = Field(2.0, ge=0.5, le=64, description="Initial knot spacing, in quads.")
    samples_per_face: Literal[0, 1, 3, 6, 10] = Field(1, description="Mesh samples per triangle beside its vertices.")
    max_samples_per_quad: float | None = Field(32.0, gt=0, le=10_000, description="Mesh samples the fit uses per "
                                               "patch quad at most (an even subset; errors are measured on all). "
                                               "None: all.")
    max_refinements: int = Field(3, ge=0, le=6, description="Knot insertions where a patch is over tolerance.")
    iterations: int = Field(8, ge=1, le=50, description="Parameter-correction rounds of the least-squares fit.")
    smoothing_mm2: float = Field(1e-4, ge=0, le=1, description="Thin-plate smoothing weight.")
    normal_weight_mm: float = Field(0.02, ge=0, le=1, description="Weight of the normal term of the fit.")
    crease_angle_deg: float = Field(40.0, gt=0, lt=180, description="Boundary corners sharper than this are kept.")
    snap_radius_quads: float = Field(1.0, ge=0, le=5, description="Boundary snapping onto sharp edges, in quads.")
    require_tolerance: bool = Field(False, description="Fail the stage when a patch stays over tolerance_mm "
                                    "(otherwise it is reported in surfaces.json).")


class ToolParams(_Group):
    shape: Literal["ball"] = Field("ball", description="Cutter shape: ball end mill.")
    radius_mm: float = Field(3.0, gt=0, le=50, description="Ball radius.")
    rest_radius_mm: float | None = Field(None, gt=0, le=50, description="Radius of a smaller ball that finishes "
                                         "what the main one leaves over the target, in a program of its own per "
                                         "setup. None: no rest program.")
    tool_number: int = Field(1, ge=1, le=99999, description="T word of the tool change.")
    rest_tool_number: int = Field(2, ge=1, le=99999, description="T word of the rest ball's tool change.")
    spindle_rpm: float = Field(12000.0, gt=0, le=200000, description="Spindle speed.")
    feed_mm_min: float = Field(1200.0, gt=0, le=100000, description="Cutting feed.")
    plunge_mm_min: float = Field(300.0, gt=0, le=100000, description="Plunge feed.")


class ToolpathParams(_Group):
    scallop_height_mm: float = Field(0.16, gt=0, le=5, description="Scallop height the program must not exceed.")
    dialect: Literal["linuxcnc", "grbl", "fanuc"] = Field("linuxcnc", description="G-code dialect.")
    chord_fraction: float = Field(0.1, gt=0, lt=0.5, description="Share of the scallop budget given to chord error.")
    samples_per_line: int = Field(32, ge=4, le=512, description="Samples per parameter line when building passes.")
    strategy: Literal["adaptive", "paper"] = Field("adaptive", description="adaptive: variable spacing and corner "
                                                    "excursions; paper: Algorithm 1 as published.")
    clearance_mm: float = Field(5.0, gt=0, le=500, description="Rapid height above the part.")
    retract_mm: float = Field(1.0, gt=0, le=100, description="How far a lift feeds off the part before its rapid "
                              "starts (and an approach feeds on).")
    min_reach_fraction: float = Field(0.5, ge=0, le=1, description="A patch whose reachable share is below this "
                                      "is reported unmachined for the setup.")
    verify_samples_per_interval: int = Field(12, ge=4, le=100, description="verify: samples of the part per "
                                             "flat pass width (the finer, the nearer it finds the largest scallop).")
    max_setups: int = Field(2, ge=1, le=4, description="Setups (tool axes) at most; they are chosen to reach the "
                            "most of the part.")
    patch_passes: bool = Field(True, description="Contour-parallel passes on the fitted patches that hold their "
                               "tolerance before the whole-part finish (false: the mesh strategies alone).")
    min_finished_share: float = Field(0.98, ge=0, le=1, description="verify passes only when at least this share "
                                      "of what the ball can reach is left within the scallop height.")
    gouge_tolerance_mm: float = Field(0.01, ge=0, le=1, description="verify fails a program that cuts deeper "
                                      "than this into the part (mesh.ply).")
    rapid_margin_mm: float = Field(0.5, ge=0, le=100, description="Rapid moves keep at least this distance from "
                                   "the part; verify checks it.")
