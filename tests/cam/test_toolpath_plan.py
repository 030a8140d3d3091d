"""The planner on analytic parts: certificates, a tool too large for a hollow, setups, the paper baseline."""

from __future__ import annotations

import numpy as np
import pytest

from cam.gcode import write_program
from cam.gcode.setup import Setup
from cam.params import ToolParams, ToolpathParams
from cam.plan import plan_patch
from cam.plan.edge import edge_scallop, ray_capsule_entry
from cam.plan.errors import TooConcave
from cam.plan.grid import check_concavity, ring_grid
from cam.plan.patch import exclude_points
from cam.plan.patch_job import plan_patches
from cam.plan.rings import corner_scallop, ring_path
from cam.plan.scallop import flat_spacing
from cam.spline import analytic
from cam.spline.geometry import Patch, frame, principal_curvatures

EYE = [Setup(1, np.eye(3), np.zeros(3))]


def test_curvature_of_analytic_parts():
    fr = frame(Patch(1, analytic.cylinder(20.0, 10.0, 60.0)), np.array([0.5]), np.array([0.5]))
    kmin, kmax = principal_curvatures(fr)
    assert kmax[0] == pytest.approx(1 / 20, rel=1e-3) and kmin[0] == pytest.approx(0, abs=1e-6)
    fr = frame(Patch(1, analytic.saddle(40.0)), np.array([0.5]), np.array([0.5]))
    kmin, kmax = principal_curvatures(fr)
    assert (kmin[0], kmax[0]) == pytest.approx((-1 / 40, 1 / 40), rel=1e-9)


def test_tool_too_large_for_a_hollow_is_reported_not_cut():
    trough = analytic.cylinder(2.5, 10.0, 100.0, concave=True)
    with pytest.raises(TooConcave, match="not larger than the tool radius"):
        check_concavity(Patch(7, trough), 3.0)
    plan = plan_patches([7, 8], [trough, analytic.plane(10, 10, z=-5.0)], EYE, ToolParams(radius_mm=3.0), ToolpathParams(scallop_height_mm=0.16))
    assert [u["patch"] for u in plan.unmachined] == [7] and "radius of curvature 2.49" in plan.unmachined[0]["reason"]
    assert [p.patch for s in plan.setups for p in s.patches] == [8]
    # A smaller ball fits and machines it.
    plan = plan_patches([7], [trough], EYE, ToolParams(radius_mm=1.5), ToolpathParams(scallop_height_mm=0.05))
    assert not plan.unmachined and plan.setups[0].patches[0].certified_scallop_mm <= 0.05


def test_a_hollow_tighter_than_any_ball_is_called_a_likely_ripple():
    # A 0.02 mm groove is no feature a ball end mill exists for; the user reads that the fit may ripple.
    with pytest.raises(TooConcave) as err:
        check_concavity(Patch(7, analytic.cylinder(0.02, 10.0, 100.0, concave=True)), 3.0)
    assert "radius of curvature 0.020 mm" in str(err.value) and "surface ripples" in str(err.value)
    assert "use a smaller ball" not in str(err.value)
    with pytest.raises(TooConcave, match="use a smaller ball"):
        check_concavity(Patch(7, analytic.cylinder(0.5, 10.0, 100.0, concave=True)), 3.0)


def _folded_plane():
    """A 10 x 10 mm plane with control columns at x = 0, 2.5, 9.5, 3, 10: x(u) turns back, an S-fold."""
    from cam.spline.surface import clamped_uniform_knots, make_bspline_surface

    g = np.linspace(0, 10, 5)
    X, Y = np.meshgrid(g, g, indexing="ij")
    P = np.stack([X, Y + 20.0, np.zeros_like(X)], -1)  # beside the plane the test machines
    P[2, :, 0], P[3, :, 0] = 9.5, 3.0
    k = clamped_uniform_knots(5)
    return make_bspline_surface(P, k, k)


def test_a_folded_surface_is_found_and_reported_not_cut():
    from cam.spline.folds import find_folds

    flat = analytic.plane(10, 10, z=-5.0)
    assert find_folds(flat) == (0.0, None)
    fraction, at = find_folds(_folded_plane())
    assert 0 < fraction < 1 and 0.0 < at[0] < 10.0
    # The fold (u in about [0.5, 0.75]) is left out and reported; the largest rectangle clear of it,
    # u in [0, 0.48] (x up to 6), is machined, and no contact lies on the fold.
    folded = _folded_plane()
    plan = plan_patches([3, 8], [folded, flat], EYE, ToolParams(radius_mm=3.0), ToolpathParams(scallop_height_mm=0.16))
    assert plan.unmachined == []
    (claim,) = plan.partial
    assert claim["patch"] == 3 and "folds over itself" in claim["reason"]
    u0, u1, v0, v1 = claim["region"]
    assert (u0, v0, v1) == (0.0, 0.0, 1.0) and 0.45 < u1 < 0.5
    (pp,) = [p for s in plan.setups for p in s.patches if p.patch == 3]
    tips = np.concatenate(pp.passes)  # a plane: tip = contact
    assert tips[:, 0].max() <= float(folded.evaluate(np.array([u1]), np.array([0.5]))[0, 0]) + 1e-6


