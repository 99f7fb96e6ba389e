"""Structure-of-arrays kernels of the local EKF and the modified ICF for :func:`run_filter`.

The general filters (:mod:`.consensus`) keep one run's state as ``(n, 4)`` / ``(n, 4, 4)``
arrays and are batched with ``vmap``; on the CPU XLA then runs every 4×4 entry as a strided
slice of a batch-first array, in dozens of small kernels per step (docs/filter_speed.md).
Here the same equations are written on *structure-of-arrays* state, batch last: a state is
a tuple of 4 mean arrays and the 10 unique entries of the symmetric covariance (or
information) matrix, each of shape ``(n, B)`` (agents, runs). Every operation is then an
elementwise operation on contiguous ``(n, B)`` arrays, which XLA fuses into a few vectorised
loops per step.

* ``local``: the EKF in *moment* form (docs/equations.md §5.1; algebraically the information
  form of :func:`.consensus.local_step`): ``S = H P̄ Hᵀ + R`` (2×2, inverted in closed form),
  ``K = P̄ Hᵀ S⁻¹``, ``x = x̄ + K ν``, ``P = P̄ − K (P̄ Hᵀ)ᵀ``. A missing measurement leaves the
  prediction unchanged.
* ``modified_icf``: Sun et al. 2011 eqs. 8–12 exactly as :func:`.consensus.modified_icf_step`
  (information form, the Cholesky inverses of :func:`mcjax.tracking.numerics.spd_inverse`).

Symmetric matrices keep their upper triangle only, so they are exactly symmetric and need no
``symmetrize``. ``H = ∂h/∂x`` comes from ``jax.jvp`` of the measurement function (one
directional derivative per state component), never from a hand-typed formula; for the
range–bearing sensor, from two ``jvp`` of the same function written on the position arrays,
its velocity columns left out as structural zeros (:func:`linearise_range_bearing`). The
modified ICF writes its weighted information pair to memory before the consensus
(:func:`materialise`): without it XLA recomputed the pair inside every agent's mix, and the
kernel ran 1.4–1.7x slower (docs/filter_speed.md). Everything is pure JAX and differentiable.
"""

from __future__ import annotations

from functools import lru_cache, partial
from types import MappingProxyType

import jax
import jax.numpy as jnp

from mcjax import runtime
from mcjax.tracking import graph, numerics
from mcjax.tracking.models.sensors import range_bearing
from mcjax.tracking.numerics import wrap_angle

D = 4  # state dimension [x, ẋ, y, ẏ]
M = 2  # measurement dimension [range, bearing]
UPPER = tuple((i, j) for i in range(D) for j in range(i, D))  # the 10 unique entries, row-major


def _sym_index(d):
    return {(i, j): k for k, (i, j) in enumerate((i, j) for i in range(d) for j in range(i, d))}


_IDX = _sym_index(D)


def sym(S, i, j):
    """Entry (i, j) of a symmetric matrix stored as its upper triangle (a tuple)."""
    return S[_IDX[(i, j)] if i <= j else _IDX[(j, i)]]


def to_sym(A):
    """Upper triangle of a dense (…, D, D) matrix as a tuple of (…) arrays."""
    return tuple(A[..., i, j] for i, j in UPPER)


def predict(x, P, F, Q):
    """``x̄ = F x``, ``P̄ = F P Fᵀ + Q`` (upper triangle). ``F``, ``Q`` are (D, D) (no batch)."""
    xb = tuple(_dot([F[i, k] for k in range(D)], x) for i in range(D))
    FP = [[_dot([F[i, k] for k in range(D)], [sym(P, k, j) for k in range(D)]) for j in range(D)]
          for i in range(D)]
    Pb = tuple(_dot([FP[i][k] for k in range(D)], [F[j, k] for k in range(D)]) + Q[i, j] for i, j in UPPER)
    return xb, Pb


def _dot(a, b):
    """``Σ_k a_k b_k``; a term whose factor is ``None`` (a structural zero) is left out."""
    out = None
    for ak, bk in zip(a, b):
        if ak is None or bk is None:
            continue
        out = ak * bk if out is None else out + ak * bk
    return out


def spd_inverse(S):
    """Inverse of SPD matrices given as upper triangles: Cholesky ``S = L Lᵀ``, ``S⁻¹ = L⁻ᵀ L⁻¹``
    (the unrolled algorithm of :func:`mcjax.tracking.numerics.spd_inverse`; NaN if not positive definite)."""
    m = numerics.lower_inverse(numerics.cholesky_entries(lambda i, j: sym(S, i, j), D))
    return tuple(numerics.inverse_entry(m, i, j) for i, j in UPPER)


