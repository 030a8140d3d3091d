"""Representations of the signed distance f that the IGR loss trains.

Both take points in the normalised frame (the cloud scaled into the unit ball)
and return ``(f, grad f)``:

- :class:`GridField`, the fast default: a pyramid of value grids whose
  trilinear interpolants are summed. f is linear in its parameters and its
  spatial gradient has a closed form, so a training step needs one backward
  pass instead of the double backward an MLP needs; on two CPU cores a step
  costs milliseconds, and the coarse levels carry the global shape while the
  finest one resolves sharp edges.
- :class:`IGRNetwork`, the paper's MLP: Softplus(beta=100), one skip
  connection halfway that re-injects the input, and the geometric
  initialisation that makes f start as the signed distance of a sphere.
"""

from __future__ import annotations

import math

import numpy as np
import torch
from torch import nn

from cam.reconstruct._gridkernel import cell_weights, interpolate, scatter_gradient

__all__ = ["GridField", "IGRNetwork"]

# Corner offsets of a cell, in the order the interpolation weights are built.
_CORNERS = np.array([[a, b, c] for a in (0, 1) for b in (0, 1) for c in (0, 1)], dtype=np.int64)


class GridField(nn.Module):
    """f(x) = sum over levels of the trilinear interpolant of that level's vertex values.

    Parameters
    ----------
    lo, hi
        float (3,) corners of the box the grids cover (normalised frame).
    finest_cells
        Cells along the longest side of the box at the finest level.
    levels
        Number of levels; each coarser one halves the cell count (at least 2 cells).
    dtype
        Parameter and evaluation dtype.

    Points outside the box are extrapolated linearly from the border cell, so
    f stays defined (and its gradient bounded) everywhere.
    """

    def __init__(self, lo: np.ndarray, hi: np.ndarray, *, finest_cells: int, levels: int,
                 dtype: torch.dtype = torch.float32) -> None:
        super().__init__()
        lo = np.asarray(lo, dtype=np.float64)
        hi = np.asarray(hi, dtype=np.float64)
        extent = hi - lo
        self.register_buffer("lo", torch.tensor(lo, dtype=dtype))
        self.cell = []
        self.dims = []
        values = []
        for level in range(levels):
            cells = max(2, int(round(finest_cells / 2 ** (levels - 1 - level))))
            h = float(extent.max() / cells)
            dims = np.maximum(np.ceil(extent / h - 1e-9).astype(np.int64), 1) + 1
            self.cell.append(h)
            self.dims.append(dims)
            values.append(nn.Parameter(torch.zeros(int(dims.prod()), dtype=dtype)))
        self.values = nn.ParameterList(values)

    def set_level(self, level: int, values: torch.Tensor) -> None:
        """Replace a level's vertex values (flattened x-major, like :meth:`vertices`)."""
        with torch.no_grad():
            self.values[level].copy_(values.reshape(-1).to(self.values[level]))

    def vertices(self, level: int = -1) -> np.ndarray:
        """float64 (m, 3) coordinates of a level's grid vertices, x-major (z fastest)."""
        dims, h = self.dims[level], self.cell[level]
        lo = self.lo.detach().cpu().double().numpy()
        axes = [lo[a] + h * np.arange(dims[a]) for a in range(3)]
        grid = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1)
        return grid.reshape(-1, 3)

    def forward(self, x: torch.Tensor, *, with_grad: bool = True):
        """f (B,) and, when ``with_grad``, grad f (B, 3) at points x (B, 3)."""
        out = None
        for values, h, dims in zip(self.values, self.cell, self.dims, strict=True):
            idx, weights = _trilinear_weights(x, self.lo, h, dims, with_grad)
            level = _Interpolate.apply(values, idx, weights)
            out = level if out is None else out + level
        return out[:, 0], (out[:, 1:] if with_grad else None)

    def lattice(self, axes: list[np.ndarray]) -> torch.Tensor:
        """f on the lattice spanned by three coordinate vectors, shape (len(ax), len(ay), len(az)).

        Each level's interpolant is separable on an axis-aligned lattice, so this costs a few
        passes over the output instead of eight gathers per point.
        """
        dev = self.values[0].device
        total = None
        for values, h, dims in zip(self.values, self.cell, self.dims, strict=True):
            vol = values.detach().view(*[int(d) for d in dims])
            for a in range(3):
                u = (torch.as_tensor(axes[a], dtype=vol.dtype, device=dev) - self.lo[a]) / h
                i0 = torch.floor(u).long().clamp_(0, int(dims[a]) - 2)
                t = (u - i0).view([-1 if b == a else 1 for b in range(3)])
                vol = vol.index_select(a, i0) * (1.0 - t) + vol.index_select(a, i0 + 1) * t
            total = vol if total is None else total + vol
        return total


def _trilinear_weights(x: torch.Tensor, lo: torch.Tensor, h: float, dims: np.ndarray, with_grad: bool):
    """Flat corner indices (B*8,) and weights (B, 8, 1 or 4) giving f (and grad f) as sum of values*weights.

    The weights depend on x only, so they are built outside autograd; the gradient
    column for axis a swaps that axis's factor (1-t, t) for its derivative (-1, 1)/h.
    On the CPU in float32 a compiled kernel builds them (`cam.reconstruct._gridkernel`, the same bits).
    """
    if _compiled(x):
        idx, weights = cell_weights(x.detach().numpy(), lo.numpy(), h, dims, with_grad)
        return torch.from_numpy(idx), torch.from_numpy(weights)
    return _torch_weights(x, lo, h, dims, with_grad)


