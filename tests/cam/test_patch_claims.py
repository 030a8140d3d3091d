"""The patch planner's claims: a patch finished on parameter rectangles only is measured on exactly those
(`cam.verify.claims` with the surface measurement of `cam.verify.measure`)."""

from __future__ import annotations

import numpy as np

from cam.gcode import parse_program, write_program
from cam.gcode.setup import Setup
from cam.params import ToolParams, ToolpathParams
from cam.plan.patch_job import plan_patches
from cam.spline import analytic
from cam.spline.geometry import machine_patches
from cam.spline.surface import clamped_uniform_knots, make_bspline_surface
from cam.verify import claimed_patches, measure_program

EYE = Setup(1, np.eye(3), np.zeros(3))


def _measure(ids, surfaces):
    plan = plan_patches(ids, surfaces, [EYE], ToolParams(radius_mm=3.0), ToolpathParams(scallop_height_mm=0.16))
    sp = plan.setups[0]
    entry = {"id": 1, "patches": list(dict.fromkeys(pp.patch for pp in sp.patches)),
             "partial": [q for q in plan.partial if q["patch"] in {pp.patch for pp in sp.patches}]}
    part = machine_patches(ids, surfaces, np.ones(len(ids)), EYE)
    program = parse_program(write_program(sp.moves, header={}))
    m = measure_program(program, claimed_patches(entry, part), part, tool_radius_mm=3.0, target_mm=0.16)
    return plan, entry, m.report


def test_a_partly_finished_patch_is_claimed_and_verified_on_its_claim():
    g = np.linspace(0, 10, 8)
    X, Y = np.meshgrid(g, g, indexing="ij")
    P = np.stack([X, Y, np.zeros_like(X)], -1)
    P[6, :, 0] = 10.6  # a lip that folds back along u = 1
    k = clamped_uniform_knots(8)
    plan, entry, report = _measure([5], [make_bspline_surface(P, k, k)])
    (claim,) = entry["partial"]
    assert claim["patch"] == 5 and claim["region"][1] < 1.0 and "folds over itself" in claim["reason"]
    assert report["max_scallop_mm"] <= plan.certified_scallop_mm <= 0.16 and report["max_gouge_mm"] < 1e-3


def test_a_patch_claimed_on_two_rectangles_is_verified_on_both():
    # A floor with a rib standing across it: the ball finishes the floor on both sides of the rib, two
    # claims of one patch; the program is measured on exactly those two rectangles.
    floor = analytic.plane(20.0, 16.0)
    rib = analytic.fit_grid(lambda u, v: np.stack([np.full_like(u, 8.0), 16 * u, 6 * v], -1), n=(4, 4))
    plan, entry, report = _measure([1, 2], [floor, rib])
    claims = [q for q in entry["partial"] if q["patch"] == 1]
    assert len(claims) == 2 and entry["patches"].count(1) == 1
    assert report["max_scallop_mm"] <= plan.certified_scallop_mm <= 0.16
    # Every sample of both claims is reached: the rectangle before the rib is machined, not left over.
    assert report["fraction_never_reached"] == 0 and report["uncut_area_mm2"] == 0
    assert report["max_gouge_mm"] < 1e-3
    assert [x["patch"] for x in report["patches"]].count(1) == 2  # each claim measured
