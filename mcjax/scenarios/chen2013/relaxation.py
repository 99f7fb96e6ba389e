"""The relaxation switch of Chen & Lu 2013: smooth versions of the step's discrete switches, which
the scenario's ``step`` uses when given a :class:`Temperatures` (training by gradient through the
closed loop, ``mcjax tune``; sensitivities of a sweep). The random draws are the exact step's.

The switches of one step and what replaces each (docs/tune.md, "Chen & Lu 2013"):

* **comm links** (a link iff ``l_ij ≤ R``): weights ``sigmoid((R − l_ij)/T_comm)``
  (:func:`mcjax.tracking.graph.soft_adjacency`). The max-degree weights of eq. 7 and the neighbourhood sums of
  eq. 8 are continuous in the links, so they follow.
* **eq. 13's path point**: whether the circle of radius l about the predicted centre meets the
  path (the grid's test), whether its largest root lies ahead, and the choice between that root
  and the approach rule (:func:`smooth_next_centre`).
* **eq. 15's cap** ``min(|a|, l)`` and the ``capped`` indicator (:func:`smooth_cap`,
  :func:`soft_capped`).

No sensing gate (every UAV measures the wind every step), no hysteresis. Left as they are: the
first step's "update without predicting" (a function of the step count, not of a Param), the
fault model's draws (their rates are :data:`mcjax.scenarios.kit.faults.ROUGH`), and the summary's
formation thresholds (``formation_tolerance``, read only by the summary: rough).
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
from jax import lax

from mcjax.scenarios.chen2013 import guidance
from mcjax.scenarios.kit import faults
from mcjax.tracking.numerics import safe_norm, softmin


class Temperatures(NamedTuple):
    """Temperatures (m) of the relaxation switch (the scenario's ``step`` with ``temperatures``).
    Ours, fixed before any tune was run (docs/tune.md, "Chen & Lu 2013")."""

    comm: float = 1e3   # of the comm links sigmoid((R − l_ij)/T): the step length l, half a formation side
    path: float = 1e2   # of eq. 13's path point: the ramps' width, "the path within l" and "the root ahead"
    cap: float = 10.0   # of eq. 15's cap: softmin(|a|, l) at T (at most T·log 2 below the cap), 1 % of l


#: Params with no smooth path: the fault rates (thresholds of uniform draws), and the formation
#: tolerance (read only by the summary's hard "in formation" test).
ROUGH = (*faults.ROUGH, "formation_tolerance")


def training_errors(cfg, params, record):
    """What the training loss of ``mcjax tune`` reads from a step's record: the wind estimate
    errors (F, n) of every filter and UAV (the ``error`` role's series)."""
    return record.error


def training_weights(cfg, params):
    """Each UAV's weight in the training loss (n,): one each (the scenario switches no UAV off;
    a UAV lost to faults keeps its held estimate, as the loss sees it)."""
    return jnp.ones(cfg.n_agents, jnp.dtype(cfg.dtype))




def smooth_cap(step, l, temperature):
    """Eq. 15's cap with the minimum made smooth: the air step has length
    ``softmin(|a|, l)`` at ``temperature`` (≤ both, at most T·log 2 below the smaller) along
    ``a``. ``step`` (..., 2)."""
    norm = safe_norm(step, axis=-1)[..., None]
    length = softmin(jnp.concatenate([norm, jnp.broadcast_to(l, norm.shape).astype(norm.dtype)], axis=-1),
                     temperature)[..., None]
    return step * length / jnp.maximum(norm, jnp.finfo(step.dtype).tiny)


def soft_capped(wanted, l, temperature, tol):
    """The soft ``capped`` indicator in [0, 1]: ``1 − Π_i (1 − sigmoid((|a_i| − l(1 + tol))/T))``
    (the exact one: some UAV's wanted air step longer than l by the fraction ``tol``)."""
    s = jax.nn.sigmoid((safe_norm(wanted, axis=-1) - l * (1.0 + tol)) / temperature)
    return 1.0 - jnp.prod(1.0 - s)


def _smooth_step01(u):
    """A C-infinity step from 0 (u ≤ 0) to 1 (u ≥ 1): f(u)/(f(u) + f(1 − u)), f(u) = exp(−1/u) for
    u > 0 and 0 otherwise (every derivative is 0 at both ends)."""
    def f(v):
        pos = v > 0
        return jnp.where(pos, jnp.exp(-1.0 / jnp.where(pos, v, 1.0)), 0.0)
    return f(u) / (f(u) + f(1.0 - u))


def _nearest_on_path(psi, centre, l, cells: int, bisections: int = 60):
    """The x in [x̃ − l, x̃ + l] where the path comes nearest the centre (the smallest
    g = :func:`guidance.circle_residual`): the grid's smallest point, refined by bisection on the
    sign of g' over its two neighbouring cells. A value only (the caller stops its gradient)."""
    xs = centre[0] + l * jnp.linspace(-1.0, 1.0, cells + 1, dtype=jnp.result_type(centre, l))
    i = jnp.clip(jnp.argmin(guidance.circle_residual(psi, xs, centre, l)), 1, cells - 1)

    def slope(x):
        return jax.jvp(lambda v: guidance.circle_residual(psi, v, centre, l), (x,), (jnp.ones_like(x),))[1]

    def halve(_, bracket):
        a, b = bracket
        m = 0.5 * (a + b)
        rising = slope(m) > 0
        return jnp.where(rising, a, m), jnp.where(rising, m, b)

    a, b = lax.fori_loop(0, bisections, halve, (xs[i - 1], xs[i + 1]))
    return 0.5 * (a + b)


def smooth_next_centre(psi, centre, l, cells: int, temperature) -> guidance.PathPoint:
    """Eq. 13's next point of the centre (:func:`guidance.next_centre`) with its switches made
    smooth at ``temperature`` (m):

    * the forward root is the exact one (the grid and bisection of :func:`guidance.forward_root`)
      with its derivative by the implicit function theorem, one Newton step on
      g(x) = (x − x̃)² + (Ψ(x) − ỹ)² − l² from the root held fixed (the bisection's own
      derivative ignores ỹ and the path's shape);
    * "the path comes within l" becomes a weight ``s((l − d)/T)``, d the distance from the
      predicted centre to the path's nearest point and s a C-infinity step from 0 (d ≥ l: no
      root) to 1 (d ≤ l − T). At the first touch the root moves like √(l − d), which the step's
      flat start absorbs, so the point stays smooth;
    * "the root lies ahead" (x ≥ x̃) becomes ``s((x − x̃)/T + 1/2)``, a ramp over x − x̃ in ±T/2;
    * the point is the blend ``w·(x, Ψ(x)) + (1 − w)·approach`` with w the product of the two
      weights, which :class:`~guidance.PathPoint` ``on_path`` holds (a float in [0, 1]).

    Not smoothed: the choice of the largest root among several (a new farther crossing, the
    path dipping into the circle again, makes it jump; with the centre on the path and the
    path's curvature radius above l there is only one)."""
    sg = lax.stop_gradient
    x0, found = guidance.forward_root(psi, sg(centre), sg(l), cells)
    x0 = sg(x0)

    def g(x):
        return guidance.circle_residual(psi, x, centre, l)

    slope = sg(jax.jvp(g, (x0,), (jnp.ones_like(x0),))[1])
    safe = found & (jnp.abs(slope) > jnp.finfo(slope.dtype).eps * sg(l) ** 2)
    x_root = x0 - jnp.where(safe, g(x0) / jnp.where(safe, slope, 1.0), 0.0)   # implicit function theorem
    xn = sg(_nearest_on_path(psi, sg(centre), sg(l), cells))
    d = safe_norm(jnp.stack([xn - centre[0], psi(xn) - centre[1]]))           # envelope: d's derivative is exact
    within = jnp.where(found, _smooth_step01((l - d) / temperature), 0.0)
    w = within * _smooth_step01((x_root - centre[0]) / temperature + 0.5)
    on_curve = jnp.stack([x_root, psi(x_root)])
    aim = jnp.stack([centre[0] + l, psi(centre[0] + l)])
    towards = aim - centre
    approach = centre + l * towards / jnp.maximum(jnp.linalg.norm(towards), jnp.finfo(towards.dtype).tiny)
    return guidance.PathPoint(w * on_curve + (1.0 - w) * approach, w)
