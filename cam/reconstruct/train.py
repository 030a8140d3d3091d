"""The IGR loss and the Adam loop that minimises it (Gropp et al. 2020, eq. 2).

loss = mean_i |f(x_i)|  +  tau * mean_i ||grad f(x_i) - n_i||  +  lam * E_s (||grad f(s)|| - 1)^2

x_i are a batch of cloud points, n_i their normals (the term is dropped when
there are none), s are the eikonal samples: one Gaussian sample around every
batch point with the point's own sigma (distance to its k-th neighbour) plus
uniform samples in the box, one for every eight points (the paper's mix).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import torch

from cam import CheckCancel, GeometryError, Progress

__all__ = ["DivergedError", "TrainSettings", "train_igr"]


class DivergedError(GeometryError):
    """The loss became NaN or infinite; the message says which setting to lower."""


@dataclass(frozen=True)
class TrainSettings:
    """The schedule and the loss weights of a training run (lam: eikonal, tau: normal term)."""

    iterations: int
    batch_size: int
    learning_rate: float
    lr_final_ratio: float
    lam: float
    tau: float
    schedule: str = "cosine"


def _lr_at(it: int, s: TrainSettings) -> float:
    if s.schedule == "step":  # the paper's: halve every 2000 iterations
        return s.learning_rate * max(0.5 ** (it // 2000), s.lr_final_ratio)
    # Cosine from lr to lr*ratio: with a budget of hundreds of iterations it spends more of
    # them at small steps, which is where the surface settles onto the points.
    p = it / max(1, s.iterations - 1)
    r = s.lr_final_ratio + (1.0 - s.lr_final_ratio) * 0.5 * (1.0 + math.cos(math.pi * p))
    return s.learning_rate * r


def train_igr(
    field: torch.nn.Module,
    points: torch.Tensor,
    normals: torch.Tensor | None,
    sigma: torch.Tensor,
    box: tuple[torch.Tensor, torch.Tensor],
    settings: TrainSettings,
    *,
    generator: torch.Generator,
    param_groups: list[dict] | None = None,
    progress: Progress | None = None,
    check_cancel: CheckCancel | None = None,
) -> dict:
    """Minimise the IGR loss over ``field``'s parameters with Adam.

    Parameters
    ----------
    field : torch.nn.Module
        Maps points (B, 3) to ``(f (B,), grad f (B, 3))``.
    points : Tensor, shape (n, 3), float32
        The cloud in the normalised frame (unit ball), on the field's device.
    normals : Tensor, shape (n, 3), float32, or None
        Their unit normals; None drops the normal term.
    sigma : Tensor, shape (n,), float32
        Standard deviation of each point's Gaussian eikonal samples, normalised frame.
    box : tuple of Tensor, shape (3,), float32
        (lo, hi) of the uniform eikonal samples.
    settings : TrainSettings
        Schedule and loss weights.
    generator : torch.Generator
        Source of every sample (on the field's device).
    param_groups : list of dict, optional
        Adam parameter groups, each with a learning-rate factor under ``lr_scale``;
        None: all of the field's parameters at factor 1.
    progress : callable, optional
        ``progress(fraction, message)`` after every iteration.
    check_cancel : callable, optional
        Called every iteration; it stops training by raising.

    Returns
    -------
    dict
        JSON-ready: ``iterations``, ``final`` (``loss``, ``point``, ``normal`` (None without
        normals), ``eikonal`` at the last iteration) and ``train_s`` (seconds).

    Raises
    ------
    DivergedError
        When the loss becomes NaN or infinite.
    """
    opt, scales = _adam(field, param_groups, settings)
    batch = min(settings.batch_size, len(points))
    started = time.perf_counter()
    terms = {}
    for it in range(settings.iterations):
        if check_cancel is not None:
            check_cancel()
        lr = _lr_at(it, settings)
        for group, scale in zip(opt.param_groups, scales, strict=True):
            group["lr"] = lr * scale
        loss, parts = _igr_loss(field, points, normals, sigma, box, settings, batch=batch, generator=generator)
        if not torch.isfinite(loss):
            raise DivergedError(
                f"training diverged: the loss became {float(loss.detach())} at iteration {it + 1}; "
                "lower reconstruct.learning_rate or check the cloud for outliers"
            )
        opt.zero_grad()
        loss.backward()
        opt.step()
        if progress is not None:
            progress((it + 1) / settings.iterations, f"iteration {it + 1}/{settings.iterations}")
        if it == settings.iterations - 1:
            terms = {"loss": float(loss.detach()),
                     **{k: None if v is None else float(v.detach()) for k, v in parts.items()}}
    return {
        "iterations": settings.iterations,
        "final": terms,
        "train_s": round(time.perf_counter() - started, 3),
    }


def _adam(field: torch.nn.Module, param_groups: list[dict] | None, settings: TrainSettings):
    """Adam over the parameter groups, and each group's learning-rate factor."""
    groups = param_groups or [{"params": list(field.parameters()), "lr_scale": 1.0}]
    spec = [{"params": list(g["params"]), "lr": settings.learning_rate * g.get("lr_scale", 1.0)} for g in groups]
    return _Adam(spec), [g.get("lr_scale", 1.0) for g in groups]


class _Adam:
    """Adam (Kingma and Ba, 2015) over parameter groups, each a dict of ``params`` and ``lr``.

    The same arithmetic as ``torch.optim.Adam``'s single-tensor path on the CPU (betas 0.9 and 0.999,
    eps 1e-8, no weight decay), step for step, so a field trains to the same bits; torch's own class
    spends about a second importing its compiler on first use (an eighth of the README example's
    reconstruction).
    """

    betas = (0.9, 0.999)
    eps = 1e-8

    def __init__(self, param_groups: list[dict]) -> None:
        self.param_groups = param_groups
        self._state: dict[int, tuple[torch.Tensor, torch.Tensor]] = {}
        self._steps = 0

    def zero_grad(self) -> None:
        for group in self.param_groups:
            for p in group["params"]:
                p.grad = None

    @torch.no_grad()
    def step(self) -> None:
        beta1, beta2 = self.betas
        self._steps += 1
        bias_correction1 = 1 - beta1 ** float(self._steps)
        bias_correction2_sqrt = (1 - beta2 ** float(self._steps)) ** 0.5
        for group in self.param_groups:
            step_size = group["lr"] / bias_correction1
            for p in group["params"]:
                if p.grad is None:
                    continue
                if id(p) not in self._state:
                    self._state[id(p)] = (torch.zeros_like(p, memory_format=torch.preserve_format),
                                          torch.zeros_like(p, memory_format=torch.preserve_format))
                exp_avg, exp_avg_sq = self._state[id(p)]
                exp_avg.lerp_(p.grad, 1 - beta1)
                exp_avg_sq.mul_(beta2).addcmul_(p.grad, p.grad, value=1 - beta2)
                denom = (exp_avg_sq.sqrt() / bias_correction2_sqrt).add_(self.eps)
                p.addcdiv_(exp_avg, denom, value=-step_size)


def _igr_loss(field, points, normals, sigma, box, settings: TrainSettings, *, batch: int,
              generator: torch.Generator):
    """The loss on one random batch, and its ``point``, ``normal`` (None without normals) and ``eikonal`` terms."""
    device, dtype = points.device, points.dtype
    lo, hi = box
    idx = torch.randint(len(points), (batch,), generator=generator, device=device)
    x = points[idx]
    near = x + torch.randn(batch, 3, generator=generator, device=device, dtype=dtype) * sigma[idx, None]
    uniform = lo + (hi - lo) * torch.rand(max(1, batch // 8), 3, generator=generator, device=device, dtype=dtype)
    f, g = field(torch.cat([x, near, uniform]))
    fx, gx, gs = f[:batch], g[:batch], g[batch:]
    point_term = fx.abs().mean()
    eikonal = ((gs.norm(dim=1) - 1.0) ** 2).mean()
    loss = point_term + settings.lam * eikonal
    normal_term = None
    if normals is not None:
        normal_term = (gx - normals[idx]).norm(dim=1).mean()
        loss = loss + settings.tau * normal_term
    return loss, {"point": point_term, "normal": normal_term, "eikonal": eikonal}
