"""The bench's own check of finishing programs against the true part; it shares no code with `cam`.

It reads the G-code with pygcode (bench-only, GPL), sweeps a ball of radius r along every move (ball
centre = tip + r·Z, in the machine frame of the program's setup) and measures on samples of the
ground-truth mesh:

- reach: the ball touching a sample (centre p + r·n, held 2 µm off) can come down the tool axis to it
  without meeting the part (OpenCAMLib's drop-cutter at the centre's xy is no higher) and stays above the
  table (the part's lowest point);
- left: the material along the sample's normal up to the swept volume, by sphere tracing from p along n
  (step = distance to the nearest ball-centre segment minus r), measured up to `range_mm`; farther is
  "not cut";
- gouge: how deep a sample lies inside the volume swept by the cutting moves (r minus its distance to the
  nearest centre segment), and the same for rapids.

The planner's own verify uses exact ray–capsule intervals; this one uses another method on another mesh
(the ground truth, not the job's `mesh.ply`), so the two agree only if both are right.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from opencamlib import ocl
from pygcode import Line, Machine
from scipy.spatial import cKDTree

REACH_TOL_MM = 2e-3  # how far off a sample the ball is held for the reach test, mm


@dataclass
class Moves:
    start: np.ndarray  # (m, 3) tool tips, mm, machine frame
    end: np.ndarray
    rapid: np.ndarray  # (m,) bool: G0


def read_moves(text: str) -> Moves:
    """Straight moves of a program, from pygcode's machine model; moves before X, Y and Z are all known
    are skipped (the controller's position there is not the program's)."""
    machine, known = Machine(), set()
    start, end, rapid = [], [], []
    for raw in text.splitlines():
        line = Line(raw)
        if not line.block.gcodes and not line.block.modal_params:
            continue
        before = np.array([machine.pos.X, machine.pos.Y, machine.pos.Z], dtype=float)
        machine.process_block(line.block)
        after = np.array([machine.pos.X, machine.pos.Y, machine.pos.Z], dtype=float)
        for w in line.block.words:
            if w.letter in "XYZ":
                known.add(w.letter)
        moves = any(w.letter in "XYZ" for w in line.block.words)
        motion = str(machine.mode.motion)[:3]
        if moves and motion not in ("G00", "G01"):
            raise ValueError(f"the bench check follows G0/G1 only, not {motion} in {raw!r}")
        if len(known) == 3 and np.any(after != before) and moves:
            start.append(before), end.append(after), rapid.append(motion == "G00")
    return Moves(np.array(start).reshape(-1, 3), np.array(end).reshape(-1, 3), np.array(rapid, dtype=bool))


def sample_mesh(vertices: np.ndarray, faces: np.ndarray, spacing_mm: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Points (k, 3), unit normals (k, 3) and areas (k,) of a triangle mesh: every triangle halved across
    its longest edge until no edge is longer than spacing_mm, one sample at each piece's centroid."""
    tri = vertices[faces].astype(np.float64)
    normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    normal = normal / np.maximum(np.linalg.norm(normal, axis=1), 1e-300)[:, None]
    owner = np.arange(len(tri))
    done_t, done_o = [], []
    while len(tri):
        edges = np.linalg.norm(np.roll(tri, -1, axis=1) - tri, axis=2)  # edge k: corner k to k + 1
        small = edges.max(axis=1) <= spacing_mm
        done_t.append(tri[small]), done_o.append(owner[small])
        tri, owner, edges = tri[~small], owner[~small], edges[~small]
        k = np.argmax(edges, axis=1)
        rows = np.arange(len(tri))
        a, b, c = tri[rows, k], tri[rows, (k + 1) % 3], tri[rows, (k + 2) % 3]
        m = 0.5 * (a + b)
        tri = np.concatenate([np.stack([a, m, c], axis=1), np.stack([m, b, c], axis=1)])
        owner = np.concatenate([owner, owner])
    tri, owner = np.concatenate(done_t), np.concatenate(done_o)
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    return tri.mean(axis=1), normal[owner], area


def reachable(vertices: np.ndarray, faces: np.ndarray, points: np.ndarray, normals: np.ndarray, r: float) -> np.ndarray:
    """bool (k,): the ball touching each sample can be lowered along Z onto it (machine frame)."""
    surf = ocl.STLSurf()
    for t in vertices[faces].tolist():
        surf.addTriangle(ocl.Triangle(ocl.Point(*t[0]), ocl.Point(*t[1]), ocl.Point(*t[2])))
    floor = float(vertices[:, 2].min())
    # The ball held REACH_TOL_MM off the sample: a ball touching a wall exactly touches the wall's top
    # edge too, and whether it then counts as blocked would be round-off.
    centre = points + (r + REACH_TOL_MM) * normals
    cutter = ocl.BallCutter(2 * r, 1000.0)
    tip = []
    for s in range(0, len(centre), 20000):  # OpenCAMLib's batch crashes on some 500k-point batches
        batch = ocl.BatchDropCutter()
        batch.setSTL(surf)
        batch.setCutter(cutter)
        for x, y in centre[s:s + 20000, :2].tolist():
            batch.appendPoint(ocl.CLPoint(x, y, floor - 1.0))
        batch.run()
        tip += [p.z for p in batch.getCLPoints()]
    tip = np.array(tip)
    return (tip <= centre[:, 2] - r + REACH_TOL_MM) & (centre[:, 2] - r >= floor)


