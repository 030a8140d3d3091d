"""Benchmark the fit stage on the CAD test meshes: deviation per patch, C0 gap, control points, time.

    python bench/fit.py [--data ../shared/data] [--out bench/results] [--meshes fandisk_tgvresult,block_tgvresult]
                        [--layouts quadriflow,creases]

Each mesh is scaled ×10 to mm and taken through the pipeline's own stage code, as
`cloud2cnc run` does (remesh → segment → fit, each a worker stage called with a
StageContext; the MeshTGV authors' denoised meshes stand in for reconstruct + denoise), once per quad layout
(`remesh.layout`) named in --layouts.
It needs the remesh and segment stages: without them it says so and exits 2,
writing nothing. Writes ``fit.md`` (tables, the machine) and ``fit-<mesh>.png``
(the surfaces coloured by their distance from the mesh) into the output folder.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from machine_info import describe_machine  # bench/ is on the path when a script runs

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

MESHES = ("fandisk_tgvresult", "block_tgvresult")


def missing_stages() -> list[str]:
    return [name for name in ("worker.stages.remesh", "worker.stages.segment")
            if importlib.util.find_spec(name) is None]


def run_stage(run, name: str, work: Path, inputs: dict[str, Path], params: dict) -> tuple[dict[str, Path], float]:
    """Run one worker stage on `inputs` with `params` (a JobParams dump, validated here, as the runner does)."""
    from core.params import JobParams
    from worker.context import StageContext

    out_dir = work / name
    out_dir.mkdir(parents=True, exist_ok=True)
    ctx = StageContext(job_id="bench", stage=name, inputs=inputs, out_dir=out_dir,
                       params=JobParams.model_validate(params), settings={})
    t0 = time.perf_counter()
    outputs = run(ctx)
    return outputs, time.perf_counter() - t0


def job_params() -> dict:
    try:
        from core.params import JobParams

        return JobParams().model_dump()
    except Exception:  # the bench runs the stages' own defaults when JobParams lacks a group
        return {}


def bench_mesh(name: str, data: Path, work: Path, params: dict | None = None) -> dict:
    """remesh → segment → fit on `name` ×10 with `params` (a JobParams dump; the defaults when None)."""
    from cam.io import read_obj, write_ply_mesh
    from worker.stages.fit import run_fit
    from worker.stages.remesh import run_remesh
    from worker.stages.segment import run_segment

    raw = read_obj(data / f"{name}.obj")
    mesh_ply = write_ply_mesh(work / "mesh.ply", raw.points * 10.0, raw.faces)
    params = job_params() if params is None else params
    remesh_out, t_remesh = run_stage(run_remesh, "remesh", work, {"mesh.ply": mesh_ply}, params)
    seg_out, t_seg = run_stage(run_segment, "segment", work, {"quads.obj": remesh_out["quads.obj"]}, params)
    fit_out, t_fit = run_stage(run_fit, "fit", work, {"quads.obj": remesh_out["quads.obj"],
                                                      "patches.json": seg_out["patches.json"], "mesh.ply": mesh_ply},
                               params)
    doc = json.loads(Path(fit_out["surfaces.json"]).read_text())
    return {"name": name, "doc": doc, "times": (t_remesh, t_seg, t_fit), "mesh": (raw.points * 10.0, raw.faces),
            "igs": Path(fit_out["surfaces.igs"]).stat().st_size,
            "remesh": json.loads(Path(remesh_out["remesh.json"]).read_text())}


def sampled_distances(doc: dict, mesh: tuple[np.ndarray, np.ndarray], n: int = 25) -> list[np.ndarray]:
    """Per surface, the distance (mm) to the mesh on an n x n grid of parameters."""
    from cam.mesh.closest import closest_points, mesh_index
    from cam.spline.surface import surface_from_json

    index = mesh_index(*mesh)
    t = np.linspace(0, 1, n)
    uu, vv = np.meshgrid(t, t, indexing="ij")
    out = []
    for entry in doc["surfaces"]:
        P = surface_from_json(entry).evaluate(uu, vv)
        out.append(closest_points(index, P.reshape(-1, 3))[1].reshape(n, n))
    return out


def worst_at(d: np.ndarray) -> str:
    """Whether a surface's largest distance is on its outer ring of samples (its border) or inside."""
    i, j = np.unravel_index(np.argmax(d), d.shape)
    return "border" if min(i, j, d.shape[0] - 1 - i, d.shape[1] - 1 - j) == 0 else "inside"


