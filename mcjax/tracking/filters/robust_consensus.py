"""Two consensus filters of Battistelli & Chisci with guaranteed stability: CI and HCMCI.

Same signature as the filters of :mod:`mcjax.tracking.filters.consensus` (``filter_step`` kinds ``"ci"`` and
``"hcmci"``); one call advances every agent of one run by one step, agents on the leading axis.
Both filters work on each agent's information pair ``(Ω, q) = (P⁻¹, P⁻¹ x)`` and average it with
**Metropolis weights** of the links that carried a message this step (``meas.adjacency``, which
already excludes the links lost to faults): ``π_ij = 1/(1 + max(d_i, d_j))`` on a link,
``π_ii = 1 − Σ_{j≠i} π_ij`` (:func:`mcjax.tracking.graph.metropolis_weights`; symmetric and doubly
stochastic on any undirected graph, the weights of both papers' simulations). They are fixed here,
whatever ``opts.weights`` says: HCMCI's ``ω = N`` needs doubly stochastic weights (Sun et al.
2011's ``"eq11"`` are only row-stochastic), and CI's guarantee needs a convex combination, which
Metropolis weights are. ``L = opts.consensus_steps``; ``opts.exchange`` (dense or sparse sums) is the
only other option read.

Timing as everywhere in mcjax: the caller passes ``F = I, Q = 0`` at the first measurement time,
so step 0 corrects the prior without predicting. The EKF contributions are linearised at each
agent's own prediction ``x̄_i`` (:func:`mcjax.tracking.filters.gaussian.contributions`; zero where the
agent has no measurement, angle components of the innovation wrapped).

The equation numbers of the papers are not quoted here: we cite the algorithms by the names the
papers give them (the notes of the work, and docs/equations.md once written, hold the equations).
"""

from __future__ import annotations

from mcjax.contract.filter import Filter, Traits
from mcjax.tracking.filters.consensus import FilterOptions, Measurements, consensus, consensus_matrix
from mcjax.tracking.filters.gaussian import Gaussian, contributions, from_information, predict_information
from mcjax.tracking.numerics import symmetrize


def _metropolis(opts: FilterOptions, adjacency):
    """Metropolis weights of the links that carried a message, dense or sparse as ``opts.exchange``."""
    return consensus_matrix(opts, adjacency, "metropolis")


def ci_step(h, angle_mask, opts: FilterOptions, post: Gaussian, meas: Measurements, F, Q) -> Gaussian:
    """Consensus on information (CI) with covariance-intersection weights: Battistelli & Chisci
    2014 (Automatica 50, "Kullback–Leibler average, consensus on probability densities, and
    distributed state estimation with guaranteed stability"), their distributed Kalman filter by
    consensus on posteriors — called "CI" in Battistelli et al. 2015 (IEEE TAC 60).

    Each agent i, with Metropolis weights ``π`` of ``meas.adjacency`` and ``L = opts.consensus_steps``:

    * prediction in information form: ``Ω̄_i = (F P_i Fᵀ + Q)⁻¹``, ``q̄_i = Ω̄_i F x_i``;
    * local correction with its OWN measurement only (linearised at ``x̄_i``):
      ``Ω_i⁽⁰⁾ = Ω̄_i + H_iᵀ R_i⁻¹ H_i``, ``q_i⁽⁰⁾ = q̄_i + H_iᵀ R_i⁻¹ (z_i − h_i(x̄_i) + H_i x̄_i)``;
    * L consensus steps on the pair, ``Ω_i⁽ˡ⁺¹⁾ = Σ_j π_ij Ω_j⁽ˡ⁾``, ``q_i⁽ˡ⁺¹⁾ = Σ_j π_ij q_j⁽ˡ⁾``:
      the Kullback–Leibler average of the neighbours' Gaussians, i.e. multi-node covariance
      intersection with the consensus weights as CI weights;
    * ``P_i = (Ω_i⁽ᴸ⁾)⁻¹``, ``x_i = P_i q_i⁽ᴸ⁾``.

    Every fused pair is a convex combination of consistent estimates, so the covariance stays
    conservative whatever the (unknown) correlations between agents — the paper's guarantee, at
    the price of under-weighting the new measurements (their information is averaged, not summed).
    Numerically this is the modified ICF of Sun et al. 2011 with ``contribution="one"`` and
    Metropolis weights.
    """
    xb, _, qb, Ob = predict_information(post.x, post.P, F, Q)
    dq, dO, _ = contributions(h, meas.z, meas.sensors, xb, meas.R_inv, angle_mask)
    W = _metropolis(opts, meas.adjacency)
    q = consensus(W, qb + dq, opts.consensus_steps)
    O = symmetrize(consensus(W, Ob + dO, opts.consensus_steps))
    return from_information(q, O)


