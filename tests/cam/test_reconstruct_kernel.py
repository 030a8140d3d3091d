"""The compiled grid-level kernels give the torch operations' results to the bit (`cam.reconstruct._gridkernel`).

The oracle is the torch code the kernels replace on the CPU (`fields._torch_weights`, and `_Interpolate`'s
expressions written out here), run on the same float32 inputs: points inside and outside the box (where the
interpolant extrapolates), every level of a pyramid, with and without the gradient's columns.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch

from cam.reconstruct import fields
from cam.reconstruct._gridkernel import cell_weights, interpolate, scatter_gradient


@pytest.fixture(scope="module")
def field() -> fields.GridField:
    rng = np.random.default_rng(3)
    f = fields.GridField(np.array([-1.1, -0.9, -1.0]), np.array([1.0, 1.1, 0.8]), finest_cells=48, levels=3)
    for values in f.values:
        with torch.no_grad():
            values.copy_(torch.from_numpy(rng.standard_normal(values.shape[0]).astype(np.float32)))
    return f


def _points(count: int, seed: int) -> torch.Tensor:
    # A third of them beyond the box on some axis (extrapolated), a few on cell faces exactly.
    rng = np.random.default_rng(seed)
    x = rng.uniform(-1.4, 1.4, (count, 3)).astype(np.float32)
    x[:8] = np.float32(0.0)
    return torch.from_numpy(x)


@pytest.mark.parametrize("with_grad", [True, False])
def test_weights_interpolation_and_gradient_are_torchs_to_the_bit(field, with_grad):
    x = _points(5000, 1)
    grad_out = np.random.default_rng(2).standard_normal((len(x), 4 if with_grad else 1)).astype(np.float32)
    for values, h, dims in zip(field.values, field.cell, field.dims, strict=True):
        ref_idx, ref_w = fields._torch_weights(x, field.lo, h, dims, with_grad)
        idx, w = cell_weights(x.numpy(), field.lo.numpy(), h, dims, with_grad)
        assert np.array_equal(idx, ref_idx.numpy())
        assert w.dtype == np.float32 and np.array_equal(w, ref_w.numpy())

        vals = values.detach()
        ref = (vals.index_select(0, ref_idx).view(len(x), 8, 1) * ref_w).sum(dim=1)
        assert np.array_equal(interpolate(vals.numpy(), idx, w), ref.numpy())

        g = torch.from_numpy(grad_out)
        per_corner = (ref_w * g[:, None, :]).sum(dim=2).reshape(-1)
        ref_grad = torch.zeros(vals.shape[0]).index_add_(0, ref_idx, per_corner)
        assert np.array_equal(scatter_gradient(idx, w, grad_out, vals.shape[0]), ref_grad.numpy())


def test_field_gradient_through_autograd_matches_a_float64_field(field):
    """The kernels serve float32 CPU fields; a float64 field (torch path) agrees within float32 rounding."""
    x = _points(2000, 4)
    wide = fields.GridField(np.array([-1.1, -0.9, -1.0]), np.array([1.0, 1.1, 0.8]), finest_cells=48, levels=3,
                            dtype=torch.float64)
    for a, b in zip(wide.values, field.values, strict=True):
        with torch.no_grad():
            a.copy_(b.double())
    losses = []
    for f, pts in ((field, x), (wide, x.double())):
        f.zero_grad()
        value, grad = f(pts)
        loss = value.abs().mean() + ((grad.norm(dim=1) - 1.0) ** 2).mean()
        loss.backward()
        losses.append((loss.item(), [p.grad.double().numpy() for p in f.values]))
    (l32, g32), (l64, g64) = losses
    assert l32 == pytest.approx(l64, rel=1e-5)
    for a, b in zip(g32, g64, strict=True):
        assert np.allclose(a, b, rtol=1e-4, atol=1e-6 * np.abs(b).max())
