"""numba peer of two mcjax filters: the local EKF and the modified ICF, batched over runs.

Written from docs/equations.md §5.1–5.2, as a performance-minded researcher would: one
``@njit(parallel=True, cache=True)`` kernel per filter with ``prange`` over the runs, results
written straight into ``(B, T, n, 4)`` / ``(B, T, n, 4, 4)`` arrays. It imports neither ``jax``
nor ``mcjax``.

* local EKF (``local_kernel``): moment form, the equations of mcjax's own local filter
  (``mcjax/tracking/filters/batched.py``, ``native_kernels.cc``), as straight-line scalar code on the
  4 mean entries and the 10 distinct entries of the symmetric covariance (no arrays in the
  loop): predict ``x̄ = F x``, ``P̄ = F P Fᵀ + Q`` (step 0: no prediction); ``H`` analytic at
  ``x̄`` (range row ``[dx/r, 0, dy/r, 0]``, bearing row ``[−dy/r², 0, dx/r², 0]``, the guards of
  ``sensors.range_bearing``), ``ν = z − h(x̄)`` with the bearing wrapped into (−π, π];
  ``S = H P̄ Hᵀ + R`` (2×2, closed-form inverse), ``K = P̄ Hᵀ S⁻¹``, ``x = x̄ + K ν``,
  ``P = P̄ − K (P̄ Hᵀ)ᵀ``; no update when a component of z is not finite.
* modified ICF (``modified_icf_kernel``): information form of Sun et al. 2011 eqs. 8–12 (the
  equations of ``numpy_peer.py``), the same straight-line scalar code per agent, the agents'
  states and information pairs (10 distinct entries each) in arrays allocated once per run:
  predict as above, ``Ȳ = P̄⁻¹`` by a Cholesky factor (``L⁻¹`` then ``L⁻ᵀ L⁻¹``), ``ȳ = Ȳ x̄``;
  contribution linearised at ``x̄``: ``i = Hᵀ R⁻¹ (ν + H x̄)``, ``I = Hᵀ R⁻¹ H``, ``(0, 0)`` when
  a component of z is not finite; ``Y_i = Ȳ_i + n_i I_i`` (``n_i`` the size of agent i's
  connected component, or 1 with ``contribution="one"``), then L iterations
  ``(y_i, Y_i) ← Σ_j W_ij (y_j, Y_j)`` with the eq. 11 / Metropolis / max-degree weights;
  recover ``P = Y⁻¹`` (Cholesky again), ``x = P y``.

numba is a benchmark-only dependency (``pip install -e .[bench]``).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

WEIGHT_CODES = {"eq11": 0, "metropolis": 1, "max_degree": 2}


@njit(inline="always")
def _wrap(a):
    """An angle wrapped to (−π, π], as ``mcjax.tracking.numerics.wrap_angle`` (inside: unchanged)."""
    if -math.pi < a <= math.pi:
        return a
    w = (a + math.pi) % (2.0 * math.pi) - math.pi
    return math.pi if w == -math.pi else w


@njit
def _model(F, Q):
    """F's 16 entries row by row and Q's 10 upper entries, as tuples of scalars (:func:`_predict`)."""
    return ((F[0, 0], F[0, 1], F[0, 2], F[0, 3], F[1, 0], F[1, 1], F[1, 2], F[1, 3],
             F[2, 0], F[2, 1], F[2, 2], F[2, 3], F[3, 0], F[3, 1], F[3, 2], F[3, 3]),
            (Q[0, 0], Q[0, 1], Q[0, 2], Q[0, 3], Q[1, 1], Q[1, 2], Q[1, 3], Q[2, 2], Q[2, 3], Q[3, 3]))


@njit  # numba-level inlining trips its parfor analysis on the returned tuples; LLVM inlines it
def _predict(m, p, Ft, Qt):
    """Moment-form prediction ``x̄ = F x``, ``P̄ = F P Fᵀ + Q`` on scalars: ``m`` the 4 mean entries, ``p`` the
    10 upper entries of P (row by row), ``Ft`` F's 16 entries row by row, ``Qt`` Q's 10 upper entries."""
    m0, m1, m2, m3 = m
    p00, p01, p02, p03, p11, p12, p13, p22, p23, p33 = p
    f00, f01, f02, f03, f10, f11, f12, f13, f20, f21, f22, f23, f30, f31, f32, f33 = Ft
    q00, q01, q02, q03, q11, q12, q13, q22, q23, q33 = Qt
    # FP = F P
    fp00 = f00 * p00 + f01 * p01 + f02 * p02 + f03 * p03
    fp01 = f00 * p01 + f01 * p11 + f02 * p12 + f03 * p13
    fp02 = f00 * p02 + f01 * p12 + f02 * p22 + f03 * p23
    fp03 = f00 * p03 + f01 * p13 + f02 * p23 + f03 * p33
    fp10 = f10 * p00 + f11 * p01 + f12 * p02 + f13 * p03
    fp11 = f10 * p01 + f11 * p11 + f12 * p12 + f13 * p13
    fp12 = f10 * p02 + f11 * p12 + f12 * p22 + f13 * p23
    fp13 = f10 * p03 + f11 * p13 + f12 * p23 + f13 * p33
    fp20 = f20 * p00 + f21 * p01 + f22 * p02 + f23 * p03
    fp21 = f20 * p01 + f21 * p11 + f22 * p12 + f23 * p13
    fp22 = f20 * p02 + f21 * p12 + f22 * p22 + f23 * p23
    fp23 = f20 * p03 + f21 * p13 + f22 * p23 + f23 * p33
    fp30 = f30 * p00 + f31 * p01 + f32 * p02 + f33 * p03
    fp31 = f30 * p01 + f31 * p11 + f32 * p12 + f33 * p13
    fp32 = f30 * p02 + f31 * p12 + f32 * p22 + f33 * p23
    fp33 = f30 * p03 + f31 * p13 + f32 * p23 + f33 * p33
    # P̄ = FP Fᵀ + Q (upper triangle)
    p00 = fp00 * f00 + fp01 * f01 + fp02 * f02 + fp03 * f03 + q00
    p01 = fp00 * f10 + fp01 * f11 + fp02 * f12 + fp03 * f13 + q01
    p02 = fp00 * f20 + fp01 * f21 + fp02 * f22 + fp03 * f23 + q02
    p03 = fp00 * f30 + fp01 * f31 + fp02 * f32 + fp03 * f33 + q03
    p11 = fp10 * f10 + fp11 * f11 + fp12 * f12 + fp13 * f13 + q11
    p12 = fp10 * f20 + fp11 * f21 + fp12 * f22 + fp13 * f23 + q12
    p13 = fp10 * f30 + fp11 * f31 + fp12 * f32 + fp13 * f33 + q13
    p22 = fp20 * f20 + fp21 * f21 + fp22 * f22 + fp23 * f23 + q22
    p23 = fp20 * f30 + fp21 * f31 + fp22 * f32 + fp23 * f33 + q23
    p33 = fp30 * f30 + fp31 * f31 + fp32 * f32 + fp33 * f33 + q33
    # x̄ = F x
    m0, m1, m2, m3 = (
        f00 * m0 + f01 * m1 + f02 * m2 + f03 * m3,
        f10 * m0 + f11 * m1 + f12 * m2 + f13 * m3,
        f20 * m0 + f21 * m1 + f22 * m2 + f23 * m3,
        f30 * m0 + f31 * m1 + f32 * m2 + f33 * m3,
    )
    return (m0, m1, m2, m3), (p00, p01, p02, p03, p11, p12, p13, p22, p23, p33)


@njit
def _store(xs, Ps, b, t, a, m0, m1, m2, m3, p00, p01, p02, p03, p11, p12, p13, p22, p23, p33):
    """Write one agent-step's mean and its full symmetric covariance from the 10 distinct entries."""
    xs[b, t, a, 0], xs[b, t, a, 1], xs[b, t, a, 2], xs[b, t, a, 3] = m0, m1, m2, m3
    Ps[b, t, a, 0, 0], Ps[b, t, a, 0, 1], Ps[b, t, a, 0, 2], Ps[b, t, a, 0, 3] = p00, p01, p02, p03
    Ps[b, t, a, 1, 0], Ps[b, t, a, 1, 1], Ps[b, t, a, 1, 2], Ps[b, t, a, 1, 3] = p01, p11, p12, p13
    Ps[b, t, a, 2, 0], Ps[b, t, a, 2, 1], Ps[b, t, a, 2, 2], Ps[b, t, a, 2, 3] = p02, p12, p22, p23
    Ps[b, t, a, 3, 0], Ps[b, t, a, 3, 1], Ps[b, t, a, 3, 2], Ps[b, t, a, 3, 3] = p03, p13, p23, p33


