"""Independent plain-numpy peer of the mcjax consensus filters (one Monte-Carlo run).

Written from the equations alone. It imports neither ``jax`` nor ``mcjax``, so it can act as
(a) the independent reference the JAX filters are tested against and (b) the run-by-run
loop peer in the throughput benchmark.

Equation sources:

* Sun et al. 2011: CV target model (eq. 1), range-bearing sensor (§1.3),
  information-form prediction (eq. 8), measurement contributions (eq. 10, with the
  linearised-measurement correction ``i = Hᵀ R⁻¹ (ν + H x̄)``), consensus (eq. 11) and
  estimate recovery (eq. 12) — the "modified ICF" (eqs. 8–12).
* Kamal, Farrell & Roy-Chowdhury 2013: information-weighted consensus filter (ICF),
  averaging contributions / priors and scaling by the number of agents.
* Olfati-Saber 2009, "Kalman-consensus filter: optimality, stability and performance"
  (Chen & Lu 2013 eqs. 6–11): the KCF.
* Xiao & Boyd 2004 (Chen & Lu 2013 eq. 7): Metropolis and max-degree consensus weights.

State ``x = [px, vx, py, vy]``; measurement ``z = [range (m), bearing (rad)]``.
"""

from __future__ import annotations

import numpy as np

FILTER_KINDS = ("cif", "local", "modified_icf", "icf", "kcf")
WEIGHT_KINDS = ("eq11", "metropolis", "max_degree")
CONTRIBUTION_KINDS = ("component", "one")
ICF_VARIANTS = ("contributions", "priors")
KCF_GAINS = ("gamma_M", "mu_P")


# --------------------------------------------------------------------------- models


def cv_matrices(dt: float, sigma_accel: float) -> tuple[np.ndarray, np.ndarray]:
    """Constant-velocity ``F`` and state noise ``Q = G diag(σ², σ²) Gᵀ`` (Sun et al. 2011 eq. 1).

    ``F = [[1,dt,0,0],[0,1,0,0],[0,0,1,dt],[0,0,0,1]]``,
    ``G = [[dt²/2,0],[dt,0],[0,dt²/2],[0,dt]]``.
    """
    F = np.array(
        [[1.0, dt, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, dt], [0.0, 0.0, 0.0, 1.0]]
    )
    G = _cv_G(dt)
    Q = G @ (sigma_accel**2 * np.eye(2)) @ G.T
    return F, Q


def _cv_G(dt: float) -> np.ndarray:
    """Noise gain ``G`` of the CV model (Sun et al. 2011 eq. 1)."""
    return np.array([[0.5 * dt**2, 0.0], [dt, 0.0], [0.0, 0.5 * dt**2], [0.0, dt]])


def wrap_angle(a):
    """Wrap angle(s) into ``(−π, π]``."""
    a = np.asarray(a, dtype=float)
    return np.pi - np.mod(np.pi - a, 2.0 * np.pi)


def range_bearing(x: np.ndarray, s: np.ndarray) -> np.ndarray:
    """``h(x, s) = [√((px−sx)²+(py−sy)²), atan2(py−sy, px−sx)]`` (Sun et al. 2011 §1.3).

    ``x`` is (..., 4), ``s`` is (..., 2); returns (..., 2). Broadcasts over leading axes.
    """
    dx = x[..., 0] - s[..., 0]
    dy = x[..., 2] - s[..., 1]
    return np.stack([np.hypot(dx, dy), np.arctan2(dy, dx)], axis=-1)


def range_bearing_jacobian(x: np.ndarray, s: np.ndarray) -> np.ndarray:
    """Analytic Jacobian of :func:`range_bearing` at ``x`` (Sun et al. 2011 §1.3).

    Row 0 = ``[dx/r, 0, dy/r, 0]``, row 1 = ``[−dy/r², 0, dx/r², 0]``; returns (..., 2, 4).
    """
    dx = x[..., 0] - s[..., 0]
    dy = x[..., 2] - s[..., 1]
    r2 = dx * dx + dy * dy
    r = np.sqrt(r2)
    H = np.zeros(np.broadcast_shapes(dx.shape) + (2, 4))
    H[..., 0, 0] = dx / r
    H[..., 0, 2] = dy / r
    H[..., 1, 0] = -dy / r2
    H[..., 1, 2] = dx / r2
    return H


