"""Distributed information filters: CIF, ICF, modified ICF, KCF and the local EKF.

One call of :func:`filter_step` advances every agent of one run by one step (docs/equations.md
§2 timing: the caller passes ``F = I, Q = 0`` at the first measurement time, so step 0
updates without predicting). Agents sit on the leading axis; nothing loops over agents.

Choices where the papers are silent or ambiguous (documented in docs/papers.md, "Filters"):

* ``contribution="component"`` (default) weights an agent's own measurement information by
  ``n_i``, the number of agents in its connected component, before it is averaged by
  consensus (the information-weighting of Kamal, Farrell & Roy-Chowdhury 2013). Averaging
  consensus divides information by the number of agents it is spread over; the weight
  restores the sum, so on a complete graph ICF and modified ICF reproduce the centralised
  filter exactly, and on an empty graph (``n_i = 1``) they are the local filters.
  ``contribution="one"`` is Sun et al. 2011 eq. 9 as printed.
* ``icf_variant="contributions"`` (default) reads the ICF of Sun et al. 2011's refs [4]–[5]
  (Casbeer & Beard 2009) as consensus on the new measurement information before it is
  added to each agent's own prediction; ``"priors"`` is the reading of docs/equations.md
  (consensus on the predicted pairs, then add the local contribution). Only the first
  converges to the centralised filter on a complete graph.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import jax
import jax.numpy as jnp

from mcjax.contract.filter import Filter, Model, Traits
from mcjax.tracking import graph
from mcjax.tracking.filters import exchange
from mcjax.tracking.filters.gaussian import (
    Gaussian,
    contributions,
    from_information,
    predict_information,
    predict_moments,
)
from mcjax.tracking.numerics import matvec, spd_inverse, symmetrize, weighted_agent_sum

CONTRIBUTION_KINDS = ("component", "one")
ICF_VARIANTS = ("contributions", "priors")
KCF_GAINS = ("gamma_M", "mu_P", "prior_consensus")
WEIGHT_KINDS = ("eq11", "metropolis", "max_degree")


@dataclass(frozen=True)
class FilterOptions:
    """Static choices of the distributed filters (changing one recompiles).

    ``consensus_steps`` is L, the consensus iterations per comm interval (Sun et al. 2011 uses
    one message per interval: L = 1). ``weights`` picks the consensus matrix: ``"eq11"``
    (Sun et al. 2011 eq. 11), ``"metropolis"`` or ``"max_degree"`` (Chen & Lu 2013 eq. 7).
    ``exchange`` is how neighbours' messages are summed: ``"dense"``, over every agent with (n, n)
    matrices; ``"sparse"``, over neighbour lists of ``max_neighbours`` slots
    (:mod:`mcjax.tracking.filters.exchange`: cost with the links, the same numbers to round-off, NaN for
    an agent with more links than slots).
    """

    consensus_steps: int = 1
    weights: str = "eq11"
    contribution: str = "component"
    icf_variant: str = "contributions"
    kcf_gain: str = "gamma_M"
    exchange: str = "dense"
    max_neighbours: int = 16

    def __post_init__(self):
        _check_choice("weights", self.weights, WEIGHT_KINDS)
        _check_choice("contribution", self.contribution, CONTRIBUTION_KINDS)
        _check_choice("icf_variant", self.icf_variant, ICF_VARIANTS)
        _check_choice("kcf_gain", self.kcf_gain, KCF_GAINS)
        _check_choice("exchange", self.exchange, exchange.EXCHANGES)
        if not isinstance(self.max_neighbours, int) or self.max_neighbours < 1:
            raise ValueError(f"max_neighbours must be an integer >= 1, got {self.max_neighbours!r}")
        if not isinstance(self.consensus_steps, int) or self.consensus_steps < 0:
            raise ValueError(f"consensus_steps must be an integer >= 0, got {self.consensus_steps!r}")


def _check_choice(name, value, allowed):
    if value not in allowed:
        raise ValueError(f"{name} must be one of {', '.join(map(repr, allowed))}; got {value!r}")


class Late(NamedTuple):
    """Consensus messages that arrive late: ``means`` (n, d), the predicted estimates x̄ every
    agent sent ``k`` steps ago (its own included, as it kept it), and ``adjacency`` (n, n), the
    links that carried them."""

    means: jax.Array
    adjacency: jax.Array


class Measurements(NamedTuple):
    """What the filters see at one step: ``z`` (n, m) with NaN where an agent has none,
    ``sensors`` (n, 2) positions, ``adjacency`` (n, n), ``R_inv`` (n, m, m), and optionally
    ``component_sizes`` (n,): the weights ``n_i`` of ``contribution="component"`` when the
    caller has them (a smooth surrogate for training); None: from the adjacency; ``late``:
    the KCF's consensus messages when they arrive late (:class:`Late`; None: this step's)."""

    z: jax.Array
    sensors: jax.Array
    adjacency: jax.Array
    R_inv: jax.Array
    component_sizes: jax.Array | None = None
    late: Late | None = None


def consensus(W: jax.Array, values: jax.Array, steps: int) -> jax.Array:
    """``steps`` synchronous consensus iterations ``v_i ← Σ_j W_ij v_j``.

    With ``W`` from :func:`mcjax.tracking.graph.laplacian_step_weights` one iteration is Sun et al. 2011
    eq. 11, ``v_i ← v_i − (1/(1+d_i)) Σ_j a_ij (v_i − v_j)``. ``values`` is (n, ...). ``W`` is an
    (n, n) matrix (the dense exchange) or :class:`mcjax.tracking.filters.exchange.SparseWeights`.
    """
    mix = exchange.mix if isinstance(W, exchange.SparseWeights) else weighted_agent_sum

    def body(_, v):
        return mix(W, v)

    if steps == 0:
        return values
    return jax.lax.fori_loop(0, steps, body, values)


def _lists(opts: FilterOptions, adjacency):
    return exchange.neighbour_lists(adjacency, opts.max_neighbours)


def consensus_matrix(opts: FilterOptions, adjacency, kind=None):
    """The consensus matrix of ``kind`` (default ``opts.weights``), dense or sparse as ``opts.exchange``."""
    kind = opts.weights if kind is None else kind
    if opts.exchange == "sparse":
        return exchange.sparse_weights(_lists(opts, adjacency), kind, adjacency.shape[0])
    return graph.consensus_weights(adjacency, kind)


def _scale(opts: FilterOptions, meas: Measurements):
    adjacency = meas.adjacency
    if opts.contribution == "one":
        return jnp.ones(adjacency.shape[0], adjacency.dtype)
    if meas.component_sizes is not None:
        return meas.component_sizes
    if opts.exchange == "sparse":
        return exchange.component_sizes(_lists(opts, adjacency))
    return graph.component_sizes(adjacency)


def _adjacent_sum(opts: FilterOptions, A, values):
    """``Σ_{j ∈ N_i} a_ij v_j``, dense or sparse as ``opts.exchange``."""
    if opts.exchange == "sparse":
        lists = _lists(opts, A)
        return exchange.neighbour_sum(lists, lists.weight, values)
    return weighted_agent_sum(A, values)


def cif_step(h, angle_mask, post: Gaussian, meas: Measurements, F, Q) -> Gaussian:
    """Centralised information filter: one filter adds every agent's contribution.

    Sun et al. 2011 §2.2 (CIF, the bound of Table 1): ``Y = Ȳ + Σ_i I_i``, ``y = ȳ + Σ_i i_i``, all
    linearised at the one central prior. ``post`` holds a single (unbatched) Gaussian.
    """
    xb, _, yb, Yb = predict_information(post.x, post.P, F, Q)
    i, I, _ = contributions(h, meas.z, meas.sensors, xb, meas.R_inv, angle_mask)
    ones = jnp.ones((1, i.shape[0]), i.dtype)
    return from_information(yb + weighted_agent_sum(ones, i)[0], Yb + weighted_agent_sum(ones, I)[0])


def local_step(h, angle_mask, post: Gaussian, meas: Measurements, F, Q) -> Gaussian:
    """Standalone EKF per agent in information form (no communication): the baseline."""
    xb, _, yb, Yb = predict_information(post.x, post.P, F, Q)
    i, I, _ = contributions(h, meas.z, meas.sensors, xb, meas.R_inv, angle_mask)
    return from_information(yb + i, Yb + I)


def modified_icf_step(h, angle_mask, opts, post: Gaussian, meas: Measurements, F, Q) -> Gaussian:
    """Modified ICF of Sun et al. 2011 (§2.2, eqs. 8–12): predict (eq. 8), add the
    local contribution (eqs. 9–10, weighted by ``n_i`` unless ``contribution="one"``), then
    L consensus steps on the information pairs (eq. 11), and recover the estimate (eq. 12)."""
    xb, _, yb, Yb = predict_information(post.x, post.P, F, Q)
    i, I, _ = contributions(h, meas.z, meas.sensors, xb, meas.R_inv, angle_mask)
    s = _scale(opts, meas)
    W = consensus_matrix(opts, meas.adjacency)
    y = consensus(W, yb + s[:, None] * i, opts.consensus_steps)
    Y = consensus(W, Yb + s[:, None, None] * I, opts.consensus_steps)
    return from_information(y, Y)


def icf_step(h, angle_mask, opts, post: Gaussian, meas: Measurements, F, Q) -> Gaussian:
    """ICF of Sun et al. 2011's refs [4]–[5] (Casbeer & Beard 2009): consensus before the update.

    ``icf_variant="contributions"``: each agent predicts (eq. 8) and computes its
    contribution (eq. 10); L consensus steps average the contributions; the agent adds
    ``n_i`` times the average to its own prediction. ``"priors"``: L consensus steps on the
    predicted pairs, then each agent adds its own contribution at its post-consensus prior.
    """
    xb, _, yb, Yb = predict_information(post.x, post.P, F, Q)
    s = _scale(opts, meas)
    W = consensus_matrix(opts, meas.adjacency)
    if opts.icf_variant == "contributions":
        i, I, _ = contributions(h, meas.z, meas.sensors, xb, meas.R_inv, angle_mask)
        i = consensus(W, i, opts.consensus_steps)
        I = consensus(W, I, opts.consensus_steps)
    else:
        yb = consensus(W, yb, opts.consensus_steps)
        Yb = symmetrize(consensus(W, Yb, opts.consensus_steps))
        xb = matvec(spd_inverse(Yb), yb)
        i, I, _ = contributions(h, meas.z, meas.sensors, xb, meas.R_inv, angle_mask)
    return from_information(yb + s[:, None] * i, Yb + s[:, None, None] * I)


class _Neighbourhood(NamedTuple):
    xb: jax.Array   # predicted means (n, d)
    Pb: jax.Array   # predicted covariances (n, d, d)
    A: jax.Array    # adjacency (n, n)
    S: jax.Array    # Σ_{J_i} U_j, the neighbourhood's measurement information (n, d, d)
    yv: jax.Array   # Σ_{J_i} u_j (n, d)
    Yb: jax.Array   # predicted information P̄⁻¹ (n, d, d)
    Y: jax.Array    # P̄⁻¹ + S (n, d, d)
    M: jax.Array    # (P̄⁻¹ + S)⁻¹, the posterior covariance (n, d, d)


def _neighbourhood_update(h, angle_mask, opts, post: Gaussian, meas: Measurements, F, Q) -> _Neighbourhood:
    """The part the two consensus Kalman filters share: predict, then pool each agent's and its
    neighbours' measurement information, ``S_i = Σ_{J_i} U_j``, ``y_i = Σ_{J_i} u_j`` and
    ``M_i = (P̄_i⁻¹ + S_i)⁻¹`` (Olfati-Saber 2009's KCF; Chen & Lu 2013, eq. 8)."""
    xb, Pb = predict_moments(post.x, post.P, F, Q)
    u, U, _ = contributions(h, meas.z, meas.sensors, xb, meas.R_inv, angle_mask)
    A = meas.adjacency
    if opts.exchange == "sparse":
        lists = _lists(opts, A)
        S, yv = exchange.inclusive_sum(lists, U), exchange.inclusive_sum(lists, u)
    else:
        inclusive = A + jnp.eye(A.shape[0], dtype=A.dtype)
        S = weighted_agent_sum(inclusive, U)
        yv = weighted_agent_sum(inclusive, u)
    Yb = spd_inverse(Pb)
    Y = symmetrize(Yb + S)
    M = symmetrize(spd_inverse(Y))
    return _Neighbourhood(xb, Pb, A, S, yv, Yb, Y, M)


def kcf_step(h, angle_mask, opts, epsilon, post: Gaussian, meas: Measurements, F, Q) -> Gaussian:
    """Kalman-consensus filter (Olfati-Saber 2009; Lou et al. 2013 Alg. 1).

    ``S_i = Σ_{J_i} U_j``, ``y_i = Σ_{J_i} u_j``, ``M_i = (P̄_i⁻¹ + S_i)⁻¹``,
    ``x̂_i = x̄_i + M_i (y_i − S_i x̄_i) + G_i Σ_{N_i} (x̄_j − x̄_i)`` with
    ``G_i = γ M_i, γ = ε/(1+‖M_i‖_F)`` (``kcf_gain="gamma_M"``, Olfati-Saber 2009) or
    ``G_i = μ P̄_i, μ = ε/(1+‖P̄_i‖_F)`` (``"mu_P"``, Lou et al. 2013). One exchange per step.

    With ``meas.late`` (messages k steps late, ours): the consensus term is the disagreement of
    k steps ago, ``Σ_{N_i} (x̄_j − x̄_i)`` over the predictions sent then and the links that
    carried them (Olfati-Saber & Murray 2004's consensus with a uniform delay; k = 0 is the
    term above), and the neighbours' measurement information, k steps old, is not fused (it
    measured the target at another time): ``S_i = U_i``, ``y_i = u_i``.
    """
    if meas.late is not None:
        own = meas._replace(adjacency=jnp.zeros_like(meas.adjacency))
        xb, Pb, A, S, yv, Yb, Y, M = _neighbourhood_update(h, angle_mask, opts, post, own, F, Q)
        A, sent = meas.late.adjacency, meas.late.means
        disagreement = _adjacent_sum(opts, A, sent) - jnp.sum(A, axis=1)[:, None] * sent
    else:
        xb, Pb, A, S, yv, Yb, Y, M = _neighbourhood_update(h, angle_mask, opts, post, meas, F, Q)
        disagreement = _adjacent_sum(opts, A, xb) - jnp.sum(A, axis=1)[:, None] * xb
    base = M if opts.kcf_gain == "gamma_M" else Pb
    fro = jnp.sqrt(sum(base[:, i, j] ** 2 for i in range(base.shape[-2]) for j in range(base.shape[-1])))
    gain = (epsilon / (1.0 + fro))[:, None, None] * base
    # x̄ + M(y − S x̄) computed as M(Ȳ x̄ + y) (equal, since M⁻¹ = Ȳ + S): inside the scenario's
    # scan XLA compiles the first form ~4x slower (22.9 vs 5.8 ms per run, measured 2026-11-23)
    x = matvec(M, matvec(Yb, xb) + yv) + matvec(gain, disagreement)
    return Gaussian(x, M, Y)


def prior_consensus_kcf_step(h, angle_mask, opts, post: Gaussian, meas: Measurements, F, Q,
                             formation=None) -> Gaussian:
    """The consensus Kalman filter of Chen & Lu 2013, eqs. 6–12 (not Olfati-Saber's γM form).

    The priors are averaged first with the consensus weights ``W`` (``opts.weights``; the
    paper's max-degree weights of eq. 7), then updated with the measurement information of
    the agent and its neighbours (``S_i = Σ_{J_i} Hᵀ R⁻¹ H``, ``y_i = Σ_{J_i} Hᵀ R⁻¹ z``):

        M_i = (P̄_i⁻¹ + S_i)⁻¹                                             (eq. 8)
        x̂_i = x̄ᶜ_i + M_i (y_i − S_i x̄ᶜ_i),   x̄ᶜ_i = Σ_j W_ij x̄_j           (eqs. 6, 9, first line)
            = x̄_i + M_i (y_i − S_i x̄_i) + (I − M_i S_i) Σ_j W_ij (x̄_j − x̄_i)   (eq. 9, second line)

    computed in the second form, to which eq. 12 adds the formation term inside the sum:
    ``Σ_j W_ij (x̄_j − x̄_i + formation_ij)`` with ``formation_ij = η (X_j − X_i − d_ij)``
    (``formation`` (n, n, d) or None for eq. 9). The posterior covariance is ``M_i``; the
    next prediction gives eq. 11, ``A M Aᵀ + B Q Bᵀ``. One consensus exchange per step.
    """
    xb, Pb, A, S, yv, Yb, Y, M = _neighbourhood_update(h, angle_mask, opts, post, meas, F, Q)
    W = consensus_matrix(opts, A)
    if isinstance(W, exchange.SparseWeights):  # Σ_k W_ik (x̄_j − x̄_i + formation_ij), j = index_ik
        pull = exchange.neighbour_sum(W.lists, W.link, xb) - exchange.neighbour_sum(
            W.lists, W.link, jnp.ones_like(xb[:, :1])) * xb
        if formation is not None:
            rows = jnp.take_along_axis(formation, W.lists.index[:, :, None], axis=1)  # formation_ij (n, K, d)
            pull = pull + jnp.sum(W.link[:, :, None] * rows, axis=1)
    else:
        offsets = xb[None, :, :] - xb[:, None, :]                     # x̄_j − x̄_i at [i, j]
        if formation is not None:
            offsets = offsets + formation
        off_diag = W * (1.0 - jnp.eye(W.shape[0], dtype=W.dtype))
        pull = jnp.sum(off_diag[..., None] * offsets, axis=1)         # Σ_{j≠i} W_ij (…)
    d = xb.shape[-1]
    gain = jnp.eye(d, dtype=M.dtype) - jnp.einsum("nab,nbc->nac", M, S)
    x = xb + matvec(M, yv - matvec(S, xb)) + matvec(gain, pull)
    return Gaussian(x, M, Y)


def _kcf(model: Model, post: Gaussian, meas: Measurements) -> Gaussian:
    """The KCF with its gain (``options.kcf_gain``): Olfati-Saber's γM or μP form (:func:`kcf_step`), or Chen
    & Lu 2013's prior consensus (:func:`prior_consensus_kcf_step`, with the formation term where given)."""
    if model.options.kcf_gain == "prior_consensus":
        return prior_consensus_kcf_step(model.h, model.angle_mask, model.options, post, meas, model.F, model.Q,
                                        model.formation)
    return kcf_step(model.h, model.angle_mask, model.options, model.epsilon, post, meas, model.F, model.Q)


# The filters of this module as records (mcjax.contract.filter). Late messages: the KCF's consensus term is
# a correction toward the neighbours' estimates, and a disagreement of k steps ago is the delayed consensus
# of Olfati-Saber & Murray 2004; the information filters (ICF, modified ICF) average quantities of the
# current step — a k-step-old pair describes another time and breaks the average (and its convergence to
# the centralised filter); the CIF and the local EKF send no consensus message.
CIF = Filter("cif", "centralised information filter: one filter fuses every agent's measurements",
             "Sun et al. 2011, sec. 2.2 (the bound of Table 1)",
             lambda m, post, meas: cif_step(m.h, m.angle_mask, post, meas, m.F, m.Q),
             Traits(centralised=True, late_messages=True, messages=False))
ICF = Filter("icf", "information consensus filter: consensus on the new measurement information",
             "Casbeer & Beard 2009 (Sun et al. 2011, refs. 4-5)",
             lambda m, post, meas: icf_step(m.h, m.angle_mask, m.options, post, meas, m.F, m.Q))
MODIFIED_ICF = Filter("modified_icf", "modified information consensus filter: consensus on the updated "
                      "information pairs", "Sun et al. 2011, eqs. 8-12",
                      lambda m, post, meas: modified_icf_step(m.h, m.angle_mask, m.options, post, meas, m.F, m.Q))
KCF = Filter("kcf", "Kalman-consensus filter: a local update with the neighbours' measurements, then a "
             "consensus correction toward their estimates",
             "Olfati-Saber 2009 (gains gamma_M, mu_P); Chen & Lu 2013, eqs. 6-12 (prior_consensus)",
             _kcf, Traits(late_messages=True))
LOCAL = Filter("local", "local extended Kalman filter: each agent on its own measurements, nothing shared",
               "the baseline of Sun et al. 2011",
               lambda m, post, meas: local_step(m.h, m.angle_mask, post, meas, m.F, m.Q),
               Traits(late_messages=True, messages=False))
