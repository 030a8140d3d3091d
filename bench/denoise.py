"""Benchmark of the ``denoise`` stage (cam.denoise.mesh_tgv, MeshTGV) on a corpus of noisy meshes.

Usage: python bench/denoise.py [--data DIR] [--out bench/results] [--no-picture]

Reads ``{fandisk,block,kinect_cone}_{noisy,gt,tgvresult}.obj`` from ../shared/data (not part of the
project; the files are never copied) and makes more noisy meshes from the clean ones (``CORPUS``
below: Gaussian noise of a stated share of the mean edge length along the vertex normals or in every
direction, impulsive noise, analytic shapes; ``CAD_NOISE``: the reconstruction bench's ABC and CSG parts,
remeshed to even triangles, with noise). Each mesh is marked ``tuned`` (its results were looked
at while the automatic weights were chosen) or ``held out`` (run only after they were fixed). Runs

  * ours: ``denoise_mesh`` with its defaults, i.e. weights chosen from the measured noise (and on
    Fandisk and Block once more with ``flip_repair_rounds=0``, i.e. the paper's vertex update alone,
    to show what the folded-face repair contributes);
  * ours before the automatic weights: alpha0=0.15, alpha1=0.4 scaled by min(1, median dihedral /
    15 deg), the defaults until then, set by hand;
  * MeshLab's two-step smoothing (pymeshlab ``apply_coord_two_steps_smoothing``, its defaults), the
    baseline of issue 36;
  * a classic baseline, bilateral normal filtering (Zheng, Fu, Au, Tai, "Bilateral normal filtering
    for mesh denoising", IEEE TVCG 2011, local iterative scheme) implemented below, followed by the
    same vertex update (no repair);
  * the MeshTGV authors' own result mesh (``*_tgvresult.obj``) and the figures from the data README;

and measures the mean angle (degrees) between face normals and the clean mesh's face normals, for the
filtered normals and for the normals of the output mesh, plus wall time. Writes
``denoise.md`` (tables), ``denoise.png`` (noisy / ours / authors for the three shared meshes) and
``denoise-worst.png`` (noisy / ours / two-step where ours is furthest from two-step's error) into --out.
"""

from __future__ import annotations

import argparse
import os
import platform
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import scipy.sparse as sp
import trimesh
from machine_info import cpu_model  # bench/ is on the path when a script runs

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from cam.denoise import denoise_mesh
from cam.params import DenoiseParams

AUTHORS = {  # from ../shared/data/README.md: (filtered normals, normals of their result mesh or None)
    "fandisk": (2.2046, 2.07),
    "block": (1.8801, 2.85),
    "kinect_cone": (6.96132, None),
}
#: The weights before they followed the noise (hand-set now): what "before" measures.
BEFORE = {"alpha0": 0.15, "alpha1": 0.4, "noise_reference_deg": 15.0, "vertex_iterations": 20}