# --------------------------------------------------------------------------- simulation


def simulate_open_loop_numpy(
    rng: np.random.Generator,
    T: int,
    positions0: np.ndarray,
    headings: np.ndarray,
    speed: float,
    x_target0: np.ndarray,
    dt: float,
    sigma_accel: float,
    sigma_range: float,
    sigma_bearing: float,
    sensing_radius: float,
    comm_radius: float,
):
    """Simulate one open-loop run (Sun et al. 2011 eq. 1 target, §1.3 sensor).

    Target: ``x_0 = x_target0``, ``x_t = F x_{t−1} + G w_t`` with ``w_t ~ N(0, σ_a² I₂)``.
    Sensors: straight lines, ``p_t = p_0 + t·dt·speed·[cos h, sin h]``.
    Measurements: ``h(x_t, p_t) + N(0, diag(σ_r², σ_b²))`` with the bearing wrapped into
    ``(−π, π]``; NaN (both components) where the true range exceeds ``sensing_radius``.
    Adjacency: link iff sensor distance ``<= comm_radius``, zero diagonal.

    Random draws per step ``t``: first ``w_t`` (only for ``t > 0``, shape (2,)), then the
    measurement noise for all agents (shape (n, 2), drawn even for agents out of range).

    Returns ``(measurements (T,n,2), sensor_positions (T,n,2), adjacency (T,n,n), truth (T,4))``.
    """
    positions0 = np.asarray(positions0, dtype=float)
    headings = np.asarray(headings, dtype=float)
    n = positions0.shape[0]
    F, _ = cv_matrices(dt, sigma_accel)
    G = _cv_G(dt)
    direction = np.stack([np.cos(headings), np.sin(headings)], axis=-1)  # (n, 2)
    noise_std = np.array([sigma_range, sigma_bearing])

    truth = np.zeros((T, 4))
    sensors = np.zeros((T, n, 2))
    meas = np.zeros((T, n, 2))
    adjacency = np.zeros((T, n, n))
    x = np.asarray(x_target0, dtype=float).copy()
    for t in range(T):
        if t > 0:
            x = F @ x + G @ (sigma_accel * rng.standard_normal(2))
        truth[t] = x
        s = positions0 + t * dt * speed * direction
        sensors[t] = s
        z_true = range_bearing(x[None, :], s)  # (n, 2)
        z = z_true + noise_std * rng.standard_normal((n, 2))
        z[:, 1] = wrap_angle(z[:, 1])
        z[z_true[:, 0] > sensing_radius] = np.nan
        meas[t] = z
        dist = np.linalg.norm(s[:, None, :] - s[None, :, :], axis=-1)
        a = (dist <= comm_radius).astype(float)
        np.fill_diagonal(a, 0.0)
        adjacency[t] = a
    return meas, sensors, adjacency, truth


# --------------------------------------------------------------------------- graph helpers


def consensus_weights(adjacency: np.ndarray, kind: str = "eq11") -> np.ndarray:
    """Consensus weight matrix ``W`` (n×n) of one step's adjacency ``A``.

    * ``"eq11"`` (Sun et al. 2011 eq. 11): ``W_ij = a_ij/(1+d_i)``, ``W_ii = 1/(1+d_i)``.
    * ``"metropolis"`` (Xiao & Boyd 2004; Chen & Lu 2013 eq. 7):
      ``W_ij = a_ij/(1+max(d_i,d_j))``, ``W_ii = 1 − Σ_{j≠i} W_ij``.
    * ``"max_degree"`` (Xiao & Boyd 2004): ``W_ij = a_ij/n``, ``W_ii = 1 − d_i/n``.
    """
    A = np.asarray(adjacency, dtype=float)
    n = A.shape[0]
    d = A.sum(axis=1)
    if kind == "eq11":
        W = A / (1.0 + d)[:, None]
        W[np.diag_indices(n)] = 1.0 / (1.0 + d)
    elif kind == "metropolis":
        W = A / (1.0 + np.maximum(d[:, None], d[None, :]))
        W[np.diag_indices(n)] = 0.0
        W[np.diag_indices(n)] = 1.0 - W.sum(axis=1)
    elif kind == "max_degree":
        W = A / n
        W[np.diag_indices(n)] = 1.0 - d / n
    else:
        raise ValueError(f"unknown weight kind {kind!r}; expected one of {WEIGHT_KINDS}")
    return W


