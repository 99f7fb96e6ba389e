"""Consensus IMM-UKF — Ren & Lv 2017 after Li & Jia 2012, docs/equations.md.

Per node i and mode j: mix (:func:`mcjax.tracking.filters.imm.mix`) → UKF predict with the mode's
transition → the pseudo-measurement information ``(i_ij, I_ij)`` of the node's own
measurement (:func:`mcjax.tracking.filters.gaussian.ukf_pseudo_measurement`) → ``L`` consensus
iterations per mode on the information pairs → information-form update → mode
probabilities → combination. Nodes sit on axis 0, modes on axis 1.

Our choices (the papers are silent): the consensus runs on ``(ȳ_ij + N_i i_ij, Ȳ_ij + N_i
I_ij)`` with ``N_i`` the size of node i's connected component — the information
weighting of Kamal et al. 2013 used for the ICF in this package — so that on a connected
graph with many iterations every node holds the mean prior plus the *sum* of all
measurement information, as the centralised filter does. The mode likelihoods are
``likelihood="fused"`` (default): the log-likelihoods ``log Λ_ij`` of the nodes'
own innovations are summed by the same consensus (``N_i`` × average), the centralised
likelihood of independent measurements; ``"local"`` uses only node i's own (Li & Jia).
"""

from __future__ import annotations

from typing import Callable

import jax
import jax.numpy as jnp

from mcjax.tracking import graph
from mcjax.tracking.filters.gaussian import Unscented, ukf_predict, ukf_pseudo_measurement, ukf_update
from mcjax.tracking.filters.imm import IMMState, combine, mix, mode_probabilities
from mcjax.tracking.numerics import spd_inverse, symmetrize
from mcjax.tracking.numerics import weighted_agent_sum

LIKELIHOODS = ("fused", "local")


def consensus_imm_ukf_step(state: IMMState, transition, F_modes, Q_modes, z, sensors, h: Callable, R,
                           adjacency, *, steps: int, weights: str = "metropolis",
                           likelihood: str = "fused", ut: Unscented = Unscented(), angle_mask=None,
                           gates=None, sizes=None):
    """One step of every node (Ren & Lv 2017, docs/equations.md). ``state``: IMMState with a node
    axis first (μ (n, M), x (n, M, d), P (n, M, d, d)); ``F_modes``/``Q_modes`` (M, d, d);
    ``z`` (n, m) (NaN: no measurement); ``sensors`` (n, ·); ``h(x, sensor)``; ``R`` (m, m);
    ``adjacency`` (n, n) 0/1 links, or link weights in [0, 1] (a smooth comm graph: the
    consensus weights are built from them the same way); ``steps`` = L; ``weights``
    "metropolis" or "max_degree" (the iteration of Ren & Lv 2017 eq. 8).

    The smooth inputs (a scenario's relaxation switch; None: the exact filter): ``gates`` (n,)
    in [0, 1] weighs node i's measurement — its information pair and its mode log-likelihoods
    are multiplied by ``g_i``, i.e. the tempered likelihood ``p(z_i | x)^g_i`` (the noise
    ``R/g_i`` in the information form): the full update at 1, none at 0; ``sizes`` (n,)
    replaces the connected-component sizes ``N_i`` of ``adjacency``.
    Returns ``(new state, (x, P) combined per node)``."""
    if likelihood not in LIKELIHOODS:
        raise ValueError(f"likelihood must be one of {', '.join(LIKELIHOODS)}; got {likelihood!r}")
    R_inv = spd_inverse(R)
    cbar, x0, P0 = jax.vmap(mix, in_axes=(0, None))(state, transition)

    def predict(x, P, F, Q):
        return ukf_predict(x, P, lambda s: F @ s, Q, ut)

    xb, Pb = jax.vmap(jax.vmap(predict, in_axes=(0, 0, 0, 0)), in_axes=(0, 0, None, None))(x0, P0, F_modes, Q_modes)

    def local(x, P, z_i, s_i):
        h_i = lambda s: h(s, s_i)  # noqa: E731
        i, I, _ = ukf_pseudo_measurement(x, P, z_i, h_i, R_inv, ut, angle_mask)
        _, _, ll = ukf_update(x, P, z_i, h_i, R, ut, angle_mask)
        return i, I, ll

    i, I, ll = jax.vmap(jax.vmap(local, in_axes=(0, 0, None, None)))(xb, Pb, z, sensors)
    if gates is not None:
        i, I, ll = gates[:, None, None] * i, gates[:, None, None, None] * I, gates[:, None] * ll
    Yb = symmetrize(spd_inverse(Pb))
    yb = jnp.einsum("nmab,nmb->nma", Yb, xb)
    size = graph.component_sizes(adjacency) if sizes is None else sizes
    W = graph.consensus_weights(adjacency, weights)

    def run(v):
        return jax.lax.fori_loop(0, steps, lambda _, u: weighted_agent_sum(W, u), v)

    Y = run(Yb + size[:, None, None, None] * I)
    y = run(yb + size[:, None, None] * i)
    if likelihood == "fused":
        ll = size[:, None] * run(ll)
    P = symmetrize(spd_inverse(Y))
    x = jnp.einsum("nmab,nmb->nma", P, y)
    mu = jax.vmap(mode_probabilities)(cbar, ll)
    new = IMMState(mu, x, P)
    return new, jax.vmap(combine)(new)
