"""Path correction of a formation on a curve y = Ψ(x) — Chen & Lu 2013, eqs. 13–16.

The formation's centre aims, each step, at the point of the path at distance ``l`` from its
predicted position (eq. 13); each UAV aims at that point plus its offset from the centre, and
flies at most ``l`` (eq. 15). Everything here is jittable and vmappable; nothing loops in
Python over runs.

Where the paper is silent (our choices, docs/equations.md "Chen & Lu 2013"):

* **the forward root.** Eq. 13's two conditions meet where the circle of radius ``l`` about the
  predicted centre crosses the curve: roots of g(x) = (x − x̃)² + (Ψ(x) − ỹ)² − l², all in
  [x̃ − l, x̃ + l]. The formation flies towards +x, so we take the *largest* root (where the
  curve leaves the circle), and use it only when it lies ahead (x ≥ x̃).
* **the approach rule.** With no forward root (the path farther than ``l``, as at the start),
  the centre moves ``l`` towards the path point one ``l`` ahead in x, (x̃ + l, Ψ(x̃ + l)).
"""

from __future__ import annotations

from typing import NamedTuple

import jax.numpy as jnp
from jax import lax


def sine_path(amplitude, scale):
    """The reference path of Chen & Lu 2013 §3, y = amplitude · sin(x / scale) (the paper:
    2000/3 m and 1200 m)."""
    def psi(x):
        return amplitude * jnp.sin(x / scale)
    return psi


class PathPoint(NamedTuple):
    point: jnp.ndarray   # (2,) the centre's next point P̂(k+1)
    on_path: jnp.ndarray  # () eq. 13 had a forward root (else the approach rule gave ``point``)


def circle_residual(psi, x, centre, l):
    """g(x) = (x − x̃)² + (Ψ(x) − ỹ)² − l², zero where the path meets the circle of eq. 13."""
    return (x - centre[0]) ** 2 + (psi(x) - centre[1]) ** 2 - l ** 2


def forward_root(psi, centre, l, cells: int = 128, bisections: int = 60):
    """The largest x with g(x) = 0 (:func:`circle_residual`) and whether one exists.

    Every root lies in [x̃ − l, x̃ + l] (there g ≥ (x − x̃)² − l² > 0 outside). The interval is cut
    into ``cells`` equal cells; the last grid point with g ≤ 0 and the next one bracket the
    largest root, which ``bisections`` halvings then locate (60 halvings of a cell of 2l/128
    leave far less than a float64 ulp of x). A root missed by the grid — the curve dipping into
    the circle and out again between two grid points — is not found; for a curve whose bends
    are gentle at the scale 2l/cells (Chen & Lu's path: curvature ≤ 4.7e-4 /m, cell 15.6 m),
    that cannot happen. Returns ``(x_root, found)``; x_root is x̃ + l when not found.
    """
    x0 = centre[0]
    xs = x0 + l * jnp.linspace(-1.0, 1.0, cells + 1, dtype=jnp.result_type(centre, l))
    g = circle_residual(psi, xs, centre, l)
    inside = g <= 0
    found = jnp.any(inside)
    last = cells - jnp.argmax(inside[::-1])          # index of the last grid point with g <= 0
    lo = xs[jnp.minimum(last, cells)]
    hi = xs[jnp.minimum(last + 1, cells)]

    def halve(_, bracket):
        a, b = bracket
        m = 0.5 * (a + b)
        below = circle_residual(psi, m, centre, l) <= 0
        return jnp.where(below, m, a), jnp.where(below, b, m)

    lo, hi = lax.fori_loop(0, bisections, halve, (lo, hi))
    root = jnp.where(last >= cells, xs[cells], 0.5 * (lo + hi))
    return jnp.where(found, root, x0 + l), found


def next_centre(psi, centre, l, cells: int = 128) -> PathPoint:
    """The centre's next point P̂(k+1) from its predicted point P̃(k) = ``centre``
    (Chen & Lu 2013 eq. 13): the path point at distance ``l`` ahead (the forward root), or,
    with none, ``l`` towards the path point one ``l`` ahead in x (the approach rule; module
    docstring)."""
    x_root, found = forward_root(psi, centre, l, cells)
    ahead = found & (x_root >= centre[0])
    on_curve = jnp.stack([x_root, psi(x_root)])
    aim = jnp.stack([centre[0] + l, psi(centre[0] + l)])
    towards = aim - centre
    approach = centre + l * towards / jnp.maximum(jnp.linalg.norm(towards), jnp.finfo(towards.dtype).tiny)
    return PathPoint(jnp.where(ahead, on_curve, approach), ahead)


def cap_step(step, l):
    """The flight vector actually flown (Chen & Lu 2013 eq. 15): ``step`` scaled down to length
    ``l`` when longer, unchanged otherwise. ``step`` (..., 2)."""
    norm = jnp.linalg.norm(step, axis=-1, keepdims=True)
    return step * jnp.minimum(1.0, l / jnp.maximum(norm, jnp.finfo(step.dtype).tiny))


def wanted_steps(next_point, offsets, positions, wind_estimates, dt):
    """Each UAV's air displacement before eq. 15's cap (Chen & Lu 2013 eqs. 14 and 16, our
    reading): the ground displacement it wants, ΔF_i = P̂(k+1) + d_i − p_i (eq. 14 as read in
    the issue: to its slot around the centre's next point), less the wind drift it predicts,
    Δz_i = ŵ_i·dt (eq. 16's first term). :func:`cap_step` then gives the air step flown; the
    UAV moves by that plus the true wind's drift. ``offsets`` d_i (n, 2), ``positions`` (n, 2),
    ``wind_estimates`` (n, 2)."""
    return next_point[None, :] + offsets - positions - wind_estimates * dt


def centre_offsets(chain_offsets):
    """Each UAV's offset d_i from the formation's centroid, from pairwise offsets.

    ``chain_offsets`` (n, 2): rows d_12, d_23, …, d_(n−1)n (d_ij = desired p_j − p_i), then the
    closing row d_1n, which must equal the sum of the others (the scenario checks it). Returns
    (n, 2) with Σ_i d_i = 0.
    """
    n = chain_offsets.shape[0]
    rel = jnp.concatenate([jnp.zeros((1, 2), chain_offsets.dtype),
                           jnp.cumsum(chain_offsets[: n - 1], axis=0)])
    return rel - jnp.mean(rel, axis=0)