def hcmci_step(h, angle_mask, opts: FilterOptions, post: Gaussian, meas: Measurements, F, Q) -> Gaussian:
    """Hybrid consensus on measurements and consensus on information (HCMCI): Battistelli,
    Chisci, Mugnai, Farina & Graziano 2015 (IEEE TAC 60, "Consensus-based linear and nonlinear
    filtering"), their HCMCI algorithm (its EKF form for a nonlinear ``h``).

    Each agent i, with Metropolis weights ``π`` of ``meas.adjacency`` and ``L = opts.consensus_steps``:

    * prediction: ``Ω̄_i = (F P_i Fᵀ + Q)⁻¹``, ``q̄_i = Ω̄_i F x_i``;
    * local measurement information, linearised at the agent's own prediction ``x̄_i``:
      ``δΩ_i = H_iᵀ R_i⁻¹ H_i``, ``δq_i = H_iᵀ R_i⁻¹ (z_i − h_i(x̄_i) + H_i x̄_i)``; zero without a
      measurement;
    * in parallel, L consensus steps on the priors ``(Ω̄, q̄)`` (consensus on information) and L on
      ``(δΩ, δq)`` (consensus on measurements), the same weights;
    * correction: ``Ω_i = Ω̄_i⁽ᴸ⁾ + ω δΩ_i⁽ᴸ⁾``, ``q_i = q̄_i⁽ᴸ⁾ + ω δq_i⁽ᴸ⁾``; ``P_i = Ω_i⁻¹``,
      ``x_i = P_i q_i``.

    ``ω = N``, the number of agents (``meas.adjacency.shape[0]``, dead or cut-off agents included):
    the paper's choice that makes the measurement term the sum of all agents' information once
    consensus has converged, so on a complete graph (Metropolis weights 1/N) with L ≥ 1 the filter
    is the centralised Kalman filter (:func:`mcjax.tracking.filters.consensus.cif_step`). The paper allows
    a per-agent ``ω_i ≥ 1`` (its stability result holds for weights between 1 and N, as far as we
    read it); one constant N is what it recommends. On a graph split into components smaller
    than N, ``N δΩ⁽ᴸ⁾`` counts a component's measurements N/n_c times: over-confident, by
    design of the paper's ω (the ICF's ``contribution="component"`` is the remedy of another paper).
    """
    xb, _, qb, Ob = predict_information(post.x, post.P, F, Q)
    dq, dO, _ = contributions(h, meas.z, meas.sensors, xb, meas.R_inv, angle_mask)
    W = _metropolis(opts, meas.adjacency)
    L = opts.consensus_steps
    omega = meas.adjacency.shape[0]
    q = consensus(W, qb, L) + omega * consensus(W, dq, L)
    O = symmetrize(consensus(W, Ob, L)) + omega * symmetrize(consensus(W, dO, L))
    return from_information(q, O)


# As records (mcjax.contract.filter): both average with Metropolis weights of the links that carried a
# message (doubly stochastic on any undirected graph), fuse by consensus only, and average quantities of
# the current step (a late message cannot join the average).
CI = Filter("ci", "consensus on information: each agent updates with its own measurement, then averages "
            "its information pair with its neighbours'", "Battistelli & Chisci 2014",
            lambda m, post, meas: ci_step(m.h, m.angle_mask, m.options, post, meas, m.F, m.Q),
            Traits(weights="doubly_stochastic", consensus_only=True))
HCMCI = Filter("hcmci", "hybrid consensus on measurements and information: the agents average their new "
               "measurement information and their priors, then combine them", "Battistelli et al. 2015",
               lambda m, post, meas: hcmci_step(m.h, m.angle_mask, m.options, post, meas, m.F, m.Q),
               Traits(weights="doubly_stochastic", consensus_only=True))