def render(path: Path, doc: dict, distances: list[np.ndarray], title: str, vmax: float) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    from cam.spline.surface import surface_from_json

    polys, values = [], []
    for entry, d in zip(doc["surfaces"], distances):
        n = d.shape[0]
        t = np.linspace(0, 1, n)
        uu, vv = np.meshgrid(t, t, indexing="ij")
        P = surface_from_json(entry).evaluate(uu, vv)
        for i in range(n - 1):
            for j in range(n - 1):
                polys.append([P[i, j], P[i + 1, j], P[i + 1, j + 1], P[i, j + 1]])
                values.append(max(d[i, j], d[i + 1, j], d[i + 1, j + 1], d[i, j + 1]))
    fig = plt.figure(figsize=(7, 6))
    ax = fig.add_subplot(111, projection="3d")
    cmap = plt.get_cmap("viridis")
    colors = cmap(np.clip(np.asarray(values) / vmax, 0, 1))
    ax.add_collection3d(Poly3DCollection(polys, facecolors=colors, edgecolors="none"))
    pts = np.concatenate([np.asarray(p) for p in polys])
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    c, r = (lo + hi) / 2, (hi - lo).max() / 2
    ax.set_xlim(c[0] - r, c[0] + r)
    ax.set_ylim(c[1] - r, c[1] + r)
    ax.set_zlim(c[2] - r, c[2] + r)
    ax.set_title(title)
    sm = plt.cm.ScalarMappable(cmap=cmap, norm=plt.Normalize(0, vmax))
    fig.colorbar(sm, ax=ax, shrink=0.6, label="surface to mesh (mm)")
    fig.savefig(path, dpi=110, bbox_inches="tight")
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", default=str(ROOT.parent / "shared" / "data"))
    ap.add_argument("--out", default=str(ROOT / "bench" / "results"))
    ap.add_argument("--meshes", default=",".join(MESHES))
    ap.add_argument("--layouts", default="quadriflow,creases", help="remesh.layout values, each a run per mesh")
    args = ap.parse_args(argv)
    missing = missing_stages()
    if missing:
        print(f"bench/fit.py needs the remesh and segment stages, missing: {', '.join(missing)}; nothing written")
        return 2
    data, out = Path(args.data), Path(args.out)
    if not data.is_dir():
        print(f"no test meshes at {data}; nothing written")
        return 2
    out.mkdir(parents=True, exist_ok=True)
    header = describe_machine()
    results = []
    for name in args.meshes.split(","):
        for layout in args.layouts.split(","):
            params = job_params()
            params.setdefault("remesh", {})["layout"] = layout
            with tempfile.TemporaryDirectory() as tmp:
                print(f"{name}, {layout} layout: remesh, segment, fit ...", flush=True)
                result = bench_mesh(name, data, Path(tmp), params)
                results.append({**result, "name": f"{name} ({layout})"})
    lines = ["# Fit benchmark", "",
             "`python bench/fit.py` — the CAD test meshes ×10 (mm) through the pipeline's remesh, segment and fit "
             "stage code with default parameters but `remesh.layout`, once with QuadriFlow's layout and once with "
             "the crease-first one, as the mesh's name says (the MeshTGV authors' denoised meshes stand in for our "
             "reconstruct + denoise output). Deviation is measured both ways between each fitted surface and the "
             "denoised triangle mesh: mesh samples (vertices and face centroids) to the surfaces, and points of the "
             "surface to the mesh; `max` is the larger of the two.", "", f"Machine: {header}.", ""]
    lines += ["| mesh | patches | over tolerance | tolerance (mm) | max C0 gap (mm) | worst patch max (mm) | "
              "median patch max (mm) | mean of means (mm) | control points | remesh (s) | segment (s) | fit (s) | "
              "surfaces.igs (kB) |", "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for r in results:
        s = r["doc"]["surfaces"]
        mx = np.array([e["max_error_mm"] for e in s])
        mean = np.array([e["mean_error_mm"] for e in s])
        cps = sum(len(e["control_points"]) * len(e["control_points"][0]) for e in s)
        t = r["times"]
        lines.append(f"| {r['name']} | {len(s)} | {len(r['doc']['over_tolerance'])} | {r['doc']['tolerance_mm']} | "
                     f"{r['doc']['max_c0_gap_mm']:.1e} | {mx.max():.4f} | {np.median(mx):.4f} | {mean.mean():.5f} | "
                     f"{cps} | {t[0]:.1f} | {t[1]:.1f} | {t[2]:.1f} | {r['igs'] / 1024:.0f} |")
    for r in results:
        distances = sampled_distances(r["doc"], r["mesh"])
        # The fit's own report of where each patch's largest error is, and how far from a crease of the mesh.
        near = [float("inf") if e.get("worst_crease_mm") is None else e["worst_crease_mm"]
                for e in r["doc"]["surfaces"]]
        bad = [worst_at(d) for e, d in zip(r["doc"]["surfaces"], distances) if not e["within_tolerance"]]
        by_crease = len(r["doc"]["at_crease"])
        lines += ["", f"## {r['name']}: per patch", "",
                  f"Of the {len(bad)} patches over tolerance, {bad.count('border')} have their "
                  "largest surface-to-mesh distance on their border (where the boundary curves are) and "
                  f"{bad.count('inside')} inside; {by_crease} have their largest error within twice "
                  "its size of a crease of the mesh (`crease`: `worst_crease_mm`, how far the point where `max` is "
                  "lies from one; the surface cuts or misses a crease there).",
                  "", "| patch | quads (rows × cols) | max (mm) | mean (mm) | surface→mesh (mm) | worst at | "
                  "crease (mm) | boundary curve (mm) | control points | refinements | within tolerance |",
                  "|---:|---:|---:|---:|---:|---|---:|---:|---:|---:|---|"]
        for e, d, c in zip(r["doc"]["surfaces"], distances, near):
            cp = f"{len(e['control_points'])}×{len(e['control_points'][0])}"
            quads = f"{e.get('rows')}×{e.get('cols')}"
            lines.append(f"| {e['patch']} | {quads} | {e['max_error_mm']:.4f} | {e['mean_error_mm']:.5f} | "
                         f"{e['surface_to_mesh_mm']:.4f} | {worst_at(d)} | {c:.3f} | {e['boundary_error_mm']:.4f} | "
                         f"{cp} | {e['refinements']} | {'yes' if e['within_tolerance'] else '**no**'} |")
        if r["doc"].get("skipped"):
            lines.append("")
            lines += [f"- skipped patch {x['patch']}: {x['reason']}" for x in r["doc"]["skipped"]]
        png = f"fit-{r['name'].replace(' (', '-').rstrip(')')}.png"
        render(out / png, r["doc"], distances, f"{r['name']}: surface to mesh (mm)", 2 * r["doc"]["tolerance_mm"])
        lines += ["", f"![{r['name']}]({png})"]
    md = out / "fit.md"
    # A hand-written "## Notes" section (analysis of a run) survives a rerun of the tables.
    notes = md.read_text().partition("\n## Notes")[2] if md.exists() else ""
    md.write_text("\n".join(lines) + "\n" + (f"\n## Notes{notes}" if notes else ""))
    print(md.read_text())
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
