"""The smoothing switch of Sun et al. 2011: smooth versions of the sensing gate and the comm
graph, which the scenario's ``step`` uses when given a :class:`Smoothing` (training by gradient
through the closed loop, ``mcjax tune``; sensitivities of a sweep)."""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from mcjax import graph
from mcjax.models.sensors import range_bearing
from mcjax.scenarios import kit


class Smoothing(NamedTuple):
    """Temperatures (m) of the smoothing switch (the scenario's ``step`` with ``smoothing``)."""

    sensing: float = 1e3   # of the sensing gate sigmoid((R_s − r)/T)
    comm: float = 1e3      # of the comm links sigmoid((min(R_i, R_j) − l_ij)/T)


def smooth_measurements(key, target, sensors, params, sensing_radius, alive, temperature):
    """Every alive agent's range–bearing measurement (Sun et al. 2011 §1.3, the same noise draws
    as :func:`mcjax.scenarios.kit.team_measurements`) with the range gate of §5 replaced by a
    soft gate ``g_i = sigmoid((R_s − r_i)/T)``: returns ``(z (n, 2), g (n,))``; the caller
    weighs agent i's measurement information (eq. 10) by ``g_i``. Dead agents: NaN, ``g = 0``."""
    dtype = sensors.dtype
    z = kit.team_measurements(key, target, sensors, params.sigma_range, params.sigma_bearing,
                              jnp.full(sensors.shape[0], jnp.inf, dtype), alive)
    r = jax.vmap(range_bearing, in_axes=(None, 0))(target, sensors)[:, 0]
    gates = jax.nn.sigmoid((sensing_radius - r) / temperature)
    return z, jnp.where(alive, gates, 0.0)


def smooth_adjacency(sensors, comm_radius, alive, temperature):
    """The comm graph of Sun et al. 2011, eq. 13 with each link a weight
    ``a_ij = sigmoid((min(R_i, R_j) − l_ij)/T)`` in (0, 1) instead of the 0/1 test; zero
    diagonal, dead agents unlinked. Gradients are finite for coincident agents (safe norm)."""
    n = sensors.shape[0]
    a = jax.nn.sigmoid(graph.link_margins(sensors, comm_radius) / temperature)
    keep = ~jnp.eye(n, dtype=bool) & alive[:, None] & alive[None, :]
    return jnp.where(keep, a, 0.0)


def smooth_component_sizes(sensors, comm_radius, alive, temperature):
    """Smooth size of each agent's connected component (the weight ``n_i`` of the ICF
    contributions, docs/equations.md): ``1 + Σ_{j≠i} sigmoid(ρ_ij/T)`` with ρ the smooth
    multi-hop pair robustness (Sun et al. 2011 eq. 14, :func:`mcjax.graph.smooth_pair_robustness`):
    j is in i's component iff ρ_ij ≥ 0, and sigmoid(ρ/T) is the widest path of the soft links of
    :func:`smooth_adjacency` (sigmoid is monotone). Paths through dead agents are not excluded."""
    n = sensors.shape[0]
    rho = graph.smooth_pair_robustness(sensors, comm_radius, temperature)
    keep = ~jnp.eye(n, dtype=bool) & alive[:, None] & alive[None, :]
    reach = jnp.where(keep, jax.nn.sigmoid(jnp.where(keep, rho, 0.0) / temperature), 0.0)
    return 1.0 + jnp.sum(reach, axis=-1)