def sym_matvec(S, v):
    return tuple(_dot([sym(S, i, k) for k in range(D)], v) for i in range(D))


def linearise(h, x, sensor):
    """``h(x)`` and ``H = ∂h/∂x`` at ``x`` for SoA state: ``x`` a tuple of D arrays, ``sensor``
    a tuple of arrays. Returns ``(h (tuple of M), H (M × D nested lists))``; one ``jax.jvp``
    per state component (a component ``h`` does not depend on gives zeros)."""
    s = jnp.stack(sensor, axis=-1)

    def f_k(k):
        def f(xk):
            xs = list(x)
            xs[k] = xk
            return h(jnp.stack(xs, axis=-1), s)
        return f

    cols = []
    value = None
    for k in range(D):
        value, col = jax.jvp(f_k(k), (x[k],), (jnp.ones_like(x[k]),))
        cols.append(col)
    hx = tuple(value[..., a] for a in range(M))
    H = [[cols[k][..., a] for k in range(D)] for a in range(M)]
    return hx, H


def _range_bearing_positions(px, py, sx, sy):
    """Range–bearing of a target at ``(px, py)`` from a sensor at ``(sx, sy)`` (Sun et al. 2011
    §1.3), the operations of :func:`mcjax.tracking.models.sensors.range_bearing` (safe norm, bearing 0 at
    the sensor) written on separate arrays: no stack, no reduction over a size-2 axis."""
    dx, dy = px - sx, py - sy
    on_sensor = (dx == 0.0) & (dy == 0.0)
    bearing = jnp.where(on_sensor, 0.0, jnp.arctan2(dy, jnp.where(on_sensor, 1.0, dx)))
    sq = dx * dx + dy * dy
    positive = ~(sq <= 1e-30)
    return jnp.where(positive, jnp.sqrt(jnp.where(positive, sq, 1.0)), 0.0), bearing


def linearise_range_bearing(x, sensor):
    """:func:`linearise` for the range–bearing sensor: ``h`` depends on the target's position
    ``(x[0], x[2])`` only, so ``H``'s velocity columns are structural zeros (``None``) and
    ``H``'s position columns come from two ``jax.jvp`` of :func:`_range_bearing_positions`."""
    f = partial(_range_bearing_positions, sx=sensor[0], sy=sensor[1])
    one, zero = jnp.ones_like(x[0]), jnp.zeros_like(x[0])
    hx, col0 = jax.jvp(f, (x[0], x[2]), (one, zero))
    _, col2 = jax.jvp(f, (x[0], x[2]), (zero, one))
    H = [[col0[a], None, col2[a], None] for a in range(M)]
    return hx, H


def _innovation(z, hx, angle_mask):
    nu = [z[a] - hx[a] for a in range(M)]
    return tuple(wrap_angle(v) if angle_mask[a] else v for a, v in enumerate(nu))


def local_update(h, angle_mask, xb, Pb, z, sensor, R):
    """Moment-form EKF update (see module docstring). ``z`` a tuple of M arrays (NaN where
    missing), ``R`` (M, M). Returns ``(x, P)``; the prediction where ``z`` is missing."""
    valid, H, nu = _measured(h, angle_mask, xb, z, sensor)
    PHt = [[_dot([sym(Pb, i, k) for k in range(D)], H[a]) for a in range(M)] for i in range(D)]
    S = {(a, c): _dot(H[a], [PHt[k][c] for k in range(D)]) + R[a, c] for a in range(M) for c in range(a, M)}
    det = S[0, 0] * S[1, 1] - S[0, 1] * S[0, 1]
    inv = {(0, 0): S[1, 1] / det, (1, 1): S[0, 0] / det, (0, 1): -S[0, 1] / det}
    Si = [[inv[min(a, c), max(a, c)] for c in range(M)] for a in range(M)]
    K = [[_dot(PHt[i], [Si[a][c] for a in range(M)]) for c in range(M)] for i in range(D)]
    x = tuple(jnp.where(valid, xb[i] + _dot(K[i], nu), xb[i]) for i in range(D))
    P = tuple(jnp.where(valid, sym(Pb, i, j) - _dot(K[i], PHt[j]), sym(Pb, i, j)) for i, j in UPPER)
    return x, P


