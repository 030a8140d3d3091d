"""Pictures of the part as inline SVG, for the setup sheet: no browser, no WebGL, no script needed to see them.

The mesh is simplified by vertex clustering (vertices snapped to a grid whose cell grows until at most
`max_faces` triangles remain), projected orthographically along the view direction, sorted far to near
(painter's algorithm) and filled with flat Lambert shading of each triangle's own colour. Arrows
(machine axes, tool axis) and a table plane can be drawn into the same picture.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["Arrow", "Plane", "is_closed", "render_svg", "simplify_mesh", "view_basis"]


@dataclass(frozen=True)
class Arrow:
    """An arrow from `start` to `end` (mm, the picture's frame), drawn over the part, with a label at its tip."""

    start: tuple[float, float, float]
    end: tuple[float, float, float]
    color: str
    label: str = ""


@dataclass(frozen=True)
class Plane:
    """A flat quadrilateral (4 corners, mm) drawn behind the part: the machine table under a setup."""

    corners: tuple[tuple[float, float, float], ...]
    color: str = "#d9dee5"
    label: str = ""


def simplify_mesh(vertices: np.ndarray, faces: np.ndarray, *, max_faces: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A coarser copy of a triangle mesh with at most `max_faces` triangles (vertex clustering).

    Parameters
    ----------
    vertices : (n, 3) float
        mm.
    faces : (m, 3) int
    max_faces : int
        Triangles kept at most (>= 1).

    Returns
    -------
    vertices : (n', 3) float64
        The mean of each cluster's vertices.
    faces : (m', 3) int64
        m' <= max_faces; no degenerate or repeated triangle.
    source : (m',) int64
        For each kept triangle, the index of the input triangle it comes from (to carry per-face data).
    """
    V = np.asarray(vertices, dtype=np.float64)
    F = np.asarray(faces, dtype=np.int64)
    if V.ndim != 2 or V.shape[1] != 3 or F.ndim != 2 or F.shape[1] != 3:
        raise ValueError(f"simplify_mesh needs (n, 3) vertices and (m, 3) faces, got {V.shape} and {F.shape}")
    if max_faces < 1:
        raise ValueError(f"max_faces must be >= 1, got {max_faces}")
    if len(F) <= max_faces:
        return V, F, np.arange(len(F))
    lo = V.min(axis=0)
    diagonal = float(np.linalg.norm(V.max(axis=0) - lo)) or 1.0

    def cluster(cells: float):
        cell = np.floor((V - lo) / (diagonal / cells)).astype(np.int64)
        n = int(cell.max()) + 1
        _, inverse = np.unique((cell[:, 0] * n + cell[:, 1]) * n + cell[:, 2], return_inverse=True)  # one sort key
        inverse = inverse.reshape(-1)
        G = inverse[F]
        ok = (G[:, 0] != G[:, 1]) & (G[:, 1] != G[:, 2]) & (G[:, 0] != G[:, 2])
        src = np.flatnonzero(ok)
        T = np.sort(G[ok], axis=1)
        m = len(V)
        if m < 2_000_000:  # a one-number key per triangle sorts far faster than rows
            _, first = np.unique((T[:, 0] * m + T[:, 1]) * m + T[:, 2], return_index=True)
        else:
            _, first = np.unique(T, axis=0, return_index=True)
        src = np.sort(src[first])
        return inverse, G[src], src

    lo_cells, hi_cells = 2.0, 4.0 * np.sqrt(max_faces)  # a grid this fine keeps about every face it can
    best = cluster(lo_cells)
    for _ in range(14):  # bisect on the grid: the finest one that still fits
        mid = 0.5 * (lo_cells + hi_cells)
        trial = cluster(mid)
        if len(trial[1]) <= max_faces:
            best, lo_cells = trial, mid
        else:
            hi_cells = mid
    inverse, G, src = best
    if len(G) > max_faces:  # even the coarsest grid is over: keep an even subset
        keep = np.linspace(0, len(G) - 1, max_faces).round().astype(np.int64)
        G, src = G[keep], src[keep]
    counts = np.bincount(inverse)
    out = np.zeros((len(counts), 3))
    np.add.at(out, inverse, V)
    out /= np.maximum(counts, 1)[:, None]
    used, G = np.unique(G, return_inverse=True)
    return out[used], G.reshape(-1, 3), src


def view_basis(direction: np.ndarray, up: np.ndarray) -> np.ndarray:
    """Rows: screen right, screen up, toward the viewer; for looking along `direction` with `up` upright.

    Parameters
    ----------
    direction : (3,) float
        From the eye toward the part (any length > 0).
    up : (3,) float
        What should point up on the page; must not be parallel to `direction`.

    Returns
    -------
    (3, 3) float64
        Orthonormal, right-handed.
    """
    d = np.asarray(direction, dtype=np.float64)
    w = -d / np.linalg.norm(d)
    u = np.cross(np.asarray(up, dtype=np.float64), w)
    if np.linalg.norm(u) < 1e-9:
        raise ValueError(f"view direction {d.tolist()} is parallel to up {np.asarray(up).tolist()}")
    u /= np.linalg.norm(u)
    return np.array([u, np.cross(w, u), w])


def _hex(rgb: np.ndarray) -> list[str]:
    c = np.clip(np.round(rgb * 255), 0, 255).astype(int)
    return [f"#{r:02x}{g:02x}{b:02x}" for r, g, b in c]


def is_closed(faces: np.ndarray) -> bool:
    """Every edge in exactly two triangles (then a triangle facing away is always hidden)."""
    e = np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), axis=1)
    _, counts = np.unique(e, axis=0, return_counts=True)
    return bool(len(counts)) and bool(np.all(counts == 2))


def render_svg(vertices: np.ndarray, faces: np.ndarray, *, direction: np.ndarray, up: np.ndarray,
               face_colors: np.ndarray | None = None, max_faces: int = 3000, width_px: int = 360,
               height_px: int = 280, arrows: tuple[Arrow, ...] = (), planes: tuple[Plane, ...] = (),
               title: str = "", key: str = "pic", cull_back: bool | None = None) -> str:
    """An SVG picture of a triangle mesh (orthographic, painter's algorithm, flat Lambert shading).

    Parameters
    ----------
    vertices : (n, 3) float
        mm, in the frame the view is given in.
    faces : (m, 3) int
    direction, up : (3,) float
        The view (see `view_basis`).
    face_colors : (m, 3) float in [0, 1], optional
        Base colour per face; default a light steel grey.
    max_faces : int
        The mesh is simplified to at most this many triangles.
    width_px, height_px : int
        The picture's size (it scales with the page: a viewBox).
    arrows, planes : tuples of Arrow, Plane
        Drawn over (arrows) and behind (planes) the part; included in the framing.
    title : str
        Text for `<title>` (read by screen readers); escaped here.
    key : str
        Unique among the pictures of one page: it prefixes the ids of the arrow heads.
    cull_back : bool, optional
        Leave out the triangles turned away from the viewer (right for a closed, outward part; a simplified
        copy of one may no longer be closed, so the caller says). None: when the drawn mesh is closed.

    Returns
    -------
    str
        One `<svg>` element, no external reference.
    """
    from html import escape

    V, F, src = simplify_mesh(vertices, faces, max_faces=max_faces)
    base = (np.full((len(F), 3), 0.78) if face_colors is None
            else np.asarray(face_colors, dtype=np.float64)[src])
    B = view_basis(direction, up)
    P = V @ B.T  # screen right, screen up, depth (toward viewer)
    tri = P[F]
    normal = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
    length = np.linalg.norm(normal, axis=1)
    ok = length > 0
    normal[ok] /= length[ok, None]
    facing = normal @ B[2]
    light = B.T @ np.array([-0.35, 0.55, 0.76])  # from the upper left, in front: a fixed studio light
    light /= np.linalg.norm(light)
    if is_closed(F) if cull_back is None else cull_back:
        keep = ok & (facing > 0)
        lambert = np.clip(normal @ light, 0.0, 1.0)
    else:  # an open sheet shows both sides: shade each by the side the viewer sees
        keep = ok
        lambert = np.abs(normal @ light)
    shade = 0.38 + 0.62 * lambert
    extra = [np.array(a.start) for a in arrows] + [np.array(a.end) for a in arrows] + \
        [np.array(c) for p in planes for c in p.corners]
    pts2 = np.concatenate([P[:, :2], np.array(extra).reshape(-1, 3) @ B[:2].T]) if extra else P[:, :2]
    lo, hi = pts2.min(axis=0), pts2.max(axis=0)
    pad = 22.0
    scale = min((width_px - 2 * pad) / max(hi[0] - lo[0], 1e-9), (height_px - 2 * pad) / max(hi[1] - lo[1], 1e-9))
    centre = 0.5 * (lo + hi)

    def to_px(xy: np.ndarray) -> np.ndarray:
        xy = np.atleast_2d(xy)
        return np.column_stack([width_px / 2 + (xy[:, 0] - centre[0]) * scale,
                                height_px / 2 - (xy[:, 1] - centre[1]) * scale])

    out = [(f'<svg viewBox="0 0 {width_px} {height_px}" width="{width_px}" '
            f'height="{height_px}" role="img" class="part-picture">'), f"<title>{escape(title)}</title>"]
    for plane in planes:
        c = to_px(np.array(plane.corners, dtype=np.float64) @ B[:2].T)
        out.append(f'<path d="M{"L".join(f"{x:.1f} {y:.1f}" for x, y in c)}Z" fill="{plane.color}" '
                   f'stroke="#9aa5b1" stroke-width="0.8"/>')
        if plane.label:
            x, y = c[np.argmax(c[:, 1])]
            out.append(f'<text x="{x:.1f}" y="{min(y + 12, height_px - 2):.1f}" class="pic-label">{escape(plane.label)}</text>')
    order = np.flatnonzero(keep)
    order = order[np.argsort(tri[order, :, 2].mean(axis=1), kind="stable")]
    colors = _hex(base[order] * shade[order, None])
    screen = to_px(tri[order][:, :, :2].reshape(-1, 2)).reshape(-1, 3, 2)
    out.append('<g stroke-width="0.6" stroke-linejoin="round">')
    for (a, b, c), col in zip(screen, colors):
        # stroke in the fill colour closes the hairline seams anti-aliasing leaves between triangles
        out.append(f'<path d="M{a[0]:.1f} {a[1]:.1f}L{b[0]:.1f} {b[1]:.1f}L{c[0]:.1f} {c[1]:.1f}Z" '
                   f'fill="{col}" stroke="{col}"/>')
    out.append("</g>")
    for k, arrow in enumerate(arrows):
        (x0, y0), (x1, y1) = to_px(np.array([arrow.start, arrow.end], dtype=np.float64) @ B[:2].T)
        out.append(f'<line x1="{x0:.1f}" y1="{y0:.1f}" x2="{x1:.1f}" y2="{y1:.1f}" stroke="{arrow.color}" '
                   f'stroke-width="2.2" marker-end="url(#{key}-tip{k})"/>')
        out.insert(2, f'<defs><marker id="{key}-tip{k}" viewBox="0 0 10 10" refX="8" refY="5" '
                      f'markerWidth="6" markerHeight="6" orient="auto-start-reverse"><path d="M0 0L10 5L0 10Z" '
                      f'fill="{arrow.color}"/></marker></defs>')
        if arrow.label:
            out.append(f'<text x="{x1 + 4:.1f}" y="{y1 - 4:.1f}" fill="{arrow.color}" class="pic-label">'
                       f'{escape(arrow.label)}</text>')
    out.append("</svg>")
    return "".join(out)