#: name: (set, how it is made). "tuned": looked at while choosing the automatic weights (cam/denoise/
#: weights.py); "held out": first run after they were fixed, never tuned on.
CORPUS = {
    "fandisk": ("tuned", "shared noisy file (synthetic Gaussian noise)"),
    "kinect_cone": ("tuned", "shared noisy file (real Kinect scan)"),
    "fandisk-n0.5": ("tuned", "Fandisk + Gaussian 0.5 mean edge lengths along the normals (seed 1)"),
    "fandisk-n0.1": ("tuned", "Fandisk + Gaussian 0.1 mean edge lengths along the normals (seed 2)"),
    "block": ("held out", ("shared noisy file (synthetic Gaussian noise); the base weights 0.15 / 0.4 were "
              "tuned on it and Fandisk before this work")),
    "fandisk-n0.7": ("held out", ("Fandisk + Gaussian 0.7 mean edge lengths along the normals (seed 0): "
                     "issue 36's heavy-noise CAD mesh")),
    "block-n0.7": ("held out", "Block + Gaussian 0.7 mean edge lengths along the normals (seed 0)"),
    "block-i0.3": ("held out", "Block + Gaussian 0.3 mean edge lengths on every coordinate (seed 4)"),
    "block-n0.05": ("held out", "Block + Gaussian 0.05 mean edge lengths along the normals (seed 7)"),
    "fandisk-impulse": ("held out", ("Fandisk, 10 % of the vertices moved 1 mean edge length along the "
                        "normal, either way (seed 6)")),
    "cube-n0.4": ("held out", ("unit cube (trimesh box, 4 subdivisions) + Gaussian 0.4 mean edge lengths "
                  "along the normals (seed 9)")),
    "sphere-n0.3": ("held out", ("icosphere (5 subdivisions) + Gaussian 0.3 mean edge lengths along the "
                    "normals (seed 5)")),
    "kinect_cone-n0.3": ("held out", ("the Kinect cone's reference surface + Gaussian 0.3 mean edge "
                         "lengths along the normals (seed 8): white noise on the real scan's shape")),
}
#: CAD parts of the reconstruction bench (the ABC parts scaled to 60 mm and the CSG parts it makes), remeshed
#: to even triangles as a scanner's mesh has them, with noise: name: (part, kind, share of the mean edge length,
#: seed); kind "n" along the vertex normals, "i" on every coordinate. All held out: added after the weight rule
#: was fixed, the levels and seeds chosen before the first run.
CAD_NOISE = {
    "abc1-n0.3": ("abc1", "n", 0.3, 11),
    "abc3-n0.5": ("abc3", "n", 0.5, 12),
    "abc4-n0.2": ("abc4", "n", 0.2, 13),
    "abc5-n0.3": ("abc5", "n", 0.3, 14),
    "abc7-i0.3": ("abc7", "i", 0.3, 15),
    "abc8-n0.7": ("abc8", "n", 0.7, 16),
    "abc9-n0.15": ("abc9", "n", 0.15, 17),
    "bracket-2-bosses-n0.4": ("bracket-2-bosses", "n", 0.4, 18),
    "pockets-fillet-n0.3": ("pockets-fillet", "n", 0.3, 19),
    "freeform-saddle-n0.5": ("freeform-saddle", "n", 0.5, 20),
}
#: Target edge length of the even remeshing, percent of the part's bounding-box diagonal.
CAD_EDGE_PERCENT = 1.0
CORPUS.update({
    name: ("held out", (
        f"{part} ({'the ABC part, scaled to 60 mm' if part.startswith('abc') else 'a CSG part'} of "
        f"bench/reconstruct.py), remeshed evenly (edges {CAD_EDGE_PERCENT:g} % of the diagonal, creases over 30 "
        f"deg kept) + Gaussian {share} mean edge lengths "
        f"{'along the normals' if kind == 'n' else 'on every coordinate'} (seed {seed})"))
    for name, (part, kind, share, seed) in CAD_NOISE.items()})


def face_normals(v, f):
    c = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    return c / np.linalg.norm(c, axis=1)[:, None]


def mean_angle(a, b) -> float:
    return float(np.degrees(np.arccos(np.clip(np.einsum("ij,ij->i", a, b), -1.0, 1.0))).mean())


def load(path: Path):
    m = trimesh.load(path, process=False)
    return np.asarray(m.vertices, dtype=np.float64), np.asarray(m.faces, dtype=np.int64)


def mean_edge_length(v, f) -> float:
    e = np.unique(np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1), axis=0)
    return float(np.linalg.norm(v[e[:, 0]] - v[e[:, 1]], axis=1).mean())


def _along_normals(v, f, share, seed):
    normals = trimesh.Trimesh(v, f, process=False).vertex_normals
    step = np.random.default_rng(seed).normal(scale=share * mean_edge_length(v, f), size=len(v))
    return v + step[:, None] * normals


def make(name: str, data: Path):
    """(noisy vertices, clean vertices, faces) of a corpus mesh."""
    if name in ("fandisk", "block", "kinect_cone"):
        vn, f = load(data / f"{name}_noisy.obj")
        vg, fg = load(data / f"{name}_gt.obj")
        assert np.array_equal(f, fg), "connectivity differs"
        return vn, vg, f
    if name == "cube-n0.4":
        box = trimesh.creation.box(extents=(1.0, 1.0, 1.0))
        for _ in range(4):
            box = box.subdivide()
        vg, f = np.asarray(box.vertices, float), np.asarray(box.faces, np.int64)
        return _along_normals(vg, f, 0.4, 9), vg, f
    if name == "sphere-n0.3":
        s = trimesh.creation.icosphere(subdivisions=5)
        vg, f = np.asarray(s.vertices, float), np.asarray(s.faces, np.int64)
        return _along_normals(vg, f, 0.3, 5), vg, f
    if name in CAD_NOISE:
        part, kind, share, seed = CAD_NOISE[name]
        vg, f = even_cad_part(part, data)
        if kind == "i":
            rng = np.random.default_rng(seed)
            return vg + rng.normal(scale=share * mean_edge_length(vg, f), size=vg.shape), vg, f
        return _along_normals(vg, f, share, seed), vg, f
    base, _, kind = name.partition("-")
    vg, f = load(data / f"{base}_gt.obj")
    if kind == "impulse":
        rng = np.random.default_rng(6)
        pick = rng.random(len(vg)) < 0.10
        normals = trimesh.Trimesh(vg, f, process=False).vertex_normals
        step = np.where(pick, rng.choice([-1.0, 1.0], size=len(vg)), 0.0) * mean_edge_length(vg, f)
        return vg + step[:, None] * normals, vg, f
    share = float(kind[1:])
    seeds = {"fandisk-n0.5": 1, "fandisk-n0.1": 2, "fandisk-n0.7": 0, "block-n0.7": 0, "block-n0.05": 7,
             "kinect_cone-n0.3": 8}
    if kind.startswith("i"):
        rng = np.random.default_rng(4)
        return vg + rng.normal(scale=share * mean_edge_length(vg, f), size=vg.shape), vg, f
    return _along_normals(vg, f, share, seeds[name]), vg, f


