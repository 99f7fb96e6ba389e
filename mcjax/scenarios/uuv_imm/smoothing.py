"""The smoothing switch of Ren & Lv 2017's scenario: smooth versions of the sonar's range gate,
the comm links, the component sizes the consensus weighs the measurement information by, and
the IMM's "likelier mode" indicator. The scenario's ``step`` uses them when given a
:class:`Smoothing` (training by gradient, ``mcjax tune``; sensitivities of a sweep).

What stays rough (no smooth path): the target's mode jumps — the fixed schedule's switch at
``ct_start`` / ``ct_stop`` (step counts) and the Markov chain's draws (thresholds of uniform
numbers) — and the fault model's draws (:data:`mcjax.scenarios.faults.ROUGH`)."""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from mcjax import graph
from mcjax.models.sensors import range_bearing
from mcjax.scenarios import kit


class Smoothing(NamedTuple):
    """Temperatures of the smoothing switch (the scenario's ``step`` with ``smoothing``); ours,
    fixed before any tune was run. The UUVs of the paper's layout are 400 m from their ring
    neighbours and the default comm radius is 450 m, so the smallest link margin is 50 m: at
    10 m a ring link weighs sigmoid(5) = 0.993 and a second neighbour (693 m) 3e-11."""

    sensing: float = 10.0   # m, the sonar's range gate sigmoid((R_s − r)/T)
    comm: float = 10.0      # m, the comm links sigmoid((min(R_i, R_j) − l_ij)/T) and the component sizes
    mode: float = 0.05      # probability, the IMM's "CT is likelier" indicator sigmoid((μ_CT − 0.5)/T)


def smooth_measurements(key, target, sensors, params, sensing_radius, alive, temperature):
    """Every alive UUV's range–bearing measurement (the same noise draws as
    :func:`mcjax.scenarios.kit.team_measurements`, so the same numbers as the exact
    simulation's where it measures) with the sonar's range gate ``r ≤ R_s`` replaced by a soft
    gate ``g_i = sigmoid((R_s − r_i)/T)``: returns ``(z (n, 2), g (n,))``. The filter weighs
    UUV i's measurement by ``g_i`` (its tempered likelihood ``p(z_i | x)^g_i``,
    :func:`mcjax.filters.consensus_imm.consensus_imm_ukf_step`). Dead UUVs: NaN, ``g = 0``."""
    dtype = sensors.dtype
    z = kit.team_measurements(key, target, sensors, params.sigma_range, params.sigma_bearing,
                              jnp.full(sensors.shape[0], jnp.inf, dtype), alive)
    r = jax.vmap(range_bearing, in_axes=(None, 0))(target, sensors)[:, 0]
    gates = jax.nn.sigmoid((sensing_radius - r) / temperature)
    return z, jnp.where(alive, gates, 0.0)


def smooth_adjacency(sensors, comm_radius, alive, temperature):
    """The comm graph (link i–j iff ``l_ij ≤ min(R_i, R_j)``, :func:`mcjax.graph.adjacency`) with
    each link a weight ``a_ij = sigmoid((min(R_i, R_j) − l_ij)/T)`` in (0, 1): the consensus
    weights of Ren & Lv 2017 (Metropolis, eq. 8) are built from these weights as from 0/1 links
    (the soft degrees ``d_i = Σ_j a_ij``). Zero diagonal, dead UUVs unlinked; finite gradients
    for coincident UUVs (safe norm)."""
    n = sensors.shape[0]
    a = jax.nn.sigmoid(graph.link_margins(sensors, comm_radius) / temperature)
    keep = ~jnp.eye(n, dtype=bool) & alive[:, None] & alive[None, :]
    return jnp.where(keep, a, 0.0)


def smooth_component_sizes(sensors, comm_radius, alive, temperature):
    """Smooth size ``N_i`` of each UUV's connected component (the weight of its measurement
    information in the consensus, :mod:`mcjax.filters.consensus_imm`): ``1 + Σ_{j≠i}
    sigmoid(ρ_ij/T)`` with ρ the smooth multi-hop link margin of the widest path
    (:func:`mcjax.graph.smooth_pair_robustness`): j is in i's component iff ρ_ij ≥ 0, and
    sigmoid(ρ/T) is the widest path of the soft links of :func:`smooth_adjacency`. Paths
    through dead UUVs are not excluded; links lost to faults are not seen."""
    n = sensors.shape[0]
    rho = graph.smooth_pair_robustness(sensors, comm_radius, temperature)
    keep = ~jnp.eye(n, dtype=bool) & alive[:, None] & alive[None, :]
    reach = jnp.where(keep, jax.nn.sigmoid(jnp.where(keep, rho, 0.0) / temperature), 0.0)
    return 1.0 + jnp.sum(reach, axis=-1)


def mode_hits(mu_ct, turns, temperature=None):
    """Per UUV (n,), whether the IMM's likelier mode is the target's true one: ``μ_CT > 0.5``
    equals ``turns`` (the target is in CT) → 1.0, else 0.0 — what the output ``mode_accuracy``
    averages. With a ``temperature`` T the indicator of ``μ_CT > 0.5`` becomes
    ``sigmoid((μ_CT − 0.5)/T)`` (the true mode is the truth's, not smoothed). NaN ``μ_CT``
    (no IMM) gives 0/1 in the exact simulation and NaN when smoothed; ``mode_accuracy`` is
    NaN then either way."""
    if temperature is None:
        return ((mu_ct > 0.5) == turns).astype(mu_ct.dtype)
    p = jax.nn.sigmoid((mu_ct - 0.5) / temperature)
    return jnp.where(turns, p, 1.0 - p)