def component_sizes(adjacency: np.ndarray) -> np.ndarray:
    """Size of each agent's connected component of ``A`` (including the agent), by BFS.

    Used as the contribution weight ``s_i`` of the "component" kind (Kamal et al. 2013:
    the average of contributions times the number of contributing agents is their sum).
    """
    A = np.asarray(adjacency) != 0
    n = A.shape[0]
    label = -np.ones(n, dtype=int)
    sizes = np.zeros(n, dtype=int)
    for start in range(n):
        if label[start] >= 0:
            continue
        members = [start]
        label[start] = start
        frontier = [start]
        while frontier:
            nxt = []
            for i in frontier:
                for j in np.flatnonzero(A[i]):
                    if label[j] < 0:
                        label[j] = start
                        members.append(j)
                        nxt.append(j)
            frontier = nxt
        sizes[members] = len(members)
    return sizes


def contribution_weights(adjacency: np.ndarray, kind: str = "component") -> np.ndarray:
    """Contribution weights ``s_i``: component sizes (``"component"``) or ones (``"one"``)."""
    if kind == "component":
        return component_sizes(adjacency).astype(float)
    if kind == "one":
        return np.ones(np.asarray(adjacency).shape[0])
    raise ValueError(f"unknown contribution kind {kind!r}; expected one of {CONTRIBUTION_KINDS}")


def consensus(W: np.ndarray, vectors: np.ndarray, matrices: np.ndarray, steps: int):
    """``steps`` synchronous consensus iterations ``v_i ← Σ_j W_ij v_j`` (Sun et al. 2011 eq. 11).

    ``vectors`` is (n, 4), ``matrices`` is (n, 4, 4); both updated simultaneously.
    """
    v, M = vectors, matrices
    for _ in range(steps):
        v = W @ v
        M = np.einsum("ij,jkl->ikl", W, M)
    return v, M


# --------------------------------------------------------------------------- filter pieces


def predict_information(x: np.ndarray, P: np.ndarray, F: np.ndarray, Q: np.ndarray):
    """Predict ``x̄ = F x``, ``P̄ = F P Fᵀ + Q``; information ``Ȳ = P̄⁻¹``, ``ȳ = Ȳ x̄``.

    Sun et al. 2011 eq. 8 (written through the moment form). Broadcasts over leading axes.
    Returns ``(x̄, P̄, ȳ, Ȳ)``.
    """
    xbar = x @ F.T
    Pbar = F @ P @ F.T + Q
    Ybar = np.linalg.inv(Pbar)
    ybar = np.einsum("...ij,...j->...i", Ybar, xbar)
    return xbar, Pbar, ybar, Ybar


def measurement_contributions(z: np.ndarray, s: np.ndarray, xbar: np.ndarray, Rinv: np.ndarray):
    """Information contributions linearised at ``x̄`` (Sun et al. 2011 eq. 10, corrected).

    ``ν = z − h(x̄, s)`` with ``ν[1]`` wrapped into ``(−π, π]``; ``i = Hᵀ R⁻¹ (ν + H x̄)``,
    ``I = Hᵀ R⁻¹ H``; zero where the measurement is invalid (any non-finite component).
    ``z``, ``s`` are (n, 2), ``xbar`` is (n, 4) or (4,). Returns ``(i (n,4), I (n,4,4))``.
    """
    n = z.shape[0]
    xbar = np.broadcast_to(xbar, (n, 4))
    valid = np.all(np.isfinite(z), axis=-1)
    i_out = np.zeros((n, 4))
    I_out = np.zeros((n, 4, 4))
    if not valid.any():
        return i_out, I_out
    xv, sv, zv = xbar[valid], s[valid], z[valid]
    H = range_bearing_jacobian(xv, sv)  # (m, 2, 4)
    nu = zv - range_bearing(xv, sv)
    nu[:, 1] = wrap_angle(nu[:, 1])
    HtRinv = np.einsum("mki,kl->mil", H, Rinv)  # Hᵀ R⁻¹, (m, 4, 2)
    pseudo = nu + np.einsum("mki,mi->mk", H, xv)  # ν + H x̄
    i_out[valid] = np.einsum("mil,ml->mi", HtRinv, pseudo)
    I_out[valid] = HtRinv @ H
    return i_out, I_out