def test_certificate_holds_and_adaptive_beats_the_paper_on_a_dome():
    dome = analytic.paraboloid(15.0, 16.0)
    out = {}
    for strategy in ("adaptive", "paper"):
        plan = plan_patches([1], [dome], EYE, ToolParams(radius_mm=3.0), ToolpathParams(scallop_height_mm=0.16, strategy=strategy))
        pp = plan.setups[0].patches[0]
        assert pp.certified_scallop_mm <= 0.16
        out[strategy] = pp.path_length_mm
    assert out["adaptive"] < 0.9 * out["paper"]


def test_rings_fill_the_square_outermost_first():
    plane = Patch(1, analytic.plane(20, 16))
    grid = ring_grid(plane, tool_radius_mm=3.0, scallop_mm=0.144)
    a, b, c, d = grid.rects.T
    # One pass on a plane leaves exactly h at the flat half interval √(2rh − h²) beside it: the first ring
    # sits that far inside the edges, the paper's on them.
    half = float(flat_spacing(0.144, 3.0)) / 2
    assert grid.claim == (0.0, 1.0, 0.0, 1.0)
    assert np.allclose(grid.rects[0], [half / 20, 1 - half / 20, half / 16, 1 - half / 16], rtol=0, atol=1e-9)
    assert np.all(grid.edge_scallop <= 0.144 * (1 + 1e-9)) and np.allclose(grid.edge_scallop, 0.144, rtol=1e-6)
    paper = ring_grid(plane, tool_radius_mm=3.0, scallop_mm=0.144, strategy="paper")
    assert paper.rects[0].tolist() == [0, 1, 0, 1] and not paper.edge_scallop.any()
    assert np.all(np.diff(a) >= 0) and np.all(np.diff(b) <= 0) and np.all(np.diff(c) >= 0) and np.all(np.diff(d) <= 0)
    last = grid.rects[-1]
    assert last[0] == last[1] or last[2] == last[3]
    assert grid.side_scallop.max() <= 0.144 * (1 + 1e-9)


def test_a_patch_facing_down_goes_to_the_opposite_setup():
    top = analytic.plane(10, 10, z=5.0)
    # The underside: the same plane flipped so its outward normal points down (−Z).
    cp = top.control_points.copy()[::-1]
    cp[..., 2] = -5.0
    from cam.spline.surface import make_bspline_surface

    bottom = make_bspline_surface(cp, top.knots_u, top.knots_v)
    plan = plan_patches([1, 2], [top, bottom], EYE, ToolParams(radius_mm=3.0), ToolpathParams(scallop_height_mm=0.16))
    assert [s.setup.id for s in plan.setups] == [1, 2]
    assert [[p.patch for p in s.patches] for s in plan.setups] == [[1], [2]]
    assert plan.setups[1].program == "program-setup2.nc"
    assert np.allclose(plan.setups[1].setup.rotation, np.diag([1.0, -1.0, -1.0]))
    with pytest.raises(ValueError, match="scallop height"):
        plan_patches([1], [top], EYE, ToolParams(radius_mm=3.0), ToolpathParams(scallop_height_mm=3.5))


def test_largest_clear_rectangle_against_every_rectangle():
    from cam.plan.region import largest_clear_rectangle

    def brute(bad, weight):
        best, out = -1.0, None
        n, m = bad.shape
        for i0 in range(n):
            for i1 in range(i0 + 2, n):
                for j0 in range(m):
                    for j1 in range(j0 + 2, m):
                        if not bad[i0:i1 + 1, j0:j1 + 1].any() and weight[i0:i1 + 1, j0:j1 + 1].sum() > best:
                            best, out = weight[i0:i1 + 1, j0:j1 + 1].sum(), (i0, i1, j0, j1)
        return out, best

    rng = np.random.default_rng(4)
    for _ in range(150):
        n, m = rng.integers(2, 11, 2)
        bad = rng.random((n, m)) < rng.uniform(0.0, 0.4)
        weight = rng.random((n, m))
        want, best = brute(bad, weight)
        got = largest_clear_rectangle(bad, weight)
        assert (got is None) == (want is None)
        if got is not None:
            i0, i1, j0, j1 = got
            assert i1 - i0 >= 2 and j1 - j0 >= 2 and not bad[i0:i1 + 1, j0:j1 + 1].any()
            assert weight[i0:i1 + 1, j0:j1 + 1].sum() == pytest.approx(best, rel=1e-12)
    # Two bad cells inside: moving each side past the bad cells nearest to it (the previous rule)
    # cut rows from the top past (4, 5) and from the bottom past (6, 6) and kept nothing; half the
    # square, columns 0..4, is clear.
    bad = np.zeros((10, 10), dtype=bool)
    bad[4, 5] = bad[6, 6] = True
    assert largest_clear_rectangle(bad, np.ones((10, 10))) == (0, 9, 0, 4)


