"""CSG parts with known creases, made with manifold3d, for tests and benchmarks (issue 35's four test shapes).

Each returns ``(vertices float64 (n, 3) mm, triangles int64 (m, 3))``, a closed manifold counter-clockwise seen
from outside.
"""

from __future__ import annotations

import numpy as np

__all__ = ["box_pocket_fillet", "bracket", "cylinder_chamfer", "ridge40", "rounded_box", "solid_mesh"]


def solid_mesh(solid) -> tuple[np.ndarray, np.ndarray]:
    """A manifold3d solid's triangle mesh."""
    m = solid.to_mesh()
    return np.asarray(m.vert_properties, dtype=np.float64)[:, :3], np.asarray(m.tri_verts, dtype=np.int64)


def bracket() -> tuple[np.ndarray, np.ndarray]:
    """An L-bracket, 60 × 40 mm: an 8 mm base, a 40 mm upright, a boss with a 10 mm through hole."""
    from manifold3d import Manifold

    base = Manifold.cube([60.0, 40.0, 8.0])
    upright = Manifold.cube([8.0, 40.0, 40.0])
    boss = Manifold.cylinder(14.0, 9.0, circular_segments=96).translate([38.0, 20.0, 0.0])
    hole = Manifold.cylinder(30.0, 5.0, circular_segments=96).translate([38.0, 20.0, -5.0])
    return solid_mesh(base + upright + boss - hole)


def rounded_box(size, corner: float, floor: float, segments: int = 48):
    """A manifold3d box (x, y, z sizes) whose vertical edges are rounded by `corner` and bottom edges by `floor`."""
    from manifold3d import Manifold

    sx, sy, sz = size
    parts = []
    for x in (corner, sx - corner):
        for y in (corner, sy - corner):
            if floor > 0:
                parts.append(Manifold.sphere(floor, segments).translate([x, y, floor]))
            parts.append(Manifold.cylinder(sz - floor, corner, circular_segments=segments).translate([x, y, floor]))
    return Manifold.batch_hull(parts)


def box_pocket_fillet() -> tuple[np.ndarray, np.ndarray]:
    """A 50 × 40 × 20 box with a 30 × 20 × 8 pocket, corners rounded 4 mm, floor filleted 2 mm."""
    from manifold3d import Manifold

    return solid_mesh(Manifold.cube([50.0, 40.0, 20.0])
                      - rounded_box((30.0, 20.0, 10.0), 4.0, 2.0).translate([10.0, 10.0, 12.0]))


def cylinder_chamfer() -> tuple[np.ndarray, np.ndarray]:
    """A cylinder of 20 mm radius, 25 mm tall, its top edge chamfered 3 mm at 45°."""
    from manifold3d import Manifold

    body = Manifold.cylinder(22.0, 20.0, circular_segments=96)
    chamfer = Manifold.cylinder(3.0, 20.0, 17.0, circular_segments=96).translate([0.0, 0.0, 22.0])
    return solid_mesh(body + chamfer)


def ridge40() -> tuple[np.ndarray, np.ndarray]:
    """A 40 mm long block whose top is two slopes of 20° meeting at a ridge: a gentle 40° crease."""
    from manifold3d import CrossSection, Manifold

    rise = 20.0 * np.tan(np.radians(20.0))
    outline = [(0.0, 0.0), (40.0, 0.0), (40.0, 15.0), (20.0, 15.0 + rise), (0.0, 15.0)]
    # the outline (x, z) extruded 40 mm along +y
    prism = Manifold.extrude(CrossSection([outline]), 40.0).rotate([90.0, 0.0, 0.0]).translate([0.0, 40.0, 0.0])
    return solid_mesh(prism)