def information_to_moment(y: np.ndarray, Y: np.ndarray):
    """``P = Y⁻¹``, ``x = P y`` (Sun et al. 2011 eq. 12). Broadcasts over leading axes."""
    P = np.linalg.inv(Y)
    x = np.einsum("...ij,...j->...i", P, y)
    return x, P


# --------------------------------------------------------------------------- filters


def run_filter_numpy(
    kind: str,
    measurements: np.ndarray,
    sensor_positions: np.ndarray,
    adjacency: np.ndarray,
    x0: np.ndarray,
    P0: np.ndarray,
    F: np.ndarray,
    Q: np.ndarray,
    R: np.ndarray,
    consensus_steps: int = 1,
    weights: str = "eq11",
    contribution: str = "component",
    icf_variant: str = "contributions",
    kcf_gain: str = "gamma_M",
    kcf_epsilon: float = 0.1,
):
    """Run one filter over one run; returns ``(estimates (T,n,4), covariances (T,n,4,4))``.

    Step 0 uses the prior ``(x0, P0)`` without prediction; every later step predicts from the
    previous posterior (Sun et al. 2011 eq. 8). Kinds:

    * ``"cif"``: centralised information filter (Sun et al. 2011 eqs. 8–10, 12), every
      contribution linearised at the central prior; same estimate reported for every agent.
    * ``"local"``: independent per-agent EKFs in information form.
    * ``"modified_icf"``: Sun et al. 2011 eqs. 8–12 — add ``s_i`` times own contribution,
      then ``L`` consensus steps on ``(y, Y)``.
    * ``"icf"``: Kamal et al. 2013 information-weighted consensus. Variant
      ``"contributions"``: consensus on ``(i, I)`` then add ``s_i (ī, Ī)`` to the prior;
      variant ``"priors"``: consensus on ``(ȳ, Ȳ)``, relinearise at the post-consensus
      prior and add ``s_i (i, I)``.
    * ``"kcf"``: Olfati-Saber 2009 Kalman-consensus filter (one exchange per step).
    """
    if kind not in FILTER_KINDS:
        raise ValueError(f"unknown filter kind {kind!r}; expected one of {FILTER_KINDS}")
    z_all = np.asarray(measurements, dtype=float)
    s_all = np.asarray(sensor_positions, dtype=float)
    A_all = np.asarray(adjacency, dtype=float)
    x0 = np.asarray(x0, dtype=float)
    P0 = np.asarray(P0, dtype=float)
    F = np.asarray(F, dtype=float)
    Q = np.asarray(Q, dtype=float)
    Rinv = np.linalg.inv(np.asarray(R, dtype=float))
    T, n = z_all.shape[:2]

    if kind == "cif":
        return _run_cif(z_all, s_all, x0, P0, F, Q, Rinv)
    if kind == "kcf":
        return _run_kcf(z_all, s_all, A_all, x0, P0, F, Q, Rinv, kcf_gain, kcf_epsilon)

    estimates = np.zeros((T, n, 4))
    covariances = np.zeros((T, n, 4, 4))
    x = np.broadcast_to(x0, (n, 4)).copy()
    P = np.broadcast_to(P0, (n, 4, 4)).copy()
    for t in range(T):
        if t == 0:
            xbar, Pbar = x, P
            Ybar = np.linalg.inv(Pbar)
            ybar = np.einsum("nij,nj->ni", Ybar, xbar)
        else:
            xbar, Pbar, ybar, Ybar = predict_information(x, P, F, Q)
        z, s, A = z_all[t], s_all[t], A_all[t]

        if kind == "local":
            i_c, I_c = measurement_contributions(z, s, xbar, Rinv)
            y, Y = ybar + i_c, Ybar + I_c
        else:
            W = consensus_weights(A, weights)
            sw = contribution_weights(A, contribution)
            if kind == "modified_icf":
                i_c, I_c = measurement_contributions(z, s, xbar, Rinv)
                y = ybar + sw[:, None] * i_c
                Y = Ybar + sw[:, None, None] * I_c
                y, Y = consensus(W, y, Y, consensus_steps)
            elif icf_variant == "contributions":
                i_c, I_c = measurement_contributions(z, s, xbar, Rinv)
                i_c, I_c = consensus(W, i_c, I_c, consensus_steps)
                y = ybar + sw[:, None] * i_c
                Y = Ybar + sw[:, None, None] * I_c
            elif icf_variant == "priors":
                ybar, Ybar = consensus(W, ybar, Ybar, consensus_steps)
                xbar_c = np.linalg.solve(Ybar, ybar[..., None])[..., 0]
                i_c, I_c = measurement_contributions(z, s, xbar_c, Rinv)
                y = ybar + sw[:, None] * i_c
                Y = Ybar + sw[:, None, None] * I_c
            else:
                raise ValueError(f"unknown icf variant {icf_variant!r}; expected {ICF_VARIANTS}")
        x, P = information_to_moment(y, Y)
        estimates[t], covariances[t] = x, P
    return estimates, covariances