def _measured(h, angle_mask, xb, z, sensor):
    """``(valid, H, ν)``: where every component of ``z`` is finite, the Jacobian at ``xb`` and
    the innovation (missing measurements zeroed, so they stay finite where masked out)."""
    valid = jnp.isfinite(z[0])
    for a in range(1, M):
        valid = valid & jnp.isfinite(z[a])
    z = tuple(jnp.where(valid, za, 0.0) for za in z)
    hx, H = linearise_range_bearing(xb, sensor) if h is range_bearing else linearise(h, xb, sensor)
    return valid, H, _innovation(z, hx, angle_mask)


def contribution(h, angle_mask, xb, z, sensor, R_inv):
    """Information contribution ``i = Hᵀ R⁻¹ (ν + H x̄)``, ``I = Hᵀ R⁻¹ H`` (upper triangle),
    zero where a component of ``z`` is missing (docs/equations.md §5.1). An entry that is zero
    whatever the data (``H``'s structural zeros) is ``None``."""
    valid, H, nu = _measured(h, angle_mask, xb, z, sensor)
    pseudo = [nu[a] + _dot(H[a], xb) for a in range(M)]
    G = [[_dot([H[a][i] for a in range(M)], [R_inv[a, c] for a in range(M)]) for c in range(M)] for i in range(D)]
    i_c = tuple(_where(valid, _dot(G[i], pseudo), 0.0) for i in range(D))
    I_c = tuple(_where(valid, _dot(G[i], [H[c][j] for c in range(M)]), 0.0) for i, j in UPPER)
    return i_c, I_c


def _where(valid, value, otherwise):
    """``jnp.where`` that keeps a structural zero (``None``) as ``None``."""
    return None if value is None else jnp.where(valid, value, otherwise)


def materialise(values, one):
    """``values`` (a tuple of arrays) divided by ``one``, a traced 1.0: the same numbers bit for
    bit (``v / 1 = v`` in IEEE arithmetic), but written to memory once. XLA's CPU fusion copies
    a chain of multiply–adds into every loop that reads its result and stops only at an
    "expensive" operation such as a division; so a value read by many later loops is
    recomputed in each of them unless a division ends its chain here (docs/filter_speed.md)."""
    return tuple(v / one for v in values)


def agent_mix(W, values):
    """``out_i = Σ_j W[i][j] values_j`` for (n, B) arrays: ``W`` (n, n, B)."""
    n = W.shape[0]
    out = W[:, 0] * values[0][None]
    for j in range(1, n):
        out = out + W[:, j] * values[j][None]
    return out


def _graph_terms(opts, adjacency):
    """Consensus weights (n, n, B) and contribution weights (n, B) of one step's batch-last
    adjacency (n, n, B), through the graph functions on a batch-first copy."""
    a = jnp.moveaxis(adjacency, -1, 0)
    W = jnp.moveaxis(graph.consensus_weights(a, opts.weights), 0, -1)
    if opts.contribution == "one":
        s = jnp.ones(adjacency.shape[1:], adjacency.dtype)
    else:
        s = jnp.moveaxis(graph.component_sizes(a), 0, -1)
    return W, s


def modified_icf_update(h, angle_mask, opts, xb, Pb, z, sensor, adjacency, R_inv, one=None):
    """Modified ICF (Sun et al. 2011 eqs. 8–12) after the prediction; returns ``(x, P)``."""
    Yb = spd_inverse(Pb)
    yb = sym_matvec(Yb, xb)
    i_c, I_c = contribution(h, angle_mask, xb, z, sensor, R_inv)
    W, s = _graph_terms(opts, adjacency)
    y = tuple(yb[k] if i_c[k] is None else yb[k] + s * i_c[k] for k in range(D))
    Y = tuple(Yb[k] if I_c[k] is None else Yb[k] + s * I_c[k] for k in range(len(UPPER)))
    if one is not None:  # every agent's consensus mix reads each agent's pair: write it once
        y_Y = materialise(y + Y, one)
        y, Y = y_Y[:D], y_Y[D:]
    if opts.consensus_steps:
        def body(_, yY):
            return tuple(agent_mix(W, v) for v in yY)
        y_Y = jax.lax.fori_loop(0, opts.consensus_steps, body, y + Y)
        y, Y = y_Y[:D], y_Y[D:]
    P = spd_inverse(Y)
    return sym_matvec(P, y), P


