"""The adapt-then-combine (ATC) diffusion Kalman filter of Cattivelli & Sayed 2010, a filter of one's own.

F. S. Cattivelli and A. H. Sayed, "Diffusion strategies for distributed Kalman filtering and smoothing",
IEEE Trans. Automatic Control 55(9), 2010 — the ATC diffusion KF algorithm, in its information form. At
every node k, with N_k its neighbourhood *including k itself*:

1. incremental update (adapt): from the prediction ``(x̄_k, P̄_k)`` fold in the measurement of every node
   ``l ∈ N_k``::

       P_k⁻¹ = P̄_k⁻¹ + Σ_{l∈N_k} H_lᵀ R_l⁻¹ H_l
       ψ_k   = P_k (P̄_k⁻¹ x̄_k + Σ_{l∈N_k} H_lᵀ R_l⁻¹ y_l)

2. diffusion update (combine): ``x̂_k = Σ_{l∈N_k} c_{l,k} ψ_l`` with ``c_{l,k} ≥ 0``, ``Σ_l c_{l,k} = 1``;
   the covariance kept is ``P_k`` of step 1, as in the paper's algorithm;
3. time update: ``x̄ ← F x̂``, ``P̄ ← F P Fᵀ + Q`` (done at the start of the next call of :func:`step`,
   the contract's timing: ``F = I, Q = 0`` at the first measurement time).

Choices (the paper's model is linear; ours may not be):

* EKF form: every neighbour's measurement is linearised at node k's **own** prediction ``x̄_k``, all at
  once — ``H_{kl} = ∂h/∂x (x̄_k; s_l)``, ``H_lᵀ R_l⁻¹ y_l`` becomes
  ``H_{kl}ᵀ R_l⁻¹ (z_l − h(x̄_k; s_l) + H_{kl} x̄_k)`` with the angle components of the innovation
  wrapped (:func:`mcjax.tracking.filters.gaussian.contributions`, one call per node k over every l). The
  paper's sequential incremental form would relinearise after each neighbour; with a linear ``h`` the two
  are the same.
* the neighbourhood is the links that carried a message this step, ``meas.adjacency`` (faults already
  removed), plus the node itself; a link's information is weighted by ``a_kl`` (1 on a 0/1 graph, the
  paper's sum; a smooth surrogate on a soft graph). A node without a measurement contributes nothing.
* the combination weights are the scenario's consensus matrix,
  ``c_{l,k} = W_kl`` of :func:`mcjax.tracking.filters.consensus.consensus_matrix` (``options.weights``
  over this step's links: row-stochastic, nonnegative), applied once per step whatever
  ``options.consensus_steps`` (ATC diffusion has one combination per step). Dense or sparse as
  ``options.exchange`` for the combination (:func:`mcjax.tracking.filters.consensus.consensus`); the
  measurement pooling is always over the (n, n) pairs.

Two exchanges per step cross a link: each node's measurement ``z_l``, sensor position ``s_l`` and
``R_l⁻¹``, then its intermediate estimate ``ψ_l``. Both are of this step, so a late message cannot join
(no late messages). Written only through mcjax's public names.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from mcjax.contract.filter import Filter, Traits
from mcjax.tracking.filters.consensus import consensus, consensus_matrix
from mcjax.tracking.filters.gaussian import Gaussian, contributions, from_information, predict_information


def neighbour_contributions(h, z, sensors, x_lin, R_inv, angle_mask):
    """Every node l's measurement information as node k sees it, linearised at node k's ``x_lin[k]``:
    ``(i, I)`` of shapes (n_k, n_l, d) and (n_k, n_l, d, d), zero where ``z_l`` is missing."""

    def at(x_k):
        i, I, _ = contributions(h, z, sensors, x_k, R_inv, angle_mask)
        return i, I

    return jax.vmap(at)(x_lin)


def incremental_update(model, post: Gaussian, meas) -> Gaussian:
    """Predict, then step 1 (adapt) of the ATC diffusion KF: each node's intermediate estimate
    ``(ψ_k, P_k, P_k⁻¹)`` from its prediction and the measurements of its neighbourhood (module docstring)."""
    x_bar, _, y_bar, Y_bar = predict_information(post.x, post.P, model.F, model.Q)
    i, I = neighbour_contributions(model.h, meas.z, meas.sensors, x_bar, meas.R_inv, model.angle_mask)
    A = meas.adjacency
    links = A + jnp.eye(A.shape[0], dtype=A.dtype)  # N_k: the carried links and the node itself
    q = jnp.einsum("kl,kld->kd", links, i)
    S = jnp.einsum("kl,klde->kde", links, I)
    return from_information(y_bar + q, Y_bar + S)


def step(model, post: Gaussian, meas) -> Gaussian:
    """One step of the ATC diffusion KF for every node (module docstring): predict, incremental update,
    then the combination ``x̂_k = Σ_l W_kl ψ_l``; the covariance is the incremental update's ``P_k``."""
    psi = incremental_update(model, post, meas)
    W = consensus_matrix(model.options, meas.adjacency)
    return Gaussian(consensus(W, psi.x, 1), psi.P, psi.Y)


DIFFUSION_KF = Filter(
    "diffusion_kf",
    "diffusion Kalman filter (adapt then combine): an update with the neighbours' measurements, then a convex "
    "combination of the neighbours' intermediate estimates",
    "Cattivelli & Sayed 2010, IEEE TAC 55(9), ATC diffusion KF",
    step,
    Traits(centralised=False, late_messages=False, messages=True, weights="any", consensus_only=False),
)
