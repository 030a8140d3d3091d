"""Setups chosen for reach: the tool axes from which a ball reaches the most of the part.

A sample of the part is reachable from a tool axis when the ball touching it (centre r along its normal)
can be lowered there from above without meeting the part: the drop-cutter height over the centre is
not above the centre. The setups given (segment's: how the part sits on its base) come first; then, greedily, of the six
axis directions of the part frame and the main directions of its normals, each next the one that reaches
the most area no chosen one reaches, until `max_setups` or until a candidate adds less than a thousandth
of the part.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cam import CheckCancel, map_forked
from cam.gcode.setup import Setup
from cam.mesh.samples import SurfaceSamples
from cam.plan.part import SetupPart, setup_part

__all__ = ["SetupReach", "choose_setups", "reachable", "rotation_to_z", "setup_for_axis", "setup_reach"]

_SCORE_SAMPLES = 8000


@dataclass(frozen=True)
class SetupReach:
    """Setups in the order chosen, and for each a bool (k,) of the samples its ball reaches."""

    setups: list[Setup]
    reach: list[np.ndarray]

    def any(self) -> np.ndarray:
        """bool (k,): reached from some setup."""
        return np.any(self.reach, axis=0) if self.reach else np.zeros(0, bool)


def rotation_to_z(axis: np.ndarray) -> np.ndarray:
    """The proper rotation R (3, 3) with R · axis = +Z: the identity for +Z, a half turn about X for −Z,
    the shortest turn otherwise."""
    a = np.asarray(axis, dtype=np.float64)
    a = a / np.linalg.norm(a)
    z = np.array([0.0, 0.0, 1.0])
    c = float(a @ z)
    if c > 1 - 1e-12:
        return np.eye(3)
    if c < -1 + 1e-12:
        return np.diag([1.0, -1.0, -1.0])
    v = np.cross(a, z)
    s = np.linalg.norm(v)
    k = v / s
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + s * K + (1 - c) * (K @ K)


def setup_for_axis(setup_id: int, axis: np.ndarray, vertices: np.ndarray) -> Setup:
    """The setup whose tool axis is `axis` (part frame), the part's xy centre at the machine origin and its
    lowest point at machine z = 0.

    Parameters
    ----------
    setup_id : int
    axis : (3,) float
        Tool axis in the part frame (need not be unit).
    vertices : (n, 3) float
        The part's vertices, mm, part frame.
    """
    R = rotation_to_z(axis)
    m = np.asarray(vertices, dtype=np.float64) @ R.T
    lo, hi = m.min(axis=0), m.max(axis=0)
    t = -np.array([0.5 * (lo[0] + hi[0]), 0.5 * (lo[1] + hi[1]), lo[2]])
    return Setup(id=setup_id, rotation=R, translation=t)


def reachable(samples: SurfaceSamples, vertices: np.ndarray, faces: np.ndarray, setup: Setup, *,
              tool_radius_mm: float, cell_mm: float | None = None) -> np.ndarray:
    """Which samples the ball reaches from `setup`.

    Parameters
    ----------
    samples : SurfaceSamples
        Points and outward normals of the part, part frame.
    vertices, faces : (n, 3) float, (m, 3) int
        The closed part, part frame, outward.
    setup : Setup
    tool_radius_mm : float
    cell_mm : float or None
        The drop-cutter index's bucket size (`cam.plan.part.setup_part`): the same answer for any.

    Returns
    -------
    (k,) bool
    """
    part = setup_part(vertices, faces, setup, tool_radius_mm=tool_radius_mm, closest=False, cell_mm=cell_mm)
    return part.reaches(setup.to_machine(samples.points), setup.to_machine(samples.normals, direction=True))


def _candidate_axes(normals: np.ndarray, area: np.ndarray, given: list[Setup], rng: np.random.Generator,
                    clusters: int = 6) -> list[np.ndarray]:
    """Given setups' axes first, then ±X, ±Y, ±Z and the area-weighted k-means directions of the normals,
    none within 5° of an earlier one."""
    from scipy.cluster.vq import kmeans2

    axes = [s.tool_axis_part for s in given] + [np.array(v, float) for v in np.vstack([np.eye(3), -np.eye(3)])]
    if len(normals) > clusters:
        pick = rng.choice(len(normals), size=min(len(normals), 20000), replace=False, p=area / area.sum())
        centroids, _ = kmeans2(normals[pick], clusters, seed=rng, minit="++")
        axes += [c / np.linalg.norm(c) for c in centroids if np.linalg.norm(c) > 0.1]
    out: list[np.ndarray] = []
    for a in axes:
        a = a / np.linalg.norm(a)
        if all(float(a @ b) < np.cos(np.radians(5.0)) for b in out):
            out.append(a)
    return out


def choose_setups(samples: SurfaceSamples, vertices: np.ndarray, faces: np.ndarray, *, tool_radius_mm: float,
                  max_setups: int, given: list[Setup] = (), rng: np.random.Generator | None = None,
                  min_gain: float = 1e-3, processes: int = 1, check_cancel: CheckCancel | None = None
                  ) -> list[Setup]:
    """Up to `max_setups` setups that together reach the most of the part, greedily.

    Parameters
    ----------
    samples : SurfaceSamples
        The part's samples, part frame (their areas weigh the choice).
    vertices, faces : (n, 3) float, (m, 3) int
        The closed part, part frame, outward.
    tool_radius_mm : float
    max_setups : int
    given : list of Setup
        Setups to consider first (kept as they are when chosen: segment's base setup).
    rng : numpy.random.Generator, optional
        For the k-means of the normals; default seeded with 0.
    min_gain : float
        A setup is added only while it reaches at least this share of the part's area more.
    processes : int
        Candidate axes measured at once, in forked processes (`cam.map_forked`; the same reach).
    check_cancel : callable, optional
        cam's callback (see `cam`), called before each setup's reach is computed.

    Returns
    -------
    list of Setup
        Ids are 1, 2, ... in the order chosen (their reach on all the samples: `setup_reach`, with the
        parts the caller plans on).
    """
    rng = rng if rng is not None else np.random.default_rng(0)
    check_cancel = check_cancel or (lambda: None)
    axes = _candidate_axes(samples.normals, samples.area, list(given), rng)
    # Candidates are scored on an even subset of the samples (a few thousand tell the shares apart);
    # the setups chosen get their reach on all of them.
    few = samples.subset(slice(None, None, max(len(samples.area) // _SCORE_SAMPLES, 1)))
    total = float(few.area.sum())
    trial = [given[k] if k < len(given) else setup_for_axis(0, axis, vertices) for k, axis in enumerate(axes)]
    # A few thousand queries per candidate: buckets a radius wide build in a sixth of the default's time
    # (a 195k-triangle mesh: 0.10 s against 0.66 s) and answer them about as fast.
    reaches = map_forked(lambda k, _cc: reachable(few, vertices, faces, trial[k], tool_radius_mm=tool_radius_mm,
                                                  cell_mm=tool_radius_mm),
                         len(trial), processes=processes, check_cancel=check_cancel)
    candidates = list(zip(trial, reaches))
    chosen: list[tuple[Setup, np.ndarray]] = []
    covered = np.zeros(len(few.area), dtype=bool)
    while len(chosen) < max_setups and candidates:
        gains = [float(few.area[reach & ~covered].sum()) for _, reach in candidates]
        best = int(np.argmax(gains))
        # A given setup goes first while it reaches anything: it is how the part sits on its base.
        for k, (setup, _) in enumerate(candidates):
            if any(setup is g for g in given) and gains[k] > 0:
                best = k
                break
        if gains[best] < min_gain * total and chosen:
            break
        setup, reach = candidates.pop(best)
        chosen.append((Setup(id=len(chosen) + 1, rotation=setup.rotation, translation=setup.translation), reach))
        covered |= reach
    return [s for s, _ in chosen]


def setup_reach(samples: SurfaceSamples, parts: list[SetupPart]) -> SetupReach:
    """The setups of `parts` (`cam.plan.part.setup_part`, one per setup) and which samples (part frame) each
    one's ball reaches."""
    return SetupReach(setups=[p.setup for p in parts],
                      reach=[p.reaches(p.setup.to_machine(samples.points),
                                       p.setup.to_machine(samples.normals, direction=True)) for p in parts])