def test_largest_clear_rectangle_of_any_size_has_the_most_clear_cells():
    # min_span=0, unit weights: the reach check's use (a single reachable sample is a rectangle too).
    from cam.plan.region import largest_clear_rectangle

    rng = np.random.default_rng(7)

    def brute(ok):
        n, m = ok.shape
        return max([(i1 - i0 + 1) * (j1 - j0 + 1) for i0 in range(n) for i1 in range(i0, n) for j0 in range(m)
                    for j1 in range(j0, m) if ok[i0:i1 + 1, j0:j1 + 1].all()], default=0)

    for _ in range(150):
        ok = rng.random((rng.integers(1, 8), rng.integers(1, 8))) < 0.7
        got = largest_clear_rectangle(~ok, np.ones(ok.shape), min_span=0)
        area = 0 if got is None else (got[1] - got[0] + 1) * (got[3] - got[2] + 1)
        assert area == brute(ok)
        assert got is None or ok[got[0]:got[1] + 1, got[2]:got[3] + 1].all()


def test_a_fold_along_one_border_is_left_out_and_the_rest_machined():
    from cam.plan.region import finishable_region
    from cam.spline.folds import find_folds
    from cam.spline.geometry import Patch
    from cam.spline.surface import clamped_uniform_knots, make_bspline_surface

    g = np.linspace(0, 10, 8)
    X, Y = np.meshgrid(g, g, indexing="ij")
    P = np.stack([X, Y, np.zeros_like(X)], -1)
    P[6, :, 0] = 10.6  # past the border column (x = 10): a thin lip folds back along u = 1
    k = clamped_uniform_knots(8)
    lip = make_bspline_surface(P, k, k)
    assert find_folds(lip)[0] > 0
    region = finishable_region(Patch(4, lip), 3.0)
    assert region.box[1] < 1.0 and 0.8 < region.kept < 1.0 and "folds over itself" in region.reason
    plan = plan_patches([4], [lip], EYE, ToolParams(radius_mm=3.0), ToolpathParams(scallop_height_mm=0.16))
    assert plan.unmachined == []
    (pp,) = plan.setups[0].patches
    assert pp.reach_fraction == pytest.approx(region.kept) and pp.certified_scallop_mm <= 0.16
    tips = np.concatenate(pp.passes)
    # Every contact point (a plane: tip = contact) lies in the kept part, short of the lip.
    assert tips[:, 0].max() <= float(lip.evaluate(np.array([region.box[1]]), np.array([0.5]))[0, 0]) + 1e-6


def test_a_fold_narrower_than_the_fits_own_grid_is_reported_where_the_planner_finds_it():
    # A plane with one of 31 control columns pulled back two column steps: a fold 0.3 mm wide, between
    # the samples of the 33 x 33 grid the fit compares its steps on. The fit's report uses the grid
    # the planner checks, so surfaces.json does not call a surface clean that the planner trims.
    from cam.plan.region import finishable_region
    from cam.spline.folds import FOLD_CHECK_SAMPLES, find_folds
    from cam.spline.surface import clamped_uniform_knots, make_bspline_surface

    g = np.linspace(0, 10, 31)
    X, Y = np.meshgrid(g, np.linspace(0, 10, 5), indexing="ij")
    P = np.stack([X, Y, np.zeros_like(X)], -1)
    P[16, :, 0] -= 2 * (g[1] - g[0])
    sheet = make_bspline_surface(P, clamped_uniform_knots(31), clamped_uniform_knots(5))
    assert find_folds(sheet, samples=33)[0] == 0.0
    assert find_folds(sheet, samples=FOLD_CHECK_SAMPLES)[0] > 0
    region = finishable_region(Patch(2, sheet), 3.0)
    assert "folds over itself" in region.reason and region.kept < 1.0


