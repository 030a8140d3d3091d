"""Sweep.probe against a plain reference: every (point, move) pair measured with `capsule_intervals`, in the
vectorised arithmetic the compiled probe reproduces bit for bit."""

from __future__ import annotations

import numpy as np
import pytest

from cam.gcode.sweep import Sweep, capsule_intervals


def _reference(p, n, a, b, r, reach):
    """Material left and overcut per point over all moves, no search structure."""
    k, m = len(p), len(a)
    i, j = np.repeat(np.arange(k), m), np.tile(np.arange(m), k)
    ab = b[j] - a[j]
    t = np.clip(np.einsum("ij,ij->i", p[i] - a[j], ab) / np.maximum(np.einsum("ij,ij->i", ab, ab), 1e-300), 0.0, 1.0)
    dist = np.linalg.norm(p[i] - (a[j] + t[:, None] * ab), axis=1)
    t_in, t_out = capsule_intervals(p[i], n[i], a[j], b[j], r)
    hit = (t_in <= t_out) & (t_out >= 0) & (dist <= r + reach)
    left = np.where(hit, np.maximum(t_in, 0.0), np.inf).reshape(k, m).min(axis=1)
    gouge = np.where(dist <= r + reach, np.maximum(r - dist, 0.0), 0.0).reshape(k, m).max(axis=1)
    return np.where(left <= reach, left, np.inf), gouge


@pytest.mark.parametrize(("r", "reach", "seed"), [(3.0, 0.5, 0), (1.0, 2.0, 1), (0.5, 0.0, 2)])
def test_probe_matches_every_pair_measured(r, reach, seed):
    rng = np.random.default_rng(seed)
    centres = np.cumsum(rng.normal(scale=0.8, size=(301, 3)), axis=0) * [1.0, 1.0, 0.2]
    centres[100:140] = centres[100]  # zero-length moves too
    a, b = centres[:-1], centres[1:]
    p = centres[rng.integers(0, 300, 1500)] + rng.normal(scale=2.0, size=(1500, 3))
    n = rng.normal(size=(1500, 3))
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    left, gouge = Sweep(a, b, r, step=r / 2).probe(p, n, reach)
    want_left, want_gouge = _reference(p, n, a, b, r, reach)
    assert np.array_equal(left, want_left) and np.array_equal(gouge, want_gouge)
    assert np.isfinite(left).any() and (gouge > 0).any()


def test_no_moves_or_no_points():
    s = Sweep(np.zeros((0, 3)), np.zeros((0, 3)), 1.0, step=0.5)
    left, gouge = s.probe(np.zeros((3, 3)), np.tile([0.0, 0.0, 1.0], (3, 1)), 1.0)
    assert np.isinf(left).all() and (gouge == 0).all()
    left, gouge = Sweep(np.zeros((1, 3)), np.ones((1, 3)), 1.0, step=0.5).probe(np.zeros((0, 3)), np.zeros((0, 3)), 1.0)
    assert left.shape == (0,) and gouge.shape == (0,)
