"""Small numerical kernels shared by every layer.

Everything here is pure, works on arrays with any leading batch shape, and is safe to
differentiate: norms and square roots use the double-``where`` trick so their gradients are
finite at zero.

The small-matrix kernels (``spd_inverse``, ``spd_solve``) are written as unrolled scalar
code over the last two axes. On the CPU, XLA runs ``jnp.linalg`` on tiny matrices through
per-matrix library calls, which is overhead-bound; unrolled elementwise code fuses into a
few vectorised loops over the batch (docs/architecture.md). They fall back to
``jnp.linalg`` above ``UNROLL_MAX``.
"""

from __future__ import annotations

import math
import warnings

import jax
import jax.numpy as jnp

UNROLL_MAX = 6

_X64_WARNED = False


def x64_enabled() -> bool:
    """Whether JAX's 64-bit mode is on (float64 arrays stay float64)."""
    return bool(jax.config.jax_enable_x64)


def require_x64(what: str) -> None:
    """Warn once per process (a ``UserWarning``) that ``what`` computes in float32 when JAX's
    64-bit mode is off: mcjax does not switch it on at import; :func:`mcjax.configure` does
    (the CLI and the engine call it), so float64 input stays float64 (e.g.
    ``graph.algebraic_connectivity`` of a float64 numpy adjacency) and float32 input, or a
    Config with ``dtype = "float32"``, stays float32. Called by the library's entry points that
    are used on their own (graph, ``run_filter``); costs one flag check."""
    global _X64_WARNED
    if _X64_WARNED or jax.config.jax_enable_x64:
        return
    _X64_WARNED = True
    warnings.warn(f"{what}: JAX's 64-bit mode is off, so this computes in float32; call mcjax.configure() "
                  "first (64-bit mode and the CPU devices mcjax uses)", UserWarning, stacklevel=3)


def symmetrize(a: jax.Array) -> jax.Array:
    """Return ``(a + aᵀ)/2`` over the last two axes."""
    return 0.5 * (a + jnp.swapaxes(a, -1, -2))


def wrap_angle(a: jax.Array) -> jax.Array:
    """Wrap angles to (−π, π]; angles already inside are returned bit-for-bit unchanged."""
    wrapped = jnp.mod(a + jnp.pi, 2.0 * jnp.pi) - jnp.pi
    # mod maps +π to −π; keep +π so the interval is (−π, π].
    wrapped = jnp.where(wrapped == -jnp.pi, jnp.pi, wrapped)
    return jnp.where((a > -jnp.pi) & (a <= jnp.pi), a, wrapped)


def safe_norm(x: jax.Array, axis: int = -1, eps: float = 1e-30) -> jax.Array:
    """Euclidean norm whose gradient is finite (zero) at the origin (double-``where``).

    NaN input gives NaN (never a silent 0)."""
    sq = jnp.sum(x * x, axis=axis)
    positive = ~(sq <= eps)  # NaN counts as positive, so it propagates instead of hiding
    safe_sq = jnp.where(positive, sq, 1.0)
    return jnp.where(positive, jnp.sqrt(safe_sq), 0.0)


def softmin(x: jax.Array, temperature: jax.Array | float, axis: int = -1) -> jax.Array:
    """Relaxation minimum ``−T·logsumexp(−x/T)``; tends to ``min`` as ``T → 0`` (≤ min)."""
    t = jnp.asarray(temperature)
    return -t * jax.nn.logsumexp(-x / t, axis=axis)


def softmax_value(x: jax.Array, temperature: jax.Array | float, axis: int = -1) -> jax.Array:
    """Relaxation maximum ``T·logsumexp(x/T)``; tends to ``max`` as ``T → 0`` (≥ max)."""
    t = jnp.asarray(temperature)
    return t * jax.nn.logsumexp(x / t, axis=axis)


def matmul(a: jax.Array, b: jax.Array) -> jax.Array:
    """Batched ``a @ b`` with the contraction unrolled into broadcast multiply-adds.

    For the 2–6 sized matrices of this package this fuses into elementwise loops (XLA's CPU
    reductions over tiny axes are several times slower), and — unlike a batched
    ``dot_general`` — its per-element result does not depend on the batch size.
    """
    out = a[..., :, 0, None] * b[..., None, 0, :]
    for k in range(1, a.shape[-1]):
        out = out + a[..., :, k, None] * b[..., None, k, :]
    return out