def test_a_collapsed_corner_is_left_out_as_degenerate_not_as_a_hollow():
    from cam.plan.region import finishable_region
    from cam.spline.surface import clamped_uniform_knots, make_bspline_surface

    g = np.linspace(0, 10, 6)
    X, Y = np.meshgrid(g, g, indexing="ij")
    P = np.stack([X, Y, np.zeros_like(X)], -1)
    P[1, 0] = P[0, 0]  # S_u vanishes at (0, 0) only: the plane's normal is undefined at that one point
    k = clamped_uniform_knots(6)
    flat = make_bspline_surface(P, k, k)
    region = finishable_region(Patch(5, flat), 3.0)
    # A plane has no hollow: the corner sample is left out (no normal to offset along there), and the
    # reason names the degenerate corner, not a concave radius of 0 mm.
    assert region.box is not None and 0.95 < region.kept < 1.0
    assert "concave" not in region.reason and "degenerate" in region.reason
    assert "[0.0, 0.0, 0.0]" in region.reason


def test_a_patch_the_planner_cannot_lay_out_is_reported_not_a_crash(monkeypatch):
    import cam.plan.patch_job as plan_module
    from cam.plan.errors import NotPlannable

    real = plan_module.plan_patch

    def flaky(p, *args, **kwargs):
        if p.id == 3:
            raise NotPlannable("no pass interval keeps the scallop within 0.1439 mm (curvature undefined there)")
        return real(p, *args, **kwargs)

    monkeypatch.setattr(plan_module, "plan_patch", flaky)
    from cam.spline.geometry import transform_surface

    flat = analytic.plane(10, 10, z=-5.0)
    beside = transform_surface(analytic.plane(10, 10), np.eye(3), np.array([0.0, 20.0, 0.0]))
    plan = plan_patches([3, 8], [beside, flat], EYE, ToolParams(radius_mm=3.0), ToolpathParams(scallop_height_mm=0.16))
    assert [u["patch"] for u in plan.unmachined] == [3] and "curvature undefined" in plan.unmachined[0]["reason"]
    assert [p.patch for s in plan.setups for p in s.patches] == [8]


def test_exclude_points_moves_the_nearest_side_or_one_side_past_trouble_in_the_middle():
    box = (0.0, 1.0, 0.0, 2.0)
    # Two strips along the borders u = 0 and v = 2: each side moves past its own points only.
    got = exclude_points(box, np.array([[0.05, 1.0], [0.5, 1.9]]), margin=0.0)
    assert got == pytest.approx((0.05, 1.0, 0.0, 1.9))
    # Points in the middle: one cut past all of them keeps more than moving two sides towards each other.
    got = exclude_points(box, np.array([[0.45, 1.0], [0.55, 1.1]]), margin=0.0)
    assert got == pytest.approx((0.0, 1.0, 0.0, 1.0))
    # Points outside the box change nothing.
    assert exclude_points(box, np.array([[2.0, 0.5]])) == box


