"""The relaxation switch of Lou, Cui & Li 2013's flock: soft links with hysteresis and the
potential faded out at R, which the scenario's ``step`` uses when given a :class:`Temperatures`
(training by gradient through the closed loop, ``mcjax tune``; sensitivities of a sweep).

The step's discrete switches and what the smooth step puts in their place:

* the hysteresis graph (Section 1.1, rules 2–3: a link is kept while ``r < R``, a new one
  forms only below ``R − ε``), a 0/1 state → a weight ``a_ij`` in [0, 1] carried in the same
  state (:func:`soft_hysteresis`); the KCF's exchange, the alignment of eq. 11, ``ḃ_ij`` and
  the energy of eq. 15 weigh each pair by it;
* the potential of eq. 12 on a link, which is +∞ at R (a link at R is a broken run) → the
  faded potential :func:`mcjax.scenarios.lou2013.model.faded_potential`, 0 at and beyond
  R, so a pair of small weight near or beyond R feels a finite force;
* the counts of links formed and broken → their soft counts (:func:`soft_link_changes`).

Not switches here: the sensing gate is the node's type (type-I nodes always measure; M is an
integer Param), the step-0 filter model is a time, and the sub-steps
(:func:`~mcjax.scenarios.lou2013.dynamics.dopri5_adaptive`, or ``rk4_adaptive``) are the
integrator's — the smooth step goes through the same sub-stepping (the error control on the
smooth flock; the closing-speed cap and the margins over the links of weight > 1/2). Its while
loop has a data-dependent length, which JAX differentiates in forward mode only.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from mcjax.scenarios.kit import faults
from mcjax.tracking import graph


class Temperatures(NamedTuple):
    """Temperatures (m) of the relaxation switch (the scenario's ``step`` with ``temperatures``).
    Defaults (ours, from the geometry, not from results): ``links`` = ε/20 with the paper's
    ε = 0.4 m, so the two rules stay 20 temperatures apart and a pair that the exact graph
    does not link weighs at most ``exp(−ε/T) ≈ 2e−9`` near R; ``barrier`` = 0.02 m, so the
    faded potential equals eq. 12's wherever a link is more than 5 cm from R (in 8 runs of the
    paper's set-up the exact flock's links stayed 0.30 m or more from R)."""

    links: float = 0.02     # m: the soft link rules sigmoid((R − r)/T) (kept) and sigmoid((R − ε − r)/T) (formed)
    barrier: float = 0.02   # m: the width w over which a link's potential fades out at R


#: Params with no smooth path (:class:`mcjax.contract.relaxation.Relaxation`): the fault rates; the start
#: rule's thresholds (they accept or reject an initial draw: derivative 0 almost everywhere);
#: the sub-step safety factor (it sets the integrator's sub-steps, not the model).
ROUGH = (*faults.ROUGH, "start_margin", "start_min_distance", "substep_safety")


def soft_hysteresis(previous, positions, R, epsilon, temperature):
    """The hysteresis graph of Lou et al. 2013 §1.1 (rules 2–3; exact:
    :func:`mcjax.tracking.graph.hysteresis_adjacency`) with soft links (ours):
    ``a′_ij = a_ij σ((R − r_ij)/T) + (1 − a_ij) σ((R − ε − r_ij)/T)`` — a link of weight a is
    kept with the weight of ``r < R`` and formed with that of ``r < R − ε``. For 0/1 weights and
    ``T → 0`` it is the exact rule (at every distance but the two thresholds). Zero diagonal;
    symmetric when ``previous`` is; finite gradients for coincident nodes."""
    n = positions.shape[-2]
    r = graph.pairwise_distances(positions)
    a = previous * jax.nn.sigmoid((R - r) / temperature) + (1.0 - previous) * jax.nn.sigmoid(
        (R - epsilon - r) / temperature)
    return jnp.where(jnp.eye(n, dtype=bool), 0.0, a)


def soft_link_changes(before, after):
    """Soft counts of the links formed and broken between two weighted graphs (ours):
    ``Σ_{i<j} a′_ij (1 − a_ij)`` and ``Σ_{i<j} (1 − a′_ij) a_ij`` — the exact counts for 0/1
    weights."""
    upper = jnp.triu(jnp.ones_like(after), 1)
    return jnp.sum(upper * after * (1.0 - before)), jnp.sum(upper * (1.0 - after) * before)