@njit(parallel=True, cache=True)
def local_kernel(z, s, x0, P0, F, Q, Rinv, xs, Ps):
    """Local EKF in moment form for every run ``b`` and agent; writes ``xs``, ``Ps``.

    Straight-line scalar code: the state is 4 scalars for the mean and the 10 distinct entries
    ``p_ij`` (i ≤ j) of the symmetric covariance, so the inner loop allocates nothing. ``R`` is
    ``Rinv⁻¹`` (2×2, closed form; ``run_filter_numba`` passes ``R⁻¹`` for both kernels)."""
    B, T, n = z.shape[0], z.shape[1], z.shape[2]
    Ft, Qt = _model(F, Q)  # hoisted out of the loops, as scalars
    ri01 = 0.5 * (Rinv[0, 1] + Rinv[1, 0])
    rdet = Rinv[0, 0] * Rinv[1, 1] - ri01 * ri01
    r00, r01, r11 = Rinv[1, 1] / rdet, -ri01 / rdet, Rinv[0, 0] / rdet
    for b in prange(B):
        for a in range(n):
            m0, m1, m2, m3 = x0[0], x0[1], x0[2], x0[3]
            p00, p01, p02, p03 = P0[0, 0], P0[0, 1], P0[0, 2], P0[0, 3]
            p11, p12, p13 = P0[1, 1], P0[1, 2], P0[1, 3]
            p22, p23, p33 = P0[2, 2], P0[2, 3], P0[3, 3]
            for t in range(T):
                if t > 0:  # step 0 updates the prior without predicting
                    (m0, m1, m2, m3), (p00, p01, p02, p03, p11, p12, p13, p22, p23, p33) = _predict(
                        (m0, m1, m2, m3), (p00, p01, p02, p03, p11, p12, p13, p22, p23, p33), Ft, Qt)
                z0 = z[b, t, a, 0]
                z1 = z[b, t, a, 1]
                if math.isfinite(z0) and math.isfinite(z1):  # else: keep the prediction
                    # h(x̄) and H = ∂h/∂x (columns 0 and 2), the guards of sensors.range_bearing
                    dx = m0 - s[b, t, a, 0]
                    dy = m2 - s[b, t, a, 1]
                    sq = dx * dx + dy * dy
                    if sq <= 1e-30:
                        r = 0.0
                        h00 = 0.0
                        h02 = 0.0
                    else:
                        r = math.sqrt(sq)
                        h00 = dx / r
                        h02 = dy / r
                    if dx == 0.0 and dy == 0.0:
                        bearing = 0.0
                        h10 = 0.0
                        h12 = 0.0
                    else:
                        bearing = math.atan2(dy, dx)
                        h10 = -dy / sq
                        h12 = dx / sq
                    nu0 = z0 - r
                    nu1 = _wrap(z1 - bearing)
                    # P̄ Hᵀ: columns a (range) and c (bearing)
                    a0 = p00 * h00 + p02 * h02
                    a1 = p01 * h00 + p12 * h02
                    a2 = p02 * h00 + p22 * h02
                    a3 = p03 * h00 + p23 * h02
                    c0 = p00 * h10 + p02 * h12
                    c1 = p01 * h10 + p12 * h12
                    c2 = p02 * h10 + p22 * h12
                    c3 = p03 * h10 + p23 * h12
                    # S = H P̄ Hᵀ + R, inverted in closed form
                    s00 = h00 * a0 + h02 * a2 + r00
                    s01 = h00 * c0 + h02 * c2 + r01
                    s11 = h10 * c0 + h12 * c2 + r11
                    det = s00 * s11 - s01 * s01
                    i00 = s11 / det
                    i01 = -s01 / det
                    i11 = s00 / det
                    # K = P̄ Hᵀ S⁻¹ (rows k0 … k3, columns range/bearing)
                    k00 = a0 * i00 + c0 * i01
                    k01 = a0 * i01 + c0 * i11
                    k10 = a1 * i00 + c1 * i01
                    k11 = a1 * i01 + c1 * i11
                    k20 = a2 * i00 + c2 * i01
                    k21 = a2 * i01 + c2 * i11
                    k30 = a3 * i00 + c3 * i01
                    k31 = a3 * i01 + c3 * i11
                    # x = x̄ + K ν, P = P̄ − K (P̄ Hᵀ)ᵀ (upper triangle)
                    m0 += k00 * nu0 + k01 * nu1
                    m1 += k10 * nu0 + k11 * nu1
                    m2 += k20 * nu0 + k21 * nu1
                    m3 += k30 * nu0 + k31 * nu1
                    p00 -= k00 * a0 + k01 * c0
                    p01 -= k00 * a1 + k01 * c1
                    p02 -= k00 * a2 + k01 * c2
                    p03 -= k00 * a3 + k01 * c3
                    p11 -= k10 * a1 + k11 * c1
                    p12 -= k10 * a2 + k11 * c2
                    p13 -= k10 * a3 + k11 * c3
                    p22 -= k20 * a2 + k21 * c2
                    p23 -= k20 * a3 + k21 * c3
                    p33 -= k30 * a3 + k31 * c3
                _store(xs, Ps, b, t, a, m0, m1, m2, m3, p00, p01, p02, p03, p11, p12, p13, p22, p23, p33)


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


