"""The MeshTGV weights the measured noise calls for (used when the user did not set them).

Two regimes, blended by how correlated the noise is (``NoiseEstimate.correlation``, the ratio of the
3-ring to the 2-ring quadric sigma):

* white noise (every vertex off on its own, as in the synthetic benchmark meshes): the first-order
  weight alpha1 grows with the noise as sigma^1.3 above the level the base weights (0.15, 0.4) were
  tuned at, and falls the same way below it, so that clean and lightly noisy meshes are left nearly
  alone; alpha0 follows below that level and stays at 0.15 above it. The base weights were tuned
  jointly on Fandisk and Block, whose noise this estimate reads as 0.26 and 0.18 mean edge lengths:
  between the two they apply unchanged.
* correlated noise (the real Kinect scan: depth errors that move patches of vertices together):
  a quadric of a small neighbourhood follows such bumps, and TGV with a small alpha0 keeps them as
  if they were curved surface. A larger alpha0 (the normal field's second derivative is dearer)
  flattens them: alpha0 0.6, alpha1 1.0, again scaled down below the noise level where they were
  tuned (the Kinect cone's 0.07 mean edge lengths).

How the numbers were found (sweeps of alpha0, alpha1 at 100 iterations; mean face-normal error of the
filtered normals, degrees):
  Fandisk, its benchmark noise (sigma 0.26): (0.15, 0.4) 1.81; (0.15, 0.8) 3.27; (0.3, 0.4) 2.87.
  Fandisk with Gaussian noise of 0.5 mean edge lengths along the normals (sigma 0.42): alpha1 0.4
  13.4, 0.6 4.4, 0.7 4.2, 0.8 4.0, 1.0 5.3, 1.2 10.5 (alpha0 0.15; 0.1-0.6 at alpha1 0.8: 4.0-6.0).
  Fandisk with 0.1 mean edge lengths (sigma 0.11): weights x1 1.94, x0.67 1.27, x0.4 0.87.
  Kinect cone (sigma 0.072, correlation 1.36): alpha1 0.8-1.6 with alpha0 0.4-1.2: 6.73-6.92;
  alpha0 0.15: 7.79-7.84 whatever alpha1. The Kinect cone's clean surface with white noise of 0.15
  edge lengths (correlation 1.02) prefers the white-noise weights (2.54 against 4.36 with 0.6, 1.0):
  the scan needs stronger weights because of how its noise is correlated, not because of its shape.

The vertex update's iterations follow the correlated share too: the paper's 20 for white noise, 300 for
correlated noise at the level it was tuned at, none extra below half that level. The update moves each
vertex by the planes of its own faces, so a correction travels about a ring per iteration; a scanner's
noise moves patches of vertices together, and 20 iterations leave the mesh short of the filtered normals.
Reconstructions read correlated but far fainter noise (0.006-0.02 mean edge lengths) and keep 20: with
31-38 iterations the 50k-point Fandisk and Block clouds' meshes lay as near the true parts as with 20
(mean 0.0074 and 0.0044 mm either way), and 70 on the README example changed QuadriFlow's layout for
the worse (three failed runs, 18 s instead of 4).
Mean face-normal error of the result mesh, degrees (filtered normals: Kinect cone 6.76, Fandisk 1.81):
  Kinect cone, iterations 20 / 60 / 150 / 300 / 1000: 7.99 / 7.31 / 6.94 / 6.80 / 6.74 (the authors'
  result mesh 7.23); white noise, 20 / 150 / 300: Fandisk 1.63 / 1.69 / 1.73, with 0.5 mean edge
  lengths 3.66 / 3.76 / 3.79, with 0.1 0.88 / 0.95 / 0.97: there the update stops early to good effect.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cam.denoise.noise import NoiseEstimate

__all__ = ["Weights", "weights_for_noise"]

#: alpha0, alpha1 tuned on Fandisk and Block with their benchmark noise.
WHITE_ALPHA0 = 0.15
WHITE_ALPHA1 = 0.4
#: The noise (sigma, mean edge lengths) between which the white-noise base weights apply unchanged.
WHITE_SIGMA_LOW = 0.18
WHITE_SIGMA_HIGH = 0.26
#: alpha1 ~ sigma^this away from that band (fits Fandisk at 0.11, 0.26 and 0.42).
WEIGHT_EXPONENT = 1.3
#: Weights for strongly correlated noise, and the noise level below which they scale down.
CORRELATED_ALPHA0 = 0.6
CORRELATED_ALPHA1 = 1.0
CORRELATED_SIGMA = 0.07
#: The correlation ratio where the blend from white to correlated starts and ends. White noise read
#: 1.01-1.14 on every mesh measured, the Kinect scan 1.36; the ramp sits halfway, 0.06 from each.
CORRELATION_WHITE = 1.2
CORRELATION_FULL = 1.3
#: Vertex-update iterations for white and for correlated noise, and the noise (mean edge lengths) over which
#: correlated noise goes from none of the extra iterations to all of them.
WHITE_VERTEX_ITERATIONS = 20
CORRELATED_VERTEX_ITERATIONS = 300
ITERATION_SIGMA_LOW = 0.035
ITERATION_SIGMA_HIGH = 0.07


@dataclass(frozen=True)
class Weights:
    """The TGV weights chosen for a mesh, and why."""

    alpha0: float
    alpha1: float
    correlated_share: float  # 0: white-noise weights, 1: correlated-noise weights
    vertex_iterations: int

    def as_report(self) -> dict:
        """Plain JSON types, for ``denoise.json``."""
        return {"alpha0": float(self.alpha0), "alpha1": float(self.alpha1),
                "correlated_share": float(self.correlated_share), "vertex_iterations": int(self.vertex_iterations)}


def weights_for_noise(noise: NoiseEstimate) -> Weights:
    """alpha0 and alpha1 (dimensionless, mesh in mean edge lengths) for the measured noise.

    Parameters
    ----------
    noise : NoiseEstimate
        From :func:`cam.denoise.noise.estimate_noise` on the mesh in mean edge lengths.

    Returns
    -------
    Weights
        Both weights non-negative (zero on a mesh without measurable noise: the filter then leaves
        the normals as they are, its linear systems depend on the penalties only), the share of
        the correlated-noise regime in the blend and the vertex update's iterations.

    Raises
    ------
    ValueError
        When sigma or the correlation is negative or not finite.
    """
    sigma, corr = noise.sigma, noise.correlation
    if not (np.isfinite(sigma) and sigma >= 0 and np.isfinite(corr) and corr >= 0):
        raise ValueError(f"noise estimate must be finite and non-negative, got sigma={sigma!r}, "
                         f"correlation={corr!r}")
    below = min(1.0, sigma / WHITE_SIGMA_LOW) ** WEIGHT_EXPONENT
    above = max(1.0, sigma / WHITE_SIGMA_HIGH) ** WEIGHT_EXPONENT
    white0, white1 = WHITE_ALPHA0 * below, WHITE_ALPHA1 * below * above
    corr_scale = min(1.0, sigma / CORRELATED_SIGMA) ** WEIGHT_EXPONENT
    corr0, corr1 = CORRELATED_ALPHA0 * corr_scale, CORRELATED_ALPHA1 * corr_scale
    share = float(np.clip((corr - CORRELATION_WHITE) / (CORRELATION_FULL - CORRELATION_WHITE), 0.0, 1.0))
    alpha0 = (1 - share) * white0 + share * corr0
    alpha1 = (1 - share) * white1 + share * corr1
    level = np.clip((sigma - ITERATION_SIGMA_LOW) / (ITERATION_SIGMA_HIGH - ITERATION_SIGMA_LOW), 0.0, 1.0)
    extra = (CORRELATED_VERTEX_ITERATIONS - WHITE_VERTEX_ITERATIONS) * share * float(level)
    return Weights(alpha0=float(alpha0), alpha1=float(alpha1), correlated_share=share,
                   vertex_iterations=WHITE_VERTEX_ITERATIONS + round(extra))