def even_cad_part(part: str, data: Path):
    """(vertices, faces) of a reconstruction-bench part remeshed to even triangles (MeshLab's isotropic
    remeshing, creases over 30 deg kept): CAD triangulations are slivers that no scanner makes."""
    import pymeshlab
    from reconstruct import CORPUS as PARTS  # bench/ is on the path when a script runs

    mesh = PARTS[part][0](data)
    if mesh is None:
        raise FileNotFoundError(f"{part}: its file is not under {data}")
    ms = pymeshlab.MeshSet()
    ms.add_mesh(pymeshlab.Mesh(vertex_matrix=np.asarray(mesh.vertices, dtype=np.float64),
                               face_matrix=np.asarray(mesh.faces, dtype=np.int32)))
    ms.meshing_isotropic_explicit_remeshing(targetlen=pymeshlab.PercentageValue(CAD_EDGE_PERCENT), featuredeg=30.0,
                                            iterations=10)
    out = ms.current_mesh()
    return np.asarray(out.vertex_matrix(), dtype=np.float64), np.asarray(out.face_matrix(), dtype=np.int64)


def two_step(v, f):
    """MeshLab's two-step smoothing with its defaults (normals smoothed, then vertices fitted to them)."""
    import pymeshlab

    ms = pymeshlab.MeshSet()
    ms.add_mesh(pymeshlab.Mesh(vertex_matrix=v, face_matrix=f.astype(np.int32)))
    ms.apply_coord_two_steps_smoothing()
    m = ms.current_mesh()
    assert np.array_equal(m.face_matrix(), f), "two-step changed the faces"
    return np.asarray(m.vertex_matrix(), dtype=np.float64)


# --- baseline: bilateral normal filtering + the same vertex update ----------------------------------
def bilateral_normal_filter(v, f, *, sigma_r=0.35, normal_iterations=20, vertex_iterations=20):
    """Zheng et al. 2011, local scheme: n_i <- normalize(sum_j A_j Ws(|c_i-c_j|) Wr(|n_i-n_j|) n_j)
    over the faces j sharing a vertex with i (i included); sigma_s = mean distance between the
    centroids of edge-adjacent faces. Then x_i += mean_f n_f (n_f . (c_f - x_i))."""
    m, n = len(f), len(v)
    inc = sp.csr_matrix((np.ones(3 * m), (f.ravel(), np.repeat(np.arange(m), 3))), shape=(n, m))
    pairs = (inc.T @ inc).tocoo()
    i, j = pairs.row, pairs.col
    c = v[f].mean(axis=1)
    nrm = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    area = 0.5 * np.linalg.norm(nrm, axis=1)
    N = nrm / (2 * area)[:, None]
    tm = trimesh.Trimesh(v, f, process=False)
    fa = tm.face_adjacency
    sigma_s = np.linalg.norm(c[fa[:, 0]] - c[fa[:, 1]], axis=1).mean()
    ws = area[j] * np.exp(-np.sum((c[i] - c[j]) ** 2, axis=1) / (2 * sigma_s**2))
    for _ in range(normal_iterations):
        wr = np.exp(-np.sum((N[i] - N[j]) ** 2, axis=1) / (2 * sigma_r**2))
        W = sp.csr_matrix((ws * wr, (i, j)), shape=(m, m))
        N = W @ N
        N /= np.linalg.norm(N, axis=1)[:, None]
    count = np.asarray(inc.sum(axis=1)).ravel()
    x = v.copy()
    for _ in range(vertex_iterations):
        cc = x[f].mean(axis=1)
        acc = np.zeros_like(x)
        for k in range(3):
            d = np.einsum("ij,ij->i", N, cc - x[f[:, k]])
            np.add.at(acc, f[:, k], N * d[:, None])
        x += acc / np.maximum(count, 1)[:, None]
    return x, N