#: XLA options per kernel. The local EKF's program runs ~20 % faster without XLA's "YNN"
#: reduction kernels (its only reductions are the 2-term sums of the range's square); the
#: modified ICF's ran ~1.7x slower without them, so it keeps XLA's defaults
#: (docs/filter_speed.md). An option this JAX does not know is dropped.
COMPILER_OPTIONS = {"local": MappingProxyType({"xla_cpu_experimental_ynn_fusion_type": ""})}


@lru_cache(maxsize=None)
def _program(kind):
    options = runtime.known_compiler_options(COMPILER_OPTIONS.get(kind))
    return jax.jit(partial(_run_batch, kind), static_argnames=("opts", "h", "angle_mask", "dtype"),
                   compiler_options=options)


def run_batch(kind, opts, h, angle_mask, z, sensors, adjacency, x0, P0, F, Q, R, dtype="float64"):
    """``kind`` ("local" or "modified_icf") over a batch of recorded runs, compiled (one
    program per kind, with its :data:`COMPILER_OPTIONS`). Called on concrete arrays (not
    inside another ``jit``). See :func:`_run_batch`."""
    return _program(kind)(opts, h, angle_mask, z, sensors, adjacency, x0, P0, F, Q, R, dtype=dtype)


def _run_batch(kind, opts, h, angle_mask, z, sensors, adjacency, x0, P0, F, Q, R, dtype="float64"):
    """``kind`` ("local" or "modified_icf") over a batch of recorded runs.

    ``z`` (B, T, n, M) (NaN where missing), ``sensors`` (B, T, n, ·), ``adjacency``
    (B, T, n, n) (not read by ``"local"``: pass ``None``); ``x0`` (D,), ``P0``, ``F``, ``Q``
    (D, D), ``R`` (M, M); every input is cast to ``dtype`` first. Step 0 updates the prior
    without predicting (docs/equations.md timing).

    Returns estimates (T, n, D, B) and covariances (T, n, D, D, B): *batch last*, as the
    state is carried, so each step's outputs are written as contiguous ``(n, B)`` rows and no
    transpose is needed; ``numpy.moveaxis(out, -1, 0)`` views them as (B, T, n, …) without a
    copy (:func:`mcjax.tracking.filters.recorded.run_filter` does so).
    """
    z, sensors, x0, P0, F, Q, R = (jnp.asarray(v, dtype) for v in (z, sensors, x0, P0, F, Q, R))
    B, T, n = z.shape[:3]
    zt = jnp.moveaxis(z, 0, -1)              # (T, n, M, B)
    st = jnp.moveaxis(sensors, 0, -1)        # (T, n, ·, B)
    if kind == "local":
        at = jnp.zeros((T,), z.dtype)        # unused
    else:
        at = jnp.moveaxis(jnp.asarray(adjacency, dtype), 0, -1)  # (T, n, n, B)
    R_inv = jnp.linalg.inv(R)
    one = P0[0, 0] / P0[0, 0]  # exactly 1.0 (P0 is positive definite), unknown to the compiler
    P0 = 0.5 * (P0 + P0.T)
    x = tuple(jnp.broadcast_to(x0[k], (n, B)) for k in range(D))
    P = tuple(jnp.broadcast_to(P0[i, j], (n, B)) for i, j in UPPER)
    eye, zero = jnp.eye(D, dtype=F.dtype), jnp.zeros_like(Q)

    def body(carry, inputs):
        x, P = carry
        t, zz, ss, aa = inputs
        first = t == 0
        xb, Pb = predict(x, P, jnp.where(first, eye, F), jnp.where(first, zero, Q))
        zs = tuple(zz[:, a] for a in range(M))
        sn = tuple(ss[:, a] for a in range(ss.shape[1]))
        if kind == "local":
            x, P = local_update(h, angle_mask, xb, Pb, zs, sn, R)
        else:
            x, P = modified_icf_update(h, angle_mask, opts, xb, Pb, zs, sn, aa, R_inv, one)
        dense = jnp.stack([jnp.stack([sym(P, i, j) for j in range(D)], 1) for i in range(D)], 1)
        return (x, P), (jnp.stack(x, 1), dense)  # (n, D, B), (n, D, D, B)

    _, (X, PP) = jax.lax.scan(body, (x, P), (jnp.arange(T), zt, st, at))
    return X, PP