def _material_left(patch, uv, contacts_uv, r):
    """Reference: the material (mm) along the normal at each uv (n, 2) under balls tangent at contacts_uv."""
    fc = frame(patch, contacts_uv[:, 0], contacts_uv[:, 1])
    centres = fc.p + r * fc.n
    fx = frame(patch, uv[:, 0], uv[:, 1])
    out = []
    for rows in np.array_split(np.arange(len(uv)), max(1, len(uv) * len(centres) // 2_000_000)):
        w = centres[None] - fx.p[rows, None]
        b = np.einsum("nmk,nk->nm", w, fx.n[rows])
        disc = b * b - np.einsum("nmk,nmk->nm", w, w) + r * r
        out.append(np.where(disc >= 0, b - np.sqrt(np.maximum(disc, 0)), np.inf).min(axis=1))
    return np.concatenate(out)


def test_ray_capsule_entry_against_dense_balls():
    rng = np.random.default_rng(7)
    a = rng.uniform(-2, 2, (40, 3))
    b = a + rng.normal(0.0, 1.0, (40, 3))
    origin = rng.uniform(-4, 4, (300, 3))
    direction = rng.normal(size=(300, 3))
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    got = ray_capsule_entry(origin, direction, a, b, 0.7)
    s = np.linspace(0.0, 1.0, 1001)[:, None, None]
    centres = (a[None] * (1 - s) + b[None] * s).reshape(-1, 3)
    w = centres[None] - origin[:, None]
    bb = np.einsum("nmk,nk->nm", w, direction)
    cc = np.einsum("nmk,nmk->nm", w, w) - 0.49
    root = bb - np.sqrt(np.maximum(bb * bb - cc, 0))
    ref = np.where(cc <= 0, 0.0, np.where((bb * bb >= cc) & (root >= 0), root, np.inf)).min(axis=1)
    hit = np.isfinite(ref)
    assert np.array_equal(np.isfinite(got), hit) and 0 < hit.sum() < len(ref) and np.any(ref == 0)
    # Dense balls enter at most a hair later than the capsules they sample.
    assert np.all(got[hit] <= ref[hit] + 1e-12) and np.allclose(got[hit], ref[hit], rtol=0, atol=2e-4)


@pytest.mark.parametrize("surface", [analytic.paraboloid(15.0, 16.0), analytic.saddle(40.0, 16.0),
                                     analytic.cylinder(20.0, 16.0, 60.0, concave=True)])
def test_edge_material_matches_the_reference_balls(surface):
    # What the first ring leaves on the patch edge against the reference material of 4001 balls on it.
    patch = Patch(1, surface)
    for along, edge, line in (("u", 0.0, 0.06), ("v", 1.0, 0.95)):
        got = edge_scallop(patch, along=along, edge=edge, line=line, lo=0.0, hi=1.0, r=3.0, samples=32)
        q = np.union1d(np.linspace(0.0, 1.0, 32), surface.knots_u if along == "u" else surface.knots_v)
        dense = np.linspace(0.0, 1.0, 4001)
        at = (lambda x, s: np.stack([x, np.full_like(x, s)], -1)) if along == "u" else (
            lambda x, s: np.stack([np.full_like(x, s), x], -1))
        ref = _material_left(patch, at(q, edge), at(dense, line), 3.0)
        assert 0.05 < got.min() and np.allclose(got, ref, rtol=0, atol=2e-5), along


def test_edge_material_peaks_where_the_edge_turns_a_corner():
    # A flat patch whose edge u = 0 turns a corner at a C0 knot line (v = 0.5): (0, 0) -> (-3, 8) -> (0, 16).
    # The first ring, inset at u = 0.05, turns with it, and the apex of the edge lies farther from it than
    # the rest: the material peaks sharply there, which none of 32 even samples hits. The knot is sampled
    # too (without it 32 samples reported 0.2035 mm against 0.2292 mm left).
    from cam.spline.surface import make_bspline_surface

    y = np.array([0, 8 / 3, 16 / 3, 8, 32 / 3, 40 / 3, 16])
    left = np.stack([-3 * (8 - np.abs(y - 8)) / 8, y, np.zeros_like(y)], -1)
    right = np.stack([np.full_like(y, 20.0), y, np.zeros_like(y)], -1)
    cp = np.stack([left + t * (right - left) for t in (0, 1 / 3, 2 / 3, 1)])
    patch = Patch(1, make_bspline_surface(cp, np.array([0, 0, 0, 0, 1, 1, 1, 1.0]),
                                          np.array([0, 0, 0, 0, 0.5, 0.5, 0.5, 1, 1, 1, 1.0])))
    got = edge_scallop(patch, along="v", edge=0.0, line=0.05, lo=0.0, hi=1.0, r=3.0, samples=32)
    q = np.linspace(0.0, 1.0, 801)
    ref = _material_left(patch, np.stack([np.zeros_like(q), q], -1),
                         np.stack([np.full(8001, 0.05), np.linspace(0.0, 1.0, 8001)], -1), 3.0)
    assert got.max() == pytest.approx(ref.max(), abs=2e-5) and ref.max() > 1.1 * np.median(ref)


def test_corner_pocket_bound_holds_where_the_near_side_is_convex():
    # A pocket on a convex cylinder (a spiral turn of its plan): the farthest point from the paths is not
    # where the most material is left, because a contact across the curved direction leaves more than one
    # along the axis. Bounding the farthest point gave 0.1385 mm here against 0.1520 mm left.
    cyl = Patch(1, analytic.cylinder(20.0, 10.0, 40.0))
    (a, b, c, d), (qa, qb, qc, qd) = outer, inner = (0.1222, 0.7562, 0.3663, 0.8173), (0.2438, 0.634, 0.5, 0.6337)
    bound, _ = corner_scallop(cyl, outer, inner, (0, 0), r=3.0)
    t = np.linspace(0.0, 1.0, 400)[:, None]
    legs = [((a, c), (b, c)), ((a, c), (a, d)), ((qa, qc), (qb, qc)), ((qa, qc), (qa, qd))]
    contacts = np.concatenate([np.array(p) * (1 - t) + np.array(q) * t for p, q in legs])
    uu, vv = np.meshgrid(np.linspace(a, qa, 41), np.linspace(c, qc, 41), indexing="ij")
    left = _material_left(cyl, np.stack([uu.ravel(), vv.ravel()], -1), contacts, 3.0)
    assert left.max() <= bound and bound <= 1.1 * left.max()


@pytest.mark.parametrize("corner", [(0, 0), (1, 1)])
def test_corner_pocket_at_the_claims_corner_against_the_reference_balls(corner):
    # The first ring inside a small, tightly curved patch: the pocket between the claim's corner (no pass
    # runs there) and the ring's corner. The bound once came from one ball at the nearest contact by the
    # circle relation, which on this dome said 0.2016 mm at (0, 0) where 0.2143 mm is left.
    patch = Patch(1, analytic.paraboloid(4.0, 4.0))
    claim, ring = (0.0, 1.0, 0.0, 1.0), (0.15, 0.8, 0.12, 0.85)
    bound, _ = corner_scallop(patch, claim, ring, corner, r=3.0, outer_cut=False)
    a, b, c, d = ring
    Q = np.array([(a, b)[corner[0]], (c, d)[corner[1]]])
    P = np.array([float(corner[0]), float(corner[1])])
    t = np.linspace(0.0, 1.0, 2001)[:, None]
    legs = [(Q, np.array([(b, a)[corner[0]], Q[1]])), (Q, np.array([Q[0], (d, c)[corner[1]]]))]
    contacts = np.concatenate([p * (1 - t) + q * t for p, q in legs])
    lo, hi = np.minimum(P, Q), np.maximum(P, Q)
    uu, vv = np.meshgrid(np.linspace(lo[0], hi[0], 41), np.linspace(lo[1], hi[1], 41), indexing="ij")
    left = _material_left(patch, np.stack([uu.ravel(), vv.ravel()], -1), contacts, 3.0)
    assert left.max() * (1 - 1e-6) <= bound <= 1.01 * left.max()


def test_spiral_turns_replace_the_diagonal_links_shorter_and_within_the_bound():
    cyl = Patch(1, analytic.cylinder(20.0, 10.0, 40.0))
    grid = ring_grid(cyl, tool_radius_mm=3.0, scallop_mm=0.144)
    rings = ring_path(cyl, grid.rects, r=3.0, corner_mm=0.14, claim=grid.claim)
    spiral = ring_path(cyl, grid.rects, r=3.0, corner_mm=0.14, spiral=True, claim=grid.claim)
    assert 1 in rings.kind and 1 not in spiral.kind  # no diagonal links left

    def length(path):
        t = np.linspace(0.0, 1.0, 50)[:, None]
        uv = np.concatenate([a * (1 - t) + b * t for a, b in zip(path.uv[:-1], path.uv[1:])])
        return np.linalg.norm(np.diff(cyl.surface.evaluate(uv[:, 0], uv[:, 1]), axis=0), axis=1).sum()

    # 2.8 % here (98.9 against 96.1 mm, 4 rings); 4.9 % when the first ring ran on the edge and could leave
    # the start of its u0 side to the next ring, which an edge half an interval away does not allow.
    assert length(spiral) < 0.98 * length(rings)
    assert spiral.corner_scallop.max() <= 0.14
    # Every turn's pocket, and the edges and corners of the square outside the first ring, are bounded
    # against the reference material of the whole contact path.
    t = np.linspace(0.0, 1.0, 600)[:, None]
    contacts = np.concatenate([a * (1 - t) + b * t for a, b in zip(spiral.uv[:-1], spiral.uv[1:])])
    uu, vv = np.meshgrid(np.linspace(0, 1, 61), np.linspace(0, 1, 61), indexing="ij")
    left = _material_left(cyl, np.stack([uu.ravel(), vv.ravel()], -1), contacts, 3.0)
    # Balls sampled δ apart leave up to about δ²/(8r) more between them than the swept ball (the edge
    # points, one ring away from the first, see that much); twice that is allowed for the reference.
    fc = frame(cyl, contacts[:, 0], contacts[:, 1])
    delta = np.linalg.norm(np.diff(fc.p + 3.0 * fc.n, axis=0), axis=1).max()
    assert left.max() <= 0.144 * (1 + 1e-6) + delta ** 2 / (4 * 3.0)


def test_a_wall_along_one_side_moves_only_that_side():
    # A floor with a wall standing on its far edge: the ball cannot reach the floor within r of the wall.
    # Every line along v runs into the wall too, but moving the far side alone frees them: the floor
    # keeps its full width and gives up only the strip by the wall.
    floor = analytic.plane(20.0, 16.0)
    wall = analytic.fit_grid(lambda u, v: np.stack([20 * u, np.full_like(u, 16.0), 8 * v], -1), n=(4, 4))
    plan = plan_patches([1, 2], [floor, wall], EYE, ToolParams(radius_mm=3.0), ToolpathParams(scallop_height_mm=0.16))
    pp = next(p for s in plan.setups for p in s.patches if p.patch == 1)
    u0, u1, v0, v1 = pp.region
    assert (u0, u1, v0) == (0.0, 1.0, 0.0)
    assert (16 - 3.0) / 16 - 0.01 < v1 <= (16 - 3.0) / 16 + 1e-9  # r from the wall (tangent is allowed)


def test_a_band_the_ball_cannot_reach_across_the_middle_leaves_both_sides_machined():
    # A floor with a thin rib standing across it at x = 8: no rectangle spanning the rib is reachable, and
    # every side of the floor runs into it. The larger part beyond the rib (x > 8 + r) is planned first,
    # then the strip before it (x < 8 - r), each claimed on its own rectangle and verified on it.
    floor = analytic.plane(20.0, 16.0)
    rib = analytic.fit_grid(lambda u, v: np.stack([np.full_like(u, 8.0), 16 * u, 6 * v], -1), n=(4, 4))
    plan = plan_patches([1, 2], [floor, rib], EYE, ToolParams(radius_mm=3.0), ToolpathParams(scallop_height_mm=0.16))
    first, second = [p for s in plan.setups for p in s.patches if p.patch == 1]
    u0, u1, v0, v1 = first.region
    assert (u1, v0, v1) == (1.0, 0.0, 1.0) and (8 + 3.0) / 20 <= u0 < (8 + 3.0) / 20 + 0.01
    u0, u1, v0, v1 = second.region
    assert (u0, v0, v1) == (0.0, 0.0, 1.0) and (8 - 3.0) / 20 - 0.01 < u1 <= (8 - 3.0) / 20
    claims = [q for q in plan.partial if q["patch"] == 1]
    assert [q["region"] for q in claims] == [list(first.region), list(second.region)]
    assert sum(q["kept"] for q in claims) == pytest.approx((20 - 6) / 20, abs=0.02)
    from cam.gcode import parse_program, write_program
    from cam.spline.knots import sub_surface
    from cam.verify import measure_program

    sp = plan.setups[0]
    machined = [Patch(1, sub_surface(floor, tuple(q["region"]))) for q in claims]
    m = measure_program(parse_program(write_program(sp.moves, header={})), machined, [Patch(1, floor), Patch(2, rib)],
                        tool_radius_mm=3.0, target_mm=0.16)
    assert m.report["max_scallop_mm"] <= plan.certified_scallop_mm * (1 + 1e-6) <= 0.16
    assert m.report["fraction_never_reached"] == 0 and m.report["max_gouge_mm"] < 1e-3


def test_move_clearance_finds_a_dip_between_its_samples():
    # A straight move of the ball centre 0.01 mm too low over the apex of a dome: its ends are clear,
    # and its samples 0.53 mm apart miss the apex; the refinement finds the exact -0.01 mm there.
    from cam.plan.gouge import build_index, move_clearance

    index = build_index([Patch(1, analytic.paraboloid(15.0, 16.0))], spacing_mm=0.5)
    a, b = np.array([[-0.9, 0.0, 2.99]]), np.array([[0.7, 0.0, 2.99]])
    worst, at = move_clearance(index, a, b, 3.0, step_mm=0.75)
    assert worst[0] == pytest.approx(-0.01, abs=1e-7) and abs(at[0, 0]) < 1e-3


def test_closest_points_cross_a_c0_line():
    # A sheet whose u = 1/2 iso-line is a C0 line (its v = 0 border turns up by 76 degrees there;
    # each half is bilinear, so its net is the map at the Greville abscissae). Points above it by
    # known heights must get exactly those distances whichever side Newton starts on.
    from cam.plan.gouge import _project
    from cam.spline.surface import make_bspline_surface

    ku = np.array([0, 0, 0, 0, 0.5, 0.5, 0.5, 1, 1, 1, 1.0])
    kv = np.array([0, 0, 0, 0, 1, 1, 1, 1.0])
    S, T = np.meshgrid([0, 1 / 3, 2 / 3, 1, 4 / 3, 5 / 3, 2], [0, 1 / 3, 2 / 3, 1], indexing="ij")
    bottom = 4.0 * np.maximum(S - 1.0, 0.0)
    sheet = Patch(1, make_bspline_surface(np.stack([S, bottom * (1 - T) + 2 * T, 0.3 * S * T], -1), ku, kv))
    rng = np.random.default_rng(3)
    u = np.concatenate([rng.uniform(0.5, 0.6, 50), rng.uniform(0.4, 0.5, 50)])
    v = rng.uniform(0.2, 0.8, 100)
    on = sheet.surface.evaluate(u, v)
    n = np.cross(sheet.surface.evaluate(u, v, du=1), sheet.surface.evaluate(u, v, dv=1))
    lift = rng.uniform(0.0, 0.05, 100)
    x = on + lift[:, None] * n / np.linalg.norm(n, axis=1)[:, None]
    for start_u in (np.where(u > 0.5, 0.45, 0.55), np.full(100, 0.5)):  # in the other piece, on the line
        uv, foot = _project(sheet, x, np.stack([start_u, v], -1))
        np.testing.assert_allclose(np.linalg.norm(foot - x, axis=1), lift, atol=1e-9)


def test_a_hollow_inside_the_rectangle_is_cut_out_not_the_whole_patch():
    # A 20 x 16 mm plate with a shallow trough along x = 1.875 (on a line of ring_grid's concavity
    # samples), concave radius just under the 3 mm ball at its bottom: the ball reaches every
    # contact (no lift), the concavity check finds the hollow, and the plan gives up the strip
    # holding it and finishes the rest, instead of losing the patch.
    from cam.plan.gouge import build_index
    from cam.spline.surface import clamped_uniform_knots, make_bspline_surface

    nu, nv = 161, 9
    ku, kv = clamped_uniform_knots(nu), clamped_uniform_knots(nv)
    gu = np.array([ku[i + 1:i + 4].mean() for i in range(nu)])  # Greville abscissae
    gv = np.array([kv[j + 1:j + 4].mean() for j in range(nv)])
    x, y = np.meshgrid(20 * gu, 16 * gv, indexing="ij")
    z = -0.11 * np.exp(-((x - 1.875) / 0.8) ** 2)  # radius 0.8² / 0.22 = 2.91 mm at the bottom
    plate = Patch(1, make_bspline_surface(np.stack([x, y, z], -1), ku, kv))
    # The plate lies in a setup's frame 5 mm along x and 10 mm up from the part's: the reason names the
    # hollow where the user's files have it.
    pp = plan_patch(plate, build_index([plate], spacing_mm=0.5), ToolParams(radius_mm=3.0),
                    ToolpathParams(scallop_height_mm=0.16), to_part=lambda x: x - np.array([5.0, 0.0, 10.0]))
    u0, u1, v0, v1 = pp.region
    assert 1.875 / 20 < u0 < 0.25 and (u1, v0, v1) == (1.0, 0.0, 1.0)
    assert pp.certified_scallop_mm <= 0.16 and pp.replans >= 1
    # The claim says why the rest is left: the hollow, not a neighbour the ball would touch.
    from cam.plan.patch_job import _claim

    assert pp.hollows and not pp.touched
    reason = _claim(plate.surface, pp, None)["reason"]
    assert reason.startswith("concave radius of curvature 2.9") and "neighbouring" not in reason
    assert "near [-3.125, " in reason and ", -10.1" in reason


@pytest.mark.parametrize("on", ["line", "next line"])
def test_a_hollow_between_the_concavity_samples_is_reported_where_a_ring_meets_it(on):
    # A 16 x 7 mm plate with a narrow trough along x, concave radius 2.6 mm at its bottom (under the
    # 3 mm ball) over a band 0.07 mm wide, halfway between two rows of check_concavity's 33 x 33 grid
    # (0.219 mm apart): the grid misses it. A ring's line that runs along the trough, or the next line
    # a step lands on, has no scallop relation there; the step names the hollow and where it lies on
    # the line (so plan_patch can cut it out), instead of giving up the patch as degenerate.
    from cam.plan.grid import side_step
    from cam.spline.surface import clamped_uniform_knots, make_bspline_surface

    nu, nv, width, height = 9, 201, 16.0, 7.0
    ku, kv = clamped_uniform_knots(nu), clamped_uniform_knots(nv)
    gu = np.array([ku[i + 1:i + 4].mean() for i in range(nu)])  # Greville abscissae
    gv = np.array([kv[j + 1:j + 4].mean() for j in range(nv)])
    x, y = np.meshgrid(width * gu, height * gv, indexing="ij")
    v_trough = 12.5 / 32
    z = -0.004 * np.exp(-((y - height * v_trough) / 0.14) ** 2)
    plate = Patch(1, make_bspline_surface(np.stack([x, y, z], -1), ku, kv))
    check_concavity(plate, 3.0)  # does not raise
    fixed, start = (v_trough, None) if on == "line" else (0.2, v_trough - 0.2)
    with pytest.raises(TooConcave) as err:
        side_step(plate, along="u", fixed=fixed, lo=0.0, hi=1.0, direction=1.0, limit=1.0, r=3.0, h=0.144,
                  samples=32, start=start)
    assert 2.4 < err.value.radius_mm < 3.0 and "use a smaller ball" in str(err.value)
    assert len(err.value.uv) >= 32 and np.all(err.value.uv[:, 1] == pytest.approx(v_trough, abs=1e-12))
    assert err.value.point[1] == pytest.approx(height * v_trough, abs=1e-6)


def test_patches_planned_in_two_processes_give_the_same_program():
    trough = analytic.cylinder(20.0, 12.0, 50.0)
    args = ([7, 8], [trough, analytic.plane(10, 10, z=-5.0)], EYE, ToolParams(radius_mm=3.0),
            ToolpathParams(scallop_height_mm=0.16))
    one, two = plan_patches(*args), plan_patches(*args, processes=2)
    assert [u["patch"] for u in one.unmachined] == [u["patch"] for u in two.unmachined]
    assert one.partial == two.partial
    for a, b in zip(one.setups, two.setups, strict=True):
        assert write_program(a.moves, header={}) == write_program(b.moves, header={})
        assert [pp.patch for pp in a.patches] == [pp.patch for pp in b.patches]