def _pieces(a: np.ndarray, b: np.ndarray, length_mm: float) -> tuple[np.ndarray, np.ndarray]:
    """Segments a → b (m, 3) cut into pieces no longer than length_mm."""
    n = np.maximum(np.ceil(np.linalg.norm(b - a, axis=1) / length_mm).astype(int), 1)
    owner = np.repeat(np.arange(len(a)), n)
    k = np.arange(len(owner)) - np.repeat(np.cumsum(n) - n, n)
    t0, t1 = k / n[owner], (k + 1) / n[owner]
    d = (b - a)[owner]
    return a[owner] + t0[:, None] * d, a[owner] + t1[:, None] * d


def _distance(x: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    ab = b - a
    t = np.clip(((x - a) * ab).sum(1) / np.maximum((ab * ab).sum(1), 1e-300), 0.0, 1.0)
    return np.linalg.norm(x - a - t[:, None] * ab, axis=1)


class _Segments:
    """Ball-centre segments, cut into short pieces and put in a KD-tree by their middles."""

    def __init__(self, a: np.ndarray, b: np.ndarray, piece_mm: float):
        self.a, self.b = _pieces(a, b, piece_mm)
        self.half = 0.5 * piece_mm
        self.tree = cKDTree(0.5 * (self.a + self.b)) if len(self.a) else None

    def near(self, x: np.ndarray, radius: float) -> tuple[np.ndarray, np.ndarray]:
        """(point, piece) pairs whose piece may come within radius of the point."""
        if self.tree is None or not len(x):
            return np.zeros(0, int), np.zeros(0, int)
        m = cKDTree(x).sparse_distance_matrix(self.tree, radius + self.half, output_type="ndarray")
        return m["i"].astype(int), m["j"].astype(int)


def _nearest(segs: _Segments, x: np.ndarray, i: np.ndarray, j: np.ndarray, k: int) -> np.ndarray:
    d = np.full(k, np.inf)
    if len(i):
        np.minimum.at(d, i, _distance(x[i], segs.a[j], segs.b[j]))
    return d


def _trace(cut: _Segments, p: np.ndarray, n: np.ndarray, i: np.ndarray, j: np.ndarray, r: float,
           range_mm: float, iterations: int) -> np.ndarray:
    """Sphere tracing from each p along n against the pieces paired with it: the first t where the ball
    centre segments come within r (+inf beyond range_mm; NaN where it has not settled: a grazing ray)."""
    t = np.zeros(len(p))
    out = np.full(len(p), np.nan)
    active = np.ones(len(p), dtype=bool)
    for _ in range(iterations):
        pair = active[i]
        i, j = i[pair], j[pair]
        step = _nearest(cut, p + t[:, None] * n, i, j, len(p)) - r
        hit = active & (step <= 1e-5)
        out[hit] = t[hit]
        t = np.where(active, t + np.maximum(step, 0.0), t)
        gone = active & ~hit & (t > range_mm)
        out[gone] = np.inf
        active &= ~(hit | gone)
        if not active.any():
            break
    return out


def left_and_gouge(moves: Moves, r: float, points: np.ndarray, normals: np.ndarray, *, range_mm: float,
                   chunk: int = 20000, iterations: int = 60) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Material left along each normal (+inf beyond range_mm), and the depth of each sample inside the
    volume swept by cutting moves and by rapids (≥ 0), mm."""
    lift = np.array([0.0, 0.0, r])
    cut = _Segments(moves.start[~moves.rapid] + lift, moves.end[~moves.rapid] + lift, 0.25 * r)
    fast = _Segments(moves.start[moves.rapid] + lift, moves.end[moves.rapid] + lift, 0.25 * r)
    left, gouge, rapid_gouge = np.full(len(points), np.inf), np.zeros(len(points)), np.zeros(len(points))
    for s in range(0, len(points), chunk):
        p, n = points[s:s + chunk], normals[s:s + chunk]
        i, j = fast.near(p, r)
        rapid_gouge[s:s + chunk] = np.maximum(r - _nearest(fast, p, i, j, len(p)), 0.0)
        # Every piece that a ball along the normal up to range_mm can meet lies within r + range/2 of the
        # middle of that stretch.
        mid = p + 0.5 * range_mm * n
        i, j = cut.near(mid, r + 0.5 * range_mm)
        keep = _distance(mid[i], cut.a[j], cut.b[j]) <= r + 0.5 * range_mm
        i, j = i[keep], j[keep]
        gouge[s:s + chunk] = np.maximum(r - _nearest(cut, p, i, j, len(p)), 0.0)
        left[s:s + chunk] = _trace(cut, p, n, i, j, r, range_mm, iterations)
    return left, gouge, rapid_gouge