def matvec(a: jax.Array, v: jax.Array) -> jax.Array:
    """Batched ``a @ v`` (see :func:`matmul`)."""
    out = a[..., :, 0] * v[..., 0, None]
    for k in range(1, a.shape[-1]):
        out = out + a[..., :, k] * v[..., k, None]
    return out


def weighted_agent_sum(w: jax.Array, values: jax.Array) -> jax.Array:
    """``out_i = Σ_j w_ij values_j`` over the leading (agent) axis of ``values`` (n, ...),
    unrolled over j like :func:`matmul`."""
    extra = (1,) * (values.ndim - 1)
    out = w[:, 0].reshape((-1,) + extra) * values[0][None]
    for j in range(1, w.shape[1]):
        out = out + w[:, j].reshape((-1,) + extra) * values[j][None]
    return out


def quad(a: jax.Array, p: jax.Array) -> jax.Array:
    """``a p aᵀ`` for batched matrices."""
    return matmul(matmul(a, p), jnp.swapaxes(a, -1, -2))


def cholesky_entries(entry, n: int) -> list[list[jax.Array]]:
    """Lower Cholesky factor, unrolled, of the n×n SPD matrix whose lower entries are
    ``entry(i, j)`` (i ≥ j; batch-shaped arrays), as a nested list of batch-shaped arrays."""
    l = [[None] * n for _ in range(n)]
    for j in range(n):
        s = entry(j, j)
        for k in range(j):
            s = s - l[j][k] * l[j][k]
        d = jnp.sqrt(s)  # NaN if the matrix is not positive definite: surfaced, never hidden
        l[j][j] = d
        for i in range(j + 1, n):
            s = entry(i, j)
            for k in range(j):
                s = s - l[i][k] * l[j][k]
            l[i][j] = s / d
    return l


def lower_inverse(l: list[list]) -> list[list]:
    """``M = L⁻¹`` of a lower-triangular nested list (forward substitution column by column)."""
    n = len(l)
    m = [[None] * n for _ in range(n)]
    for j in range(n):
        m[j][j] = 1.0 / l[j][j]
        for i in range(j + 1, n):
            s = l[i][j] * m[j][j]
            for k in range(j + 1, i):
                s = s + l[i][k] * m[k][j]
            m[i][j] = -s / l[i][i]
    return m


def inverse_entry(m: list[list], i: int, j: int):
    """Entry (i, j), i ≤ j, of ``Mᵀ M`` = ``(L Lᵀ)⁻¹`` for ``M = L⁻¹`` (:func:`lower_inverse`)."""
    s = m[j][i] * m[j][j]
    for k in range(j + 1, len(m)):
        s = s + m[k][i] * m[k][j]
    return s


def _cholesky_unrolled(a: jax.Array) -> list[list[jax.Array]]:
    """Lower Cholesky factor of ``a`` given with the matrix axes FIRST, (n, n, ...), as a
    nested list of batch-shaped arrays."""
    return cholesky_entries(lambda i, j: a[i, j], a.shape[0])


def _matrix_axes_first(a: jax.Array) -> jax.Array:
    # One transpose so every scalar slice below is contiguous over the batch (SIMD-friendly);
    # slicing the last two axes of a batch-first array is strided and ~3x slower on the CPU.
    return jnp.moveaxis(a, (-2, -1), (0, 1))


def spd_inverse(a: jax.Array) -> jax.Array:
    """Inverse of symmetric positive-definite matrices over the last two axes.

    Cholesky ``a = L Lᵀ``, then ``a⁻¹ = L⁻ᵀ L⁻¹``, unrolled for ``n ≤ UNROLL_MAX``. A matrix
    that is not positive definite yields NaN (it is never silently repaired).
    """
    n = a.shape[-1]
    if n > UNROLL_MAX:
        c = jnp.linalg.cholesky(a)
        eye = jnp.broadcast_to(jnp.eye(n, dtype=a.dtype), a.shape)
        linv = jax.scipy.linalg.solve_triangular(c, eye, lower=True)
        return jnp.swapaxes(linv, -1, -2) @ linv
    m = lower_inverse(_cholesky_unrolled(_matrix_axes_first(a)))
    out = [[None] * n for _ in range(n)]
    for i in range(n):
        for j in range(i, n):
            out[i][j] = out[j][i] = inverse_entry(m, i, j)
    stacked = jnp.stack([jnp.stack(row) for row in out])  # (n, n, ...)
    return jnp.moveaxis(stacked, (0, 1), (-2, -1))


