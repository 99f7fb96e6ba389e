"""numba peer of two mcjax filters: the local EKF and the modified ICF, batched over runs.

Written from docs/equations.md §5.1–5.2 (the same equations as ``numpy_peer.py``, in the
information form of Sun et al. 2011 eqs. 8–12), as a performance-minded researcher would:
one ``@njit(parallel=True, cache=True)`` kernel with ``prange`` over the runs, scalar loops over the
4×4 matrices, scratch arrays allocated once per run, results written straight into
``(B, T, n, 4)`` / ``(B, T, n, 4, 4)`` arrays. It imports neither ``jax`` nor ``mcjax``.

Per agent-step (docs/filter_speed.md counts the flops):

* predict ``x̄ = F x``, ``P̄ = F P Fᵀ + Q`` (upper triangle, then mirrored), ``Ȳ = P̄⁻¹``
  by a Cholesky factor (``L⁻¹`` then ``L⁻ᵀ L⁻¹``), ``ȳ = Ȳ x̄`` (step 0: no prediction);
* contribution linearised at ``x̄``: ``H`` analytic (range row ``[dx/r, 0, dy/r, 0]``,
  bearing row ``[−dy/r², 0, dx/r², 0]``), ``ν = z − h(x̄)`` with the bearing wrapped into
  (−π, π], ``i = Hᵀ R⁻¹ (ν + H x̄)``, ``I = Hᵀ R⁻¹ H``; ``(0, 0)`` when a component of z is
  not finite;
* local: ``Y = Ȳ + I``, ``y = ȳ + i``; modified ICF: ``Y_i = Ȳ_i + n_i I_i`` (``n_i`` the
  size of agent i's connected component, or 1 with ``contribution="one"``), then L
  iterations ``(y_i, Y_i) ← Σ_j W_ij (y_j, Y_j)`` with the eq. 11 / Metropolis / max-degree
  weights;
* recover ``P = Y⁻¹`` (Cholesky again), ``x = P y``.

numba is a benchmark-only dependency (``pip install -e .[bench]``).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

WEIGHT_CODES = {"eq11": 0, "metropolis": 1, "max_degree": 2}


@njit(inline="always")
def _spd_inverse(A, L, M, out):
    """``out = A⁻¹`` for SPD 4×4 ``A``: ``A = L Lᵀ``, ``M = L⁻¹``, ``A⁻¹ = Mᵀ M`` (NaN if not PD)."""
    for j in range(4):
        s = A[j, j]
        for k in range(j):
            s -= L[j, k] * L[j, k]
        d = math.sqrt(s) if s >= 0.0 else math.nan
        L[j, j] = d
        for i in range(j + 1, 4):
            s = A[i, j]
            for k in range(j):
                s -= L[i, k] * L[j, k]
            L[i, j] = s / d
    for j in range(4):
        M[j, j] = 1.0 / L[j, j]
        for i in range(j + 1, 4):
            s = L[i, j] * M[j, j]
            for k in range(j + 1, i):
                s += L[i, k] * M[k, j]
            M[i, j] = -s / L[i, i]
    for i in range(4):
        for j in range(i, 4):
            s = 0.0
            for k in range(j, 4):
                s += M[k, i] * M[k, j]
            out[i, j] = s
            out[j, i] = s


@njit(inline="always")
def _predict(x, P, F, Q, xb, Pb, FP):
    """``x̄ = F x``, ``P̄ = F P Fᵀ + Q`` (upper triangle computed, lower mirrored)."""
    for i in range(4):
        s = 0.0
        for k in range(4):
            s += F[i, k] * x[k]
        xb[i] = s
    for i in range(4):
        for j in range(4):
            s = 0.0
            for k in range(4):
                s += F[i, k] * P[k, j]
            FP[i, j] = s
    for i in range(4):
        for j in range(i, 4):
            s = Q[i, j]
            for k in range(4):
                s += FP[i, k] * F[j, k]
            Pb[i, j] = s
            Pb[j, i] = s


@njit(inline="always")
def _contribution(z0, z1, sx, sy, xb, Rinv, i_out, I_out):
    """Range–bearing information contribution at ``x̄``; returns False (and zeros) when invalid."""
    if not (math.isfinite(z0) and math.isfinite(z1)):
        for a in range(4):
            i_out[a] = 0.0
            for b in range(4):
                I_out[a, b] = 0.0
        return False
    dx = xb[0] - sx
    dy = xb[2] - sy
    r2 = dx * dx + dy * dy
    r = math.sqrt(r2)
    nu0 = z0 - r
    nu1 = z1 - math.atan2(dy, dx)
    if not (-math.pi < nu1 <= math.pi):
        nu1 = math.pi - ((math.pi - nu1) % (2.0 * math.pi))
    # H has non-zero columns 0 and 2 only: H = [[h00, 0, h02, 0], [h10, 0, h12, 0]]
    h00 = dx / r
    h02 = dy / r
    h10 = -dy / r2
    h12 = dx / r2
    p0 = nu0 + h00 * xb[0] + h02 * xb[2]  # ν + H x̄
    p1 = nu1 + h10 * xb[0] + h12 * xb[2]
    # G = Hᵀ R⁻¹: rows 0 and 2 non-zero
    g00 = h00 * Rinv[0, 0] + h10 * Rinv[1, 0]
    g01 = h00 * Rinv[0, 1] + h10 * Rinv[1, 1]
    g20 = h02 * Rinv[0, 0] + h12 * Rinv[1, 0]
    g21 = h02 * Rinv[0, 1] + h12 * Rinv[1, 1]
    for a in range(4):
        i_out[a] = 0.0
        for b in range(4):
            I_out[a, b] = 0.0
    i_out[0] = g00 * p0 + g01 * p1
    i_out[2] = g20 * p0 + g21 * p1
    I_out[0, 0] = g00 * h00 + g01 * h10
    I_out[0, 2] = g00 * h02 + g01 * h12
    I_out[2, 0] = I_out[0, 2]
    I_out[2, 2] = g20 * h02 + g21 * h12
    return True


@njit(parallel=True, cache=True)
def local_kernel(z, s, x0, P0, F, Q, Rinv, xs, Ps):
    """Local EKF in information form for every run ``b`` and agent; writes ``xs``, ``Ps``."""
    B, T, n = z.shape[0], z.shape[1], z.shape[2]
    for b in prange(B):
        x = np.empty(4)
        P = np.empty((4, 4))
        xb = np.empty(4)
        Pb = np.empty((4, 4))
        Yb = np.empty((4, 4))
        FP = np.empty((4, 4))
        L = np.zeros((4, 4))
        M = np.zeros((4, 4))
        ic = np.empty(4)
        Ic = np.empty((4, 4))
        y = np.empty(4)
        Y = np.empty((4, 4))
        for a in range(n):
            for k in range(4):
                x[k] = x0[k]
                for m in range(4):
                    P[k, m] = P0[k, m]
            for t in range(T):
                if t == 0:
                    for k in range(4):
                        xb[k] = x[k]
                        for m in range(4):
                            Pb[k, m] = P[k, m]
                else:
                    _predict(x, P, F, Q, xb, Pb, FP)
                _spd_inverse(Pb, L, M, Yb)
                _contribution(z[b, t, a, 0], z[b, t, a, 1], s[b, t, a, 0], s[b, t, a, 1], xb, Rinv, ic, Ic)
                for k in range(4):
                    acc = ic[k]
                    for m in range(4):
                        acc += Yb[k, m] * xb[m]
                    y[k] = acc
                    for m in range(4):
                        Y[k, m] = Yb[k, m] + Ic[k, m]
                _spd_inverse(Y, L, M, P)
                for k in range(4):
                    acc = 0.0
                    for m in range(4):
                        acc += P[k, m] * y[m]
                    x[k] = acc
                    xs[b, t, a, k] = acc
                    for m in range(4):
                        Ps[b, t, a, k, m] = P[k, m]


@njit(inline="always")
def _component_sizes(A, label, stack, sizes):
    """Connected-component sizes of the 0/1 graph ``A`` (n×n) by depth-first search."""
    n = A.shape[0]
    for i in range(n):
        label[i] = -1
    for start in range(n):
        if label[start] >= 0:
            continue
        label[start] = start
        top = 0
        stack[0] = start
        count = 1
        while top >= 0:
            i = stack[top]
            top -= 1
            for j in range(n):
                if A[i, j] != 0.0 and label[j] < 0:
                    label[j] = start
                    top += 1
                    stack[top] = j
                    count += 1
        for i in range(n):
            if label[i] == start:
                sizes[i] = count


@njit(inline="always")
def _weights(A, kind, W):
    """Consensus weights of docs/equations.md §3: 0 eq. 11, 1 Metropolis, 2 max-degree."""
    n = A.shape[0]
    for i in range(n):
        d_i = 0.0
        for j in range(n):
            d_i += A[i, j]
        if kind == 0:
            for j in range(n):
                W[i, j] = A[i, j] / (1.0 + d_i)
            W[i, i] = 1.0 / (1.0 + d_i)
        elif kind == 1:
            off = 0.0
            for j in range(n):
                if j == i:
                    continue
                d_j = 0.0
                for k in range(n):
                    d_j += A[j, k]
                W[i, j] = A[i, j] / (1.0 + max(d_i, d_j))
                off += W[i, j]
            W[i, i] = 1.0 - off
        else:
            for j in range(n):
                W[i, j] = A[i, j] / n
            W[i, i] = 1.0 - d_i / n


@njit(parallel=True, cache=True)
def modified_icf_kernel(z, s, adj, x0, P0, F, Q, Rinv, steps, weight_kind, component, xs, Ps):
    """Modified ICF (Sun et al. 2011 eqs. 8–12) for every run ``b``; writes ``xs``, ``Ps``."""
    B, T, n = z.shape[0], z.shape[1], z.shape[2]
    for b in prange(B):
        x = np.empty((n, 4))
        P = np.empty((n, 4, 4))
        xb = np.empty(4)
        Pb = np.empty((4, 4))
        Yb = np.empty((4, 4))
        FP = np.empty((4, 4))
        L = np.zeros((4, 4))
        M = np.zeros((4, 4))
        ic = np.empty(4)
        Ic = np.empty((4, 4))
        y = np.empty((n, 4))
        Y = np.empty((n, 4, 4))
        y2 = np.empty((n, 4))
        Y2 = np.empty((n, 4, 4))
        W = np.empty((n, n))
        label = np.empty(n, np.int64)
        stack = np.empty(n, np.int64)
        sizes = np.ones(n, np.int64)
        Pi = np.empty((4, 4))
        for a in range(n):
            for k in range(4):
                x[a, k] = x0[k]
                for m in range(4):
                    P[a, k, m] = P0[k, m]
        for t in range(T):
            A = adj[b, t]
            if component:
                _component_sizes(A, label, stack, sizes)
            _weights(A, weight_kind, W)
            for a in range(n):
                if t == 0:
                    for k in range(4):
                        xb[k] = x[a, k]
                        for m in range(4):
                            Pb[k, m] = P[a, k, m]
                else:
                    _predict(x[a], P[a], F, Q, xb, Pb, FP)
                _spd_inverse(Pb, L, M, Yb)
                _contribution(z[b, t, a, 0], z[b, t, a, 1], s[b, t, a, 0], s[b, t, a, 1], xb, Rinv, ic, Ic)
                w = float(sizes[a])
                for k in range(4):
                    acc = 0.0
                    for m in range(4):
                        acc += Yb[k, m] * xb[m]
                    y[a, k] = acc + w * ic[k]
                    for m in range(4):
                        Y[a, k, m] = Yb[k, m] + w * Ic[k, m]
            for _ in range(steps):
                for a in range(n):
                    for k in range(4):
                        acc = 0.0
                        for j in range(n):
                            acc += W[a, j] * y[j, k]
                        y2[a, k] = acc
                        for m in range(k, 4):
                            acc = 0.0
                            for j in range(n):
                                acc += W[a, j] * Y[j, k, m]
                            Y2[a, k, m] = acc
                            Y2[a, m, k] = acc
                y, y2 = y2, y
                Y, Y2 = Y2, Y
            for a in range(n):
                _spd_inverse(Y[a], L, M, Pi)
                for k in range(4):
                    acc = 0.0
                    for m in range(4):
                        acc += Pi[k, m] * y[a, m]
                    x[a, k] = acc
                    xs[b, t, a, k] = acc
                    for m in range(4):
                        P[a, k, m] = Pi[k, m]
                        Ps[b, t, a, k, m] = Pi[k, m]


def run_filter_numba(kind, measurements, sensor_positions, adjacency, x0, P0, F, Q, R,
                     consensus_steps=1, weights="eq11", contribution="component"):
    """``kind`` ∈ {"local", "modified_icf"} over a batch (B, T, n, ·); returns
    ``(estimates (B,T,n,4), covariances (B,T,n,4,4))``. Outputs are allocated here (timed)."""
    z = np.ascontiguousarray(measurements, dtype=np.float64)
    s = np.ascontiguousarray(sensor_positions, dtype=np.float64)
    B, T, n = z.shape[:3]
    xs = np.empty((B, T, n, 4))
    Ps = np.empty((B, T, n, 4, 4))
    args = [np.ascontiguousarray(v, dtype=np.float64) for v in (x0, P0, F, Q)]
    Rinv = np.linalg.inv(np.asarray(R, dtype=np.float64))
    if kind == "local":
        local_kernel(z, s, *args, Rinv, xs, Ps)
    elif kind == "modified_icf":
        a = np.ascontiguousarray(adjacency, dtype=np.float64)
        if contribution not in ("component", "one"):
            raise ValueError(f"unknown contribution {contribution!r}")
        modified_icf_kernel(z, s, a, *args, Rinv, int(consensus_steps), WEIGHT_CODES[weights],
                            contribution == "component", xs, Ps)
    else:
        raise ValueError(f"the numba peer has 'local' and 'modified_icf', not {kind!r}")
    return xs, Ps