def _torch_weights(x: torch.Tensor, lo: torch.Tensor, h: float, dims: np.ndarray, with_grad: bool):
    """`_trilinear_weights` as torch operations (any device and dtype)."""
    with torch.no_grad():
        u = (x - lo) / h
        top = torch.as_tensor(dims - 2, device=x.device)
        i0 = torch.minimum(torch.clamp_min(torch.floor(u), 0).long(), top)
        t = u - i0  # outside the box t leaves [0, 1]: linear extrapolation
        sy, sx = int(dims[2]), int(dims[1] * dims[2])
        base = i0[:, 0] * sx + i0[:, 1] * sy + i0[:, 2]
        offsets = torch.as_tensor(_CORNERS @ np.array([sx, sy, 1]), device=x.device)
        idx = (base[:, None] + offsets).reshape(-1)
        w = torch.stack([1.0 - t, t], dim=2)  # (B, 3, 2)
        wx, wy, wz = w[:, 0], w[:, 1], w[:, 2]
        yz = (wy[:, :, None] * wz[:, None, :]).reshape(-1, 1, 4)
        value = (wx[:, :, None] * yz).reshape(-1, 8)
        if not with_grad:
            return idx, value[:, :, None]
        ones = torch.tensor([-1.0 / h, 1.0 / h], dtype=x.dtype, device=x.device)
        gx = (ones[None, :, None] * yz).reshape(-1, 8)
        gy = (wx[:, :, None, None] * (ones[None, :, None] * wz[:, None, :])[:, None]).reshape(-1, 8)
        gz = (wx[:, :, None, None] * (wy[:, :, None] * ones[None, None, :])[:, None]).reshape(-1, 8)
        return idx, torch.stack([value, gx, gy, gz], dim=2)


def _compiled(t: torch.Tensor) -> bool:
    """Whether the compiled kernels serve this tensor's level: float32 on the CPU."""
    return t.device.type == "cpu" and t.dtype == torch.float32


class _Interpolate(torch.autograd.Function):
    """(values, idx, weights) -> (B, k) = sum over the 8 corners of values[idx] * weights.

    A hand-written backward (one scatter-add) instead of autograd's graph of
    gathers and broadcasts: this is what makes a training step cheap on a CPU.
    """

    @staticmethod
    def forward(ctx, values, idx, weights):
        ctx.save_for_backward(idx, weights)
        ctx.size = values.shape[0]
        if _compiled(values):
            return torch.from_numpy(interpolate(values.detach().numpy(), idx.numpy(), weights.numpy()))
        vals = values.index_select(0, idx).view(weights.shape[0], 8, 1)
        return (vals * weights).sum(dim=1)

    @staticmethod
    def backward(ctx, grad_out):
        idx, weights = ctx.saved_tensors
        if _compiled(grad_out):
            grad = scatter_gradient(idx.numpy(), weights.numpy(), grad_out.detach().numpy(), ctx.size)
            return torch.from_numpy(grad), None, None
        per_corner = (weights * grad_out[:, None, :]).sum(dim=2).reshape(-1)
        # index_add_ on CPU accumulates in index order, so the result is the same run to run.
        grad = torch.zeros(ctx.size, dtype=grad_out.dtype, device=grad_out.device)
        grad.index_add_(0, idx, per_corner)
        return grad, None, None


class IGRNetwork(nn.Module):
    """The IGR paper's MLP: ``depth`` hidden layers of ``width``, Softplus(beta=100), a skip at depth/2.

    With geometric initialisation f(x) is close to ``|x| - radius`` at the start.
    """

    def __init__(self, *, width: int, depth: int, radius: float = 0.5,
                 dtype: torch.dtype = torch.float32, generator: torch.Generator | None = None) -> None:
        super().__init__()
        dims = [3] + [width] * depth + [1]
        self.skip = depth // 2 if depth >= 4 else None
        layers = []
        for i in range(len(dims) - 1):
            out_dim = dims[i + 1]
            # The layer feeding the skip leaves room for the re-injected input.
            if self.skip is not None and i + 1 == self.skip:
                out_dim = dims[i + 1] - 3
            lin = nn.Linear(dims[i], out_dim, dtype=dtype)
            if i == len(dims) - 2:
                nn.init.normal_(lin.weight, mean=math.sqrt(math.pi) / math.sqrt(dims[i]), std=1e-5,
                                generator=generator)
                nn.init.constant_(lin.bias, -radius)
            else:
                nn.init.normal_(lin.weight, 0.0, math.sqrt(2.0) / math.sqrt(out_dim), generator=generator)
                nn.init.constant_(lin.bias, 0.0)
                if self.skip is not None and i == self.skip:
                    # The re-injected coordinates start with no weight so the sphere survives.
                    nn.init.constant_(lin.weight[:, -3:], 0.0)
            layers.append(lin)
        self.layers = nn.ModuleList(layers)
        self.act = nn.Softplus(beta=100)

    def value(self, x: torch.Tensor) -> torch.Tensor:
        h = x
        for i, lin in enumerate(self.layers):
            if self.skip is not None and i == self.skip:
                h = torch.cat([h, x], dim=1) / math.sqrt(2.0)
            h = lin(h)
            if i < len(self.layers) - 1:
                h = self.act(h)
        return h[:, 0]

    def forward(self, x: torch.Tensor, *, with_grad: bool = True):
        """f (B,) and, when ``with_grad``, grad f (B, 3) kept in the graph for the loss."""
        if not with_grad:
            return self.value(x), None
        x = x.detach().requires_grad_(True)
        f = self.value(x)
        (g,) = torch.autograd.grad(f.sum(), x, create_graph=True)
        return f, g