@njit(inline="always")
def _root(v):
    return math.sqrt(v) if v >= 0.0 else math.nan


@njit(inline="always")
def _spd_inverse10(a00, a01, a02, a03, a11, a12, a13, a22, a23, a33):
    """Inverse of the SPD 4×4 with upper triangle ``a_ij``, as its 10 upper entries (row-major):
    ``A = L Lᵀ``, ``M = L⁻¹``, ``A⁻¹ = Mᵀ M`` (``mcjax.tracking.numerics.spd_inverse``; NaN if not PD)."""
    l00 = _root(a00)
    l10 = (a01) / l00
    l20 = (a02) / l00
    l30 = (a03) / l00
    l11 = _root(a11 - l10 * l10)
    l21 = (a12 - l20 * l10) / l11
    l31 = (a13 - l30 * l10) / l11
    l22 = _root(a22 - l20 * l20 - l21 * l21)
    l32 = (a23 - l30 * l20 - l31 * l21) / l22
    l33 = _root(a33 - l30 * l30 - l31 * l31 - l32 * l32)
    m00 = 1.0 / l00
    m11 = 1.0 / l11
    m22 = 1.0 / l22
    m33 = 1.0 / l33
    m10 = -(l10 * m00) / l11
    m20 = -(l20 * m00 + l21 * m10) / l22
    m21 = -(l21 * m11) / l22
    m30 = -(l30 * m00 + l31 * m10 + l32 * m20) / l33
    m31 = -(l31 * m11 + l32 * m21) / l33
    m32 = -(l32 * m22) / l33
    return (
        (m00 * m00 + m10 * m10 + m20 * m20 + m30 * m30),
        (m10 * m11 + m20 * m21 + m30 * m31),
        (m20 * m22 + m30 * m32),
        (m30 * m33),
        (m11 * m11 + m21 * m21 + m31 * m31),
        (m21 * m22 + m31 * m32),
        (m31 * m33),
        (m22 * m22 + m32 * m32),
        (m32 * m33),
        (m33 * m33),
    )