# --- a small flat-shaded software renderer for the picture -----------------------------------------
def render(v, f, size=360, view=(1.0, 0.8, 0.6), up=(0.0, 0.0, 1.0)):
    from PIL import Image, ImageDraw

    w = np.asarray(view, float)
    w /= np.linalg.norm(w)
    u = np.cross(np.asarray(up, float), w)
    u /= np.linalg.norm(u)
    t = np.cross(w, u)
    ctr = v.mean(axis=0)
    p = (v - ctr) @ np.stack([u, t, w], axis=1)
    scale = 0.45 * size / np.max(np.abs(p[:, :2]))
    xy = np.stack([size / 2 + scale * p[:, 0], size / 2 - scale * p[:, 1]], axis=1)
    fn = face_normals(v, f)
    light = 0.6 * w + 0.5 * t + 0.3 * u
    light /= np.linalg.norm(light)
    shade = np.clip(fn @ light, 0, 1)
    facing = fn @ w > 0
    order = np.argsort(p[f, 2].mean(axis=1))  # far to near
    img = Image.new("RGB", (size, size), (255, 255, 255))
    draw = ImageDraw.Draw(img)
    for k in order:
        if not facing[k]:
            continue
        g = int(60 + 180 * shade[k])
        draw.polygon([tuple(xy[q]) for q in f[k]], fill=(g, g, int(g * 0.95) + 10))
    return img


def machine() -> dict:
    cpu = cpu_model()
    try:
        nproc = subprocess.run(["nproc"], check=False, capture_output=True, text=True).stdout.strip()
    except OSError:
        nproc = str(os.cpu_count())
    return {"nproc": nproc, "cpu": cpu, "python": platform.python_version(),
            "blas_threads": os.environ.get("OPENBLAS_NUM_THREADS", "unset")}


def _timed(fn, *args, **kwargs):
    t = time.perf_counter()
    out = fn(*args, **kwargs)
    return out, time.perf_counter() - t


def run_mesh(name: str, data: Path) -> dict:
    """Every method on one corpus mesh; errors in degrees, times in s."""
    vn, vg, f = make(name, data)
    truth = face_normals(vg, f)
    ours, t_ours = _timed(denoise_mesh, vn, f)
    before, t_before = _timed(denoise_mesh, vn, f, DenoiseParams(**BEFORE))
    xt, t_two = _timed(two_step, vn, f)
    (xb, nb), t_bil = _timed(bilateral_normal_filter, vn, f)
    row = {
        "mesh": name, "set": CORPUS[name][0], "faces": len(f),
        "noisy": mean_angle(face_normals(vn, f), truth),
        "noise": ours.report["noise"], "weights": ours.report["weights"],
        "ours_filtered": mean_angle(ours.face_normals, truth),
        "ours_mesh": mean_angle(face_normals(ours.vertices, f), truth),
        "before_filtered": mean_angle(before.face_normals, truth),
        "before_mesh": mean_angle(face_normals(before.vertices, f), truth),
        "two_step_mesh": mean_angle(face_normals(xt, f), truth),
        "bil_filtered": mean_angle(nb, truth), "bil_mesh": mean_angle(face_normals(xb, f), truth),
        "ours_time": t_ours, "before_time": t_before, "two_step_time": t_two, "bil_time": t_bil,
        "ours_iterations": ours.iterations, "ours_converged": ours.report["converged"],
        "ours_time_split": ours.report["time_s"], "folded": ours.report["folded_faces"],
        "vertices": (vn, ours.vertices, f), "two_step_vertices": xt,
    }
    if name in AUTHORS:
        va, fa = load(data / f"{name}_tgvresult.obj")
        assert np.array_equal(f, fa), "connectivity differs"
        row["authors_filtered"], row["authors_mesh_readme"] = AUTHORS[name]
        row["authors_mesh_measured"] = mean_angle(face_normals(va, f), truth)
        row["authors_vertices"] = va
    if name in ("fandisk", "block"):
        plain = denoise_mesh(vn, f, DenoiseParams(flip_repair_rounds=0))
        row["ours_plain_mesh"] = mean_angle(face_normals(plain.vertices, f), truth)
        clean = denoise_mesh(vg, f)  # what the filter does to noise-free input
        clean_full = denoise_mesh(vg, f, DenoiseParams(alpha0=0.15, alpha1=0.4))  # full weights, by hand
        row["clean_filtered"] = mean_angle(clean.face_normals, truth)
        row["clean_mesh"] = mean_angle(face_normals(clean.vertices, f), truth)
        row["clean_full_filtered"] = mean_angle(clean_full.face_normals, truth)
        row["clean_full_mesh"] = mean_angle(face_normals(clean_full.vertices, f), truth)
        clean_before = denoise_mesh(vg, f, DenoiseParams(**BEFORE))
        row["clean_before_filtered"] = mean_angle(clean_before.face_normals, truth)
        row["clean_before_mesh"] = mean_angle(face_normals(clean_before.vertices, f), truth)
        row["clean_noise"] = clean.report["noise"]
        row["clean_weights"] = clean.report["weights"]
    return row