def spd_solve(a: jax.Array, b: jax.Array) -> jax.Array:
    """Solve ``a x = b`` for SPD ``a`` (…, n, n) and a vector ``b`` (…, n)."""
    return matvec(spd_inverse(a), b)


def spd_logdet(a: jax.Array) -> jax.Array:
    """``log det a`` of SPD matrices from the Cholesky diagonal."""
    n = a.shape[-1]
    if n > UNROLL_MAX:
        return 2.0 * jnp.sum(jnp.log(jnp.diagonal(jnp.linalg.cholesky(a), axis1=-2, axis2=-1)), -1)
    l = _cholesky_unrolled(_matrix_axes_first(a))
    return 2.0 * sum(jnp.log(l[j][j]) for j in range(n))


def is_finite_tree(*arrays: jax.Array) -> jax.Array:
    """True where every element of every array (reduced over all non-batch axes) is finite."""
    out = True
    for x in arrays:
        out = jnp.logical_and(out, jnp.all(jnp.isfinite(x)))
    return out


#: jaxlib's CPU LAPACK kernels split a batch over XLA's CPU thread pool once the batch's estimated
#: work (``batch × 5 n³`` for ``syevd``) reaches 2·10⁵ flops, and the calling thread then blocks
#: until pool threads have run the pieces. With one CPU device per core, every pool thread may
#: be a device running its program and blocked the same way: the sweep hangs at 0 % CPU
#: (2026-12-04, jax 0.10.2: two devices, teams of ≥ 8 UAVs at 100 runs per batch). Batches are
#: therefore handed to LAPACK in pieces below that size, which jaxlib runs on the calling thread.
LAPACK_INLINE_WORK = 200_000


def _in_pieces(fn, x: jax.Array):
    """``fn`` (a batched LAPACK call) over the matrices (…, n, n) of ``x``, in pieces of
    ``k`` matrices with ``k · 5 n³ < LAPACK_INLINE_WORK`` (one matrix at a time from n = 35)."""
    n, lead = x.shape[-1], x.shape[:-2]
    m = math.prod(lead)
    k = max(1, (LAPACK_INLINE_WORK - 1) // (5 * n ** 3))
    flat = jnp.reshape(x, (m, n, n))
    out = fn(flat) if m <= k else jax.lax.map(fn, flat, batch_size=k)  # a loop: one program size for any m
    return jax.tree.map(lambda o: jnp.reshape(o, lead + o.shape[1:]), out)


def _batched_in_pieces(fn):
    """``fn`` over (…, n, n) in pieces (:func:`_in_pieces`), also when vmapped: the vmapped axis
    leads the rule's input, so it is cut into pieces with the others."""
    @jax.custom_batching.custom_vmap
    def batched(x: jax.Array):
        return _in_pieces(fn, x)

    @batched.def_vmap
    def _rule(axis_size, in_batched, x):
        out = batched(x)
        return out, jax.tree.map(lambda _: True, out)

    return batched


_eigvalsh_batched = _batched_in_pieces(jnp.linalg.eigvalsh)
_eigh_batched = _batched_in_pieces(lambda x: tuple(jnp.linalg.eigh(x)))


@jax.custom_jvp
def eigvalsh(x: jax.Array) -> jax.Array:
    """Eigenvalues in ascending order of symmetric matrices (…, n, n), as ``jnp.linalg.eigvalsh``
    computes them (the same LAPACK call per matrix: the same bits), batched and vmapped alike,
    but handed to LAPACK in pieces that run on the calling thread (:data:`LAPACK_INLINE_WORK`).
    Differentiable: ``dλ_i = v_iᵀ dX v_i`` (first-order perturbation of a simple eigenvalue),
    the eigenvectors ``v`` from ``jnp.linalg.eigh`` in the same pieces."""
    return _eigvalsh_batched(x)


@eigvalsh.defjvp
def _eigvalsh_jvp(primals, tangents):
    (x,), (dx,) = primals, tangents
    _, v = _eigh_batched(x)
    return eigvalsh(x), jnp.einsum("...ji,...jk,...ki->...i", v, symmetrize(dx), v)