@njit(parallel=True, cache=True)
def modified_icf_kernel(z, s, adj, x0, P0, F, Q, Rinv, steps, weight_kind, component, xs, Ps):
    """Modified ICF (Sun et al. 2011 eqs. 8–12) for every run ``b``; writes ``xs``, ``Ps``.

    Straight-line scalar code per agent (4 mean entries, the 10 distinct entries of each
    symmetric matrix); the agents' states and information pairs live in ``(n, 4)`` / ``(n, 10)``
    arrays allocated once per run, which the consensus mixes."""
    B, T, n = z.shape[0], z.shape[1], z.shape[2]
    Ft, Qt = _model(F, Q)  # hoisted out of the loops, as scalars
    ri00, ri01, ri10, ri11 = Rinv[0, 0], Rinv[0, 1], Rinv[1, 0], Rinv[1, 1]
    for b in prange(B):
        X = np.empty((n, 4))  # the agents' estimates and covariances (upper triangles)
        Pu = np.empty((n, 10))
        y = np.empty((n, 4))  # information pairs, mixed by the consensus
        Yu = np.empty((n, 10))
        y2 = np.empty((n, 4))
        Yu2 = np.empty((n, 10))
        W = np.empty((n, n))
        label = np.empty(n, np.int64)
        stack = np.empty(n, np.int64)
        sizes = np.ones(n, np.int64)
        for a in range(n):
            for k in range(4):
                X[a, k] = x0[k]
            e = 0
            for k in range(4):
                for m in range(k, 4):
                    Pu[a, e] = P0[k, m]
                    e += 1
        for t in range(T):
            A = adj[b, t]
            if component:
                _component_sizes(A, label, stack, sizes)
            _weights(A, weight_kind, W)
            for a in range(n):
                m0, m1, m2, m3 = X[a, 0], X[a, 1], X[a, 2], X[a, 3]
                p00, p01, p02, p03, p11 = Pu[a, 0], Pu[a, 1], Pu[a, 2], Pu[a, 3], Pu[a, 4]
                p12, p13, p22, p23, p33 = Pu[a, 5], Pu[a, 6], Pu[a, 7], Pu[a, 8], Pu[a, 9]
                if t > 0:  # step 0 updates the prior without predicting
                    (m0, m1, m2, m3), (p00, p01, p02, p03, p11, p12, p13, p22, p23, p33) = _predict(
                        (m0, m1, m2, m3), (p00, p01, p02, p03, p11, p12, p13, p22, p23, p33), Ft, Qt)
                # Ȳ = P̄⁻¹, ȳ = Ȳ x̄
                b00, b01, b02, b03, b11, b12, b13, b22, b23, b33 = _spd_inverse10(
                    p00, p01, p02, p03, p11, p12, p13, p22, p23, p33)
                v0 = b00 * m0 + b01 * m1 + b02 * m2 + b03 * m3
                v1 = b01 * m0 + b11 * m1 + b12 * m2 + b13 * m3
                v2 = b02 * m0 + b12 * m1 + b22 * m2 + b23 * m3
                v3 = b03 * m0 + b13 * m1 + b23 * m2 + b33 * m3
                z0 = z[b, t, a, 0]
                z1 = z[b, t, a, 1]
                if math.isfinite(z0) and math.isfinite(z1):  # else: no contribution
                    # h(x̄) and H = ∂h/∂x (columns 0 and 2), the guards of sensors.range_bearing
                    dx = m0 - s[b, t, a, 0]
                    dy = m2 - s[b, t, a, 1]
                    sq = dx * dx + dy * dy
                    if sq <= 1e-30:
                        r = 0.0
                        h00 = 0.0
                        h02 = 0.0
                    else:
                        r = math.sqrt(sq)
                        h00 = dx / r
                        h02 = dy / r
                    if dx == 0.0 and dy == 0.0:
                        bearing = 0.0
                        h10 = 0.0
                        h12 = 0.0
                    else:
                        bearing = math.atan2(dy, dx)
                        h10 = -dy / sq
                        h12 = dx / sq
                    # i = Hᵀ R⁻¹ (ν + H x̄), I = Hᵀ R⁻¹ H (rows/columns 0 and 2 only), weighted
                    w = float(sizes[a])
                    e0 = z0 - r + h00 * m0 + h02 * m2
                    e1 = _wrap(z1 - bearing) + h10 * m0 + h12 * m2
                    g00 = h00 * ri00 + h10 * ri10
                    g01 = h00 * ri01 + h10 * ri11
                    g20 = h02 * ri00 + h12 * ri10
                    g21 = h02 * ri01 + h12 * ri11
                    v0 += w * (g00 * e0 + g01 * e1)
                    v2 += w * (g20 * e0 + g21 * e1)
                    b00 += w * (g00 * h00 + g01 * h10)
                    b02 += w * (g00 * h02 + g01 * h12)
                    b22 += w * (g20 * h02 + g21 * h12)
                y[a, 0], y[a, 1], y[a, 2], y[a, 3] = v0, v1, v2, v3
                Yu[a, 0], Yu[a, 1], Yu[a, 2], Yu[a, 3], Yu[a, 4] = b00, b01, b02, b03, b11
                Yu[a, 5], Yu[a, 6], Yu[a, 7], Yu[a, 8], Yu[a, 9] = b12, b13, b22, b23, b33
            for _ in range(steps):  # (y_i, Y_i) ← Σ_j W_ij (y_j, Y_j)
                for a in range(n):
                    for k in range(4):
                        acc = 0.0
                        for j in range(n):
                            acc += W[a, j] * y[j, k]
                        y2[a, k] = acc
                    for e in range(10):
                        acc = 0.0
                        for j in range(n):
                            acc += W[a, j] * Yu[j, e]
                        Yu2[a, e] = acc
                y, y2 = y2, y
                Yu, Yu2 = Yu2, Yu
            for a in range(n):  # P = Y⁻¹, x = P y
                p00, p01, p02, p03, p11, p12, p13, p22, p23, p33 = _spd_inverse10(
                    Yu[a, 0], Yu[a, 1], Yu[a, 2], Yu[a, 3], Yu[a, 4],
                    Yu[a, 5], Yu[a, 6], Yu[a, 7], Yu[a, 8], Yu[a, 9])
                v0, v1, v2, v3 = y[a, 0], y[a, 1], y[a, 2], y[a, 3]
                m0 = p00 * v0 + p01 * v1 + p02 * v2 + p03 * v3
                m1 = p01 * v0 + p11 * v1 + p12 * v2 + p13 * v3
                m2 = p02 * v0 + p12 * v1 + p22 * v2 + p23 * v3
                m3 = p03 * v0 + p13 * v1 + p23 * v2 + p33 * v3
                X[a, 0], X[a, 1], X[a, 2], X[a, 3] = m0, m1, m2, m3
                Pu[a, 0], Pu[a, 1], Pu[a, 2], Pu[a, 3], Pu[a, 4] = p00, p01, p02, p03, p11
                Pu[a, 5], Pu[a, 6], Pu[a, 7], Pu[a, 8], Pu[a, 9] = p12, p13, p22, p23, p33
                _store(xs, Ps, b, t, a, m0, m1, m2, m3, p00, p01, p02, p03, p11, p12, p13, p22, p23, p33)


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