def halves_table(rows: list[dict]) -> list[str]:
    """Both halves of the corpus at a glance: against two-step and, where they exist, the MeshTGV authors."""
    lines = [("| set | meshes | ours below two-step (result mesh) | median ours / two-step | worst ours / two-step | "
              "ours at or below the authors (filtered normals) |"), "|---|---:|---:|---:|---:|---|"]
    for half in ("tuned", "held out"):
        part = [r for r in rows if r["set"] == half]
        if not part:
            continue
        ratio = np.array([r["ours_mesh"] / r["two_step_mesh"] for r in part])
        authors = [f"{r['mesh']} {r['ours_filtered']:.2f} vs {r['authors_filtered']:.2f}"
                   f" {'yes' if r['ours_filtered'] <= r['authors_filtered'] else 'NO'}"
                   for r in part if "authors_filtered" in r]
        below = sum(r["ours_mesh"] < r["two_step_mesh"] for r in part)
        lines.append(f"| {half} | {len(part)} | {below} of {len(part)} | {np.median(ratio):.2f} | {ratio.max():.2f} | "
                     f"{'; '.join(authors) or '–'} |")
    return lines


#: The previous committed table (alpha0=0.15, alpha1=0.4 scaled by the median dihedral), filtered / mesh.
PREVIOUS = {"fandisk": (1.8141, 1.6381), "block": (1.7794, 1.6952)}