def _run_cif(z_all, s_all, x0, P0, F, Q, Rinv):
    """Centralised information filter (Sun et al. 2011 eqs. 8–10, 12): ``Y = Ȳ + Σ_j I_j``,
    ``y = ȳ + Σ_j i_j`` with every contribution linearised at the single central prior."""
    T, n = z_all.shape[:2]
    estimates = np.zeros((T, n, 4))
    covariances = np.zeros((T, n, 4, 4))
    x, P = x0.copy(), P0.copy()
    for t in range(T):
        if t == 0:
            xbar = x
            Ybar = np.linalg.inv(P)
            ybar = Ybar @ xbar
        else:
            xbar, _, ybar, Ybar = predict_information(x, P, F, Q)
        i_c, I_c = measurement_contributions(z_all[t], s_all[t], xbar, Rinv)
        x, P = information_to_moment(ybar + i_c.sum(axis=0), Ybar + I_c.sum(axis=0))
        estimates[t] = x
        covariances[t] = P
    return estimates, covariances


def _run_kcf(z_all, s_all, A_all, x0, P0, F, Q, Rinv, gain, epsilon):
    """Kalman-consensus filter, Olfati-Saber 2009 (Chen & Lu 2013 eqs. 6–11).

    ``(u_j, U_j)`` = contribution of ``j`` at its own prior ``x̄_j``;
    ``S_i = Σ_{j∈N_i∪{i}} U_j``, ``y_i = Σ_{j∈N_i∪{i}} u_j``; ``M_i = (P̄_i⁻¹ + S_i)⁻¹``;
    ``x̂_i = x̄_i + M_i (y_i − S_i x̄_i) + G_i Σ_{j∈N_i} (x̄_j − x̄_i)`` with
    ``G_i = γ M_i``, ``γ = ε/(1+‖M_i‖_F)`` (``"gamma_M"``) or ``G_i = μ P̄_i``,
    ``μ = ε/(1+‖P̄_i‖_F)`` (``"mu_P"``); posterior covariance ``M_i``.
    """
    if gain not in KCF_GAINS:
        raise ValueError(f"unknown kcf gain {gain!r}; expected one of {KCF_GAINS}")
    T, n = z_all.shape[:2]
    estimates = np.zeros((T, n, 4))
    covariances = np.zeros((T, n, 4, 4))
    x = np.broadcast_to(x0, (n, 4)).copy()
    P = np.broadcast_to(P0, (n, 4, 4)).copy()
    for t in range(T):
        if t == 0:
            xbar, Pbar = x, P
        else:
            xbar = x @ F.T
            Pbar = F @ P @ F.T + Q
        A = A_all[t]
        u, U = measurement_contributions(z_all[t], s_all[t], xbar, Rinv)
        Aself = A + np.eye(n)  # N_i ∪ {i}
        y = Aself @ u
        S = np.einsum("ij,jkl->ikl", Aself, U)
        M = np.linalg.inv(np.linalg.inv(Pbar) + S)
        disagreement = A @ xbar - A.sum(axis=1)[:, None] * xbar  # Σ_{j∈N_i} (x̄_j − x̄_i)
        if gain == "gamma_M":
            coef = epsilon / (1.0 + np.linalg.norm(M, axis=(1, 2)))
            Gi = coef[:, None, None] * M
        else:
            coef = epsilon / (1.0 + np.linalg.norm(Pbar, axis=(1, 2)))
            Gi = coef[:, None, None] * Pbar
        innov = y - np.einsum("nij,nj->ni", S, xbar)
        x = (
            xbar
            + np.einsum("nij,nj->ni", M, innov)
            + np.einsum("nij,nj->ni", Gi, disagreement)
        )
        P = M
        estimates[t], covariances[t] = x, P
    return estimates, covariances