def notes(rows: list[dict]) -> list[str]:
    """The Notes section: what changed, before and after, the tuning split, times."""
    by = {r["mesh"]: r for r in rows}
    k = by["kinect_cone"]
    tuned = [r["mesh"] for r in rows if r["set"] == "tuned"]
    held = [r["mesh"] for r in rows if r["set"] == "held out"]
    worse_than_two_step = [r["mesh"] for r in rows if r["ours_mesh"] >= r["two_step_mesh"]]
    r_two = [r["ours_time"] / r["two_step_time"] for r in rows]
    r_bil = [r["ours_time"] / r["bil_time"] for r in rows]
    r_before = [r["ours_time"] / r["before_time"] for r in rows]
    t_noise = [r["ours_time_split"]["noise_estimate"] / r["ours_time"] for r in rows]
    lines = [
        "## Notes",
        "",
        ("What changed (issue 36, \"denoising whose strength follows the noise\"): alpha0 and alpha1 are "
         "unset by default and chosen from two numbers measured on the input: sigma, the robust (median) "
         "spread of each vertex about a quadric fitted over its 2-ring, in mean edge lengths, and the "
         "ratio of the same over 3 rings, which is about 1 for white noise and grows when neighbouring "
         "vertices move together. White noise: alpha1 grows as sigma^1.3 above the band (0.18-0.26) where "
         "the old weights 0.15 / 0.4 were tuned and falls below it (alpha0 falls, never rises); correlated "
         "noise (ratio over 1.3; a ramp from 1.2): alpha0 0.6, alpha1 1.0. A weight set by hand is used "
         "as given; `denoise.json` reports `noise` and `weights` (the weights used, where each came from, "
         "and what the noise alone would have chosen). The numbers and the sweeps behind them are in "
         "`cam/denoise/weights.py`."),
        "",
        "Before -> after, filtered / mesh (before: the old defaults, run here in the same run): "
        + "; ".join(f"{r['mesh']} {r['before_filtered']:.2f} / {r['before_mesh']:.2f} -> "
                    f"{r['ours_filtered']:.2f} / {r['ours_mesh']:.2f}" for r in rows)
        + ". The previous committed table had Fandisk "
        + f"{PREVIOUS['fandisk'][0]} / {PREVIOUS['fandisk'][1]} and Block {PREVIOUS['block'][0]} / "
        + f"{PREVIOUS['block'][1]}.",
        "",
        (f"The Kinect cone: {k['ours_filtered']:.2f} deg for the filtered normals against the authors' "
         f"{k['authors_filtered']:.2f} (issue 36's target: at or below 6.96) "
         f"{'- reached' if k['ours_filtered'] <= 6.96 else '- NOT reached'}; the normals of our result "
         f"mesh, {k['ours_mesh']:.2f} ({k['weights']['vertex_iterations']} vertex-update iterations, chosen "
         f"for correlated noise; {k['folded']['after_repair']} faces stay folded), "
         f"{'at or below' if k['ours_mesh'] <= k['authors_mesh_measured'] else 'above'} those of the "
         f"authors' result mesh measured here ({k['authors_mesh_measured']:.2f}). Issue 36 quotes 7.95 (ours) and 6.17 "
         "(authors) for this mesh; this bench, which measures per face and unweighted as the authors do, "
         f"gives {k['before_filtered']:.2f} / {k['before_mesh']:.2f} for the old defaults and "
         f"{k['authors_mesh_measured']:.2f} for the authors' mesh: the issue's figures were measured "
         "some other way and are not reproduced here."),
        "",
        ("Tuned on: " + ", ".join(tuned) + " (and the Kinect cone's reference surface with white noise of "
         "0.15 mean edge lengths, to tell the scan's noise from its shape; not in the table). Held out: "
         + ", ".join(held) + ": run for the first time after the weight rule was fixed; no constant was "
         "changed after. One code change came after that first run: a floor of 1e-6 on the chosen weights "
         "was removed (it moved a clean cube's vertices in a test); it changes no weight in this table. "
         "Block is held out from the new rule, but the base weights 0.15 / 0.4 were tuned on it (with "
         "Fandisk) before this work."),
        "",
        ("The vertex update's iterations (20 for white noise, 300 for correlated noise at the Kinect cone's "
         "level, `cam/denoise/weights.py`) were swept on the tuned half only (the Kinect cone, Fandisk with "
         "its three noise levels). Meshes given more than 20 here: "
         + (", ".join(f"{r['mesh']} ({r['set']}, {r['weights']['vertex_iterations']})" for r in rows
                      if r["weights"]["vertex_iterations"] != 20) or "none")
         + "; every other mesh's result is the same as with 20. Of the clean meshes below: "
         + (", ".join(f"{r['mesh']} ({r['clean_weights']['vertex_iterations']})" for r in rows
                      if "clean_weights" in r and r["clean_weights"]["vertex_iterations"] != 20) or "none")
         + "."),
        "",
        ("Below MeshLab's two-step smoothing (its defaults, not tuned per mesh) on every mesh: "
         + ("yes." if not worse_than_two_step else "no, not on " + ", ".join(worse_than_two_step) + ".")
         + f" Issue 36's heavy-noise CAD mesh (fandisk-n0.7): {by['fandisk-n0.7']['ours_mesh']:.2f} deg "
         f"against two-step's {by['fandisk-n0.7']['two_step_mesh']:.2f} (before: "
         f"{by['fandisk-n0.7']['before_mesh']:.2f})."),
        "",
        ("CAD parts (`CAD_NOISE`, added when the corpus grew from 13 to 23 meshes; all held out, their noise levels "
         "and seeds set before their first run, nothing tuned after it), result mesh against two-step, degrees: "
         + "; ".join(f"{r['mesh']} {r['ours_mesh']:.2f} vs {r['two_step_mesh']:.2f}"
                     + (f" ({r['folded']['after_repair']} faces stay folded)" if r['folded']['after_repair'] > 20
                        else "") for r in rows if r["mesh"] in CAD_NOISE)
         + ". abc5, a plate under 3 mm thick with narrow grooves across it, keeps the most faces folded (along the "
         "grooves' edges in the worst-three picture); why was not looked into."),
        "",
        (f"Time: ours / two-step {min(r_two):.0f}-{max(r_two):.0f} x, ours / bilateral "
         f"{min(r_bil):.1f}-{max(r_bil):.1f} x, ours / before {min(r_before):.2f}-{max(r_before):.2f} x "
         "(the 100 filter iterations dominate either way and vary with the load of this shared machine); the "
         f"noise estimate is {100 * min(t_noise):.0f}-{100 * max(t_noise):.0f} % of our time."),
        "",
        ("Noticed, left alone: the estimate reads the Fandisk meshes' normal-direction noise of 0.25 and "
         f"0.7 mean edge lengths as {by['fandisk']['noise']['sigma']:.2f} and "
         f"{by['fandisk-n0.7']['noise']['sigma']:.2f} (within 4 % on a plane and a sphere up to 0.5, "
         "`tests/cam/test_denoise_noise.py`): at heavy noise on a small-featured part the quadrics absorb "
         "part of it; the weights were tuned on the estimate as it reads, so this is folded into them. The "
         "clean meshes, filtered / mesh, before -> after: "
         + "; ".join(f"{n} {by[n]['clean_before_filtered']:.3f} / {by[n]['clean_before_mesh']:.3f} -> "
                     f"{by[n]['clean_filtered']:.3f} / {by[n]['clean_mesh']:.3f}" for n in ("fandisk", "block"))
         + " (the weights read from a clean mesh's sigma differ from the old dihedral scaling's, both "
         "tiny)."),
    ]
    return lines


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, default=REPO.parent / "shared" / "data")
    ap.add_argument("--out", type=Path, default=REPO / "bench" / "results")
    ap.add_argument("--no-picture", action="store_true")
    args = ap.parse_args()
    if not (args.data / "fandisk_noisy.obj").exists():
        print(f"test meshes not found under {args.data}", file=sys.stderr)
        return 2
    args.out.mkdir(parents=True, exist_ok=True)
    mach = machine()
    load_before = os.getloadavg()
    rows = []
    for name in CORPUS:
        rows.append(run_mesh(name, args.data))
        r = rows[-1]
        print({k: v for k, v in r.items() if k not in ("vertices", "authors_vertices", "two_step_vertices")},
              flush=True)
    load_after = os.getloadavg()
    by = {r["mesh"]: r for r in rows}

    lines = [
        "# Denoising benchmark (MeshTGV, `cam.denoise.mesh_tgv`)",
        "",
        "Generated by `python bench/denoise.py`. Mean angle in degrees between face normals and the",
        "clean mesh's face normals (per face, unweighted, as the MeshTGV authors measure); lower is better.",
        "",
        (f"Machine: {mach['nproc']} CPUs ({mach['cpu']}), Python {mach['python']}, "
         f"OPENBLAS_NUM_THREADS={mach['blas_threads']}; load average before/after "
         f"{load_before[0]:.1f}/{load_after[0]:.1f} (a shared machine: other jobs ran at the same time)."),
        "",
        ("Ours: the defaults, alpha0, alpha1 and vertex_iterations unset, so chosen from the noise measured on the mesh "
         "(`cam/denoise/noise.py`, `cam/denoise/weights.py`); the other parameters: "
         + ", ".join(f"{k}={v}" for k, v in DenoiseParams().model_dump(exclude={"enabled"}).items()
                     if v is not None and k not in ("alpha0", "alpha1", "noise_reference_deg")) + ". "
         "Before: the defaults until the weights were chosen from the noise, alpha0=0.15, alpha1=0.4 scaled by "
         "min(1, median dihedral / 15 deg), set by hand, and 20 vertex-update iterations. Noise sigma: the estimate's, in mean edge lengths (2-ring quadric fits); "
         "correlation: its 3-ring over 2-ring ratio."),
        "",
        "## The corpus",
        "",
        ("| mesh | set | how it is made | faces | noisy input | noise sigma / correlation | weights chosen "
         "(alpha0 / alpha1) | ours: filtered | ours: mesh | before: filtered | before: mesh | two-step: mesh | "
         "bilateral: mesh | MeshTGV authors: filtered (README) / mesh (measured here) |"),
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        nz, w = r["noise"], r["weights"]
        best = min(r["ours_mesh"], r["ours_filtered"]) < r["two_step_mesh"]
        authors = (f"{r['authors_filtered']:.2f} / {r['authors_mesh_measured']:.2f}"
                   if "authors_filtered" in r else "–")
        lines.append(
            f"| {r['mesh']} | {r['set']} | {CORPUS[r['mesh']][1]} | {r['faces']} | {r['noisy']:.2f} | "
            f"{nz['sigma']:.3f} / {nz['correlation']:.2f} | {w['alpha0']:.3g} / {w['alpha1']:.3g} | "
            f"**{r['ours_filtered']:.2f}** | **{r['ours_mesh']:.2f}** | {r['before_filtered']:.2f} | "
            f"{r['before_mesh']:.2f} | {r['two_step_mesh']:.2f}{'' if best else ' (better than ours)'} | "
            f"{r['bil_mesh']:.2f} | {authors} |")
    lines += ["", *halves_table(rows)]
    lines += [
        "",
        ("| mesh | ours: wall time (s) | before (s) | two-step (s) | bilateral (s) | time ratio ours / "
         "two-step | ours / bilateral | outer iterations | converged | setup / factor / iterate / vertex "
         "update (s) | noise estimate (s) | folded faces after update -> after repair |"),
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        ts = r["ours_time_split"]
        lines.append(
            f"| {r['mesh']} | {r['ours_time']:.2f} | {r['before_time']:.2f} | {r['two_step_time']:.2f} | "
            f"{r['bil_time']:.2f} | {r['ours_time'] / r['two_step_time']:.0f} | "
            f"{r['ours_time'] / r['bil_time']:.1f} | {r['ours_iterations']} | {r['ours_converged']} | "
            f"{ts['setup']:.2f} / {ts['factorization']:.2f} / {ts['normal_iterations']:.2f} / "
            f"{ts['vertex_update']:.2f} | {ts['noise_estimate']:.2f} | "
            f"{r['folded']['after_update']} -> {r['folded']['after_repair']} |")
    lines += [
        "",
        "## Fandisk and Block: the folded-face repair and clean input",
        "",
        ("| mesh | ours: mesh | ours: mesh, paper's vertex update only | authors: filtered (README) | "
         "authors: mesh (README) | authors: mesh (measured here) | ours on the clean mesh, filtered / mesh: "
         "default (noise sigma read there) | full weights 0.15 / 0.4 set by hand |"),
        "|---|---|---|---|---|---|---|---|",
    ]
    for name in ("fandisk", "block"):
        r = by[name]
        lines.append(
            f"| {name} | {r['ours_mesh']:.4f} | {r['ours_plain_mesh']:.4f} | {r['authors_filtered']:.4f} | "
            f"{r['authors_mesh_readme']:.2f} | {r['authors_mesh_measured']:.4f} | "
            f"{r['clean_filtered']:.3f} / {r['clean_mesh']:.3f} (sigma {r['clean_noise']['sigma']:.4f}, "
            f"weights {r['clean_weights']['alpha0']:.2g} / {r['clean_weights']['alpha1']:.2g}) | "
            f"{r['clean_full_filtered']:.3f} / {r['clean_full_mesh']:.3f} |")
    worst = sorted(rows, key=lambda r: -r["ours_mesh"] / r["two_step_mesh"])[:3]
    lines += ["", *notes(rows), "", "![noisy / ours / authors](denoise.png)", "",
              ("Picture: each row noisy input, ours (defaults), the MeshTGV authors' result mesh; Fandisk, Block, "
              "the Kinect cone."), "", "![noisy / ours / two-step](denoise-worst.png)", "",
              ("Worst three (ours against two-step, result meshes): each row noisy input, ours, two-step; "
               + ", ".join(f"{r['mesh']} ({r['ours_mesh']:.2f} against {r['two_step_mesh']:.2f} deg)" for r in worst)
               + ".")]
    (args.out / "denoise.md").write_text("\n".join(lines) + "\n")
    if not args.no_picture:
        from PIL import Image

        views = {"fandisk": ((1.0, -0.9, 0.7), (0.0, 1.0, 0.0)), "block": ((1.0, 0.8, 0.9), (0.0, 0.0, 1.0)),
                 "kinect_cone": ((0.3, 0.4, 1.0), (0.0, 1.0, 0.0))}
        tiles = []
        for name, (view, up) in views.items():
            vn, vo, f = by[name]["vertices"]
            tiles.append([render(x, f, view=view, up=up) for x in (vn, vo, by[name]["authors_vertices"])])
        s = tiles[0][0].size[0]
        sheet = Image.new("RGB", (3 * s, len(tiles) * s), (255, 255, 255))
        for r_, row in enumerate(tiles):
            for c_, img in enumerate(row):
                sheet.paste(img, (c_ * s, r_ * s))
        sheet.save(args.out / "denoise.png")
        sheet = Image.new("RGB", (3 * s, len(worst) * s), (255, 255, 255))
        for r_, r in enumerate(worst):
            vn, vo, f = r["vertices"]
            for c_, x in enumerate((vn, vo, r["two_step_vertices"])):
                sheet.paste(render(x, f), (c_ * s, r_ * s))
        sheet.save(args.out / "denoise-worst.png")
    print((args.out / "denoise.md").read_text())
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
