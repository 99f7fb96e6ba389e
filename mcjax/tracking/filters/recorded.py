"""Run one distributed filter over recorded range–bearing data: :func:`run_filter`."""

from __future__ import annotations

from functools import partial

import jax
import jax.numpy as jnp
import numpy as np

from mcjax.tracking.filters import batched, native
from mcjax.tracking.filters.consensus import LOCAL, MODIFIED_ICF, FilterOptions, Measurements
from mcjax.tracking.filters.gaussian import first_step_model
from mcjax.tracking.filters.registry import get
from mcjax.tracking.filters.steps import filter_step, init_states, per_agent
from mcjax.tracking.models.sensors import range_bearing
from mcjax.tracking.numerics import require_x64, x64_enabled

_ANGLE_MASK_RB = (False, True)


def _as_array(name, value, dtype):
    try:
        arr = np.asarray(value, dtype=dtype)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name} must be a numeric array: {exc}") from None
    return arr


def _expect_shape(name, arr, expected, meaning):
    ok = arr.ndim == len(expected) and all(e is None or e == s for e, s in zip(expected, arr.shape))
    if not ok:
        shown = str(tuple(expected)).replace("None", "?")
        raise ValueError(f"{name} must have shape {shown} {meaning}; got {arr.shape}")


def _check_spd(name, m, allow_singular=False):
    if not np.all(np.isfinite(m)):
        raise ValueError(f"{name} must be finite")
    if not np.allclose(m, m.T, rtol=1e-9, atol=1e-12 * max(1.0, np.abs(m).max())):
        raise ValueError(f"{name} must be symmetric")
    eig = np.linalg.eigvalsh(m)
    tol = -1e-12 * max(1.0, np.abs(eig).max())
    if (allow_singular and eig.min() < tol) or (not allow_singular and eig.min() <= 0):
        what = "positive semi-definite" if allow_singular else "positive definite"
        raise ValueError(f"{name} must be a {what} covariance; smallest eigenvalue {eig.min():.3g}")


def _adjacency_bytes(a):
    """The checked adjacency as 0/1 bytes (the kernels read the graph as bytes: 1/8 of the
    memory); ValueError if it has an entry other than 0 and 1, is not symmetric or has a nonzero
    diagonal. One native pass over the CPU's threads where the native kernels are built (the
    numpy checks below cost ~15 ns per agent-step at B = 1,000, as much as a third of the local
    filter's run), else numpy."""
    if USE_NATIVE and a.size and native.available():
        a8, bad = native.adjacency_bytes(a)
        wrong_value, asymmetric, diagonal = bad & 1, bad & 2, bad & 4
    else:
        a8 = (a == 1).view(np.uint8)  # any other value than 0 and 1 (NaN, 2, …) then differs from a
        wrong_value = not np.array_equal(a8, a)
        asymmetric = not wrong_value and not np.array_equal(a8, np.swapaxes(a8, -1, -2))
        diagonal = not wrong_value and np.any(np.diagonal(a8, axis1=-2, axis2=-1))
    if wrong_value:
        raise ValueError("adjacency must contain only 0 and 1")
    if asymmetric:
        raise ValueError("adjacency must be symmetric (undirected comm links)")
    if diagonal:
        raise ValueError("adjacency must have a zero diagonal")
    return a8


@partial(jax.jit, static_argnames=("kind", "opts"))
def _run_one(kind, opts, z, sensors, adjacency, x0, P0, F, Q, R, kcf_epsilon):
    n = z.shape[1]
    R_inv = jnp.broadcast_to(jnp.linalg.inv(R), (n, 2, 2))
    angle_mask = jnp.array(_ANGLE_MASK_RB)
    states = init_states((kind,), x0, P0, n)

    def body(states, inputs):
        t, zt, st, at = inputs
        first = t == 0
        meas = Measurements(zt, st, at, R_inv)
        Ft, Qt = first_step_model(first, F, Q)
        new = filter_step((kind,), opts, range_bearing, angle_mask, states, meas, Ft, Qt, kcf_epsilon)
        out = per_agent(kind, new[0], n)
        return new, (out.x, out.P)

    ts = jnp.arange(z.shape[0])
    _, (xs, Ps) = jax.lax.scan(body, states, (ts, z, sensors, adjacency))
    return xs, Ps


#: The filters that also have hand-written batched kernels — the same equations as their records' steps, in
#: structure-of-arrays form (:mod:`mcjax.tracking.filters.batched`, :mod:`mcjax.tracking.filters.native`) —
#: by record (not by name), with the kernel's key. Any other filter runs its record's step under ``vmap``.
BATCHED_KERNELS = {LOCAL: "local", MODIFIED_ICF: "modified_icf"}


def batched_kernel(kind: str) -> str | None:
    """The key of the hand-written batched kernel of the filter ``kind`` (:data:`BATCHED_KERNELS`), or None."""
    return BATCHED_KERNELS.get(get(kind))
#: Split a batch over the CPU devices (one contiguous chunk each, then one copy into the result).
#: Off: on the shared 2-core VM the copy of the halves cost more than the second core gave
#: (docs/filter_speed.md, 2026-12-01: 1.5x slower at B = 10,000).
SPLIT_OVER_DEVICES = False
#: Run the local EKF and the modified ICF (float64) through the native kernels when the
#: machine can build them (:func:`mcjax.tracking.filters.native.available`; ``MCJAX_NATIVE=off`` turns
#: them off for the process). False: always the pure-JAX kernels of :mod:`.batched`.
USE_NATIVE = True
#: Fewest runs per CPU device when a batch is split over the devices.
MIN_RUNS_PER_DEVICE = 64


def _run_batched(kind, opts, z, s, a, consts, dt):
    """The local EKF / modified ICF: in float64, through the native kernels where they are
    built (:mod:`.native`, C-ordered results); otherwise through :func:`batched.run_batch` on
    one CPU device, or with ``SPLIT_OVER_DEVICES`` the batch split into contiguous chunks over
    the devices (every run is computed independently, so the split does not change any bit).
    ``z``, ``s``, ``a`` are numpy or device arrays. Returns numpy arrays with ``z``'s leading
    axes: from the pure-JAX kernels on one device, read-only views of their batch-last outputs
    (no copy); split, one copy into a batch-last result."""
    single = z.ndim == 3
    if single:
        z, s, a = z[None], s[None], a[None]
    B = z.shape[0]
    native_ok = dt == "float64" and jax.config.jax_enable_x64  # the C++ kernels take float64 buffers only
    if USE_NATIVE and native_ok and (kind == "local" or z.shape[2] <= native.MAX_AGENTS) and native.available():
        xs, Ps = native.run_batch(kind, opts, z, s, a, *consts)
        return (xs[0], Ps[0]) if single else (xs, Ps)
    if B == 1:  # XLA compiles a batch of one differently (last-bit changes): run two copies
        xs, Ps = _run_batched(kind, opts, *(np.concatenate([v, v]) for v in (z, s, a)), consts, dt)
        return (xs[0], Ps[0]) if single else (xs[:1], Ps[:1])
    devices = jax.local_devices() if SPLIT_OVER_DEVICES else jax.local_devices()[:1]
    k = max(1, min(len(devices), B // MIN_RUNS_PER_DEVICE))
    bounds = np.linspace(0, B, k + 1).astype(int)
    pending = []
    for d, lo, hi in zip(devices, bounds[:-1], bounds[1:]):
        chunk = (z, s, None if kind == "local" else a) if k == 1 else (
            np.asarray(z[lo:hi]), np.asarray(s[lo:hi]), None if kind == "local" else np.asarray(a[lo:hi]))
        args = [None if v is None else jax.device_put(v, d) for v in chunk]
        cst = [jax.device_put(np.asarray(v), d) for v in consts]
        pending.append(batched.run_batch(kind, opts, range_bearing, _ANGLE_MASK_RB, *args, *cst, dtype=dt))
    if k == 1:
        xs, Ps = (np.asarray(v) for v in pending[0])
    else:
        xs = np.concatenate([np.asarray(p[0]) for p in pending], axis=-1)
        Ps = np.concatenate([np.asarray(p[1]) for p in pending], axis=-1)
    xs, Ps = np.moveaxis(xs, -1, 0), np.moveaxis(Ps, -1, 0)
    return (xs[0], Ps[0]) if single else (xs, Ps)


def run_filter(
    kind: str,
    *,
    measurements,
    sensor_positions,
    adjacency,
    x0,
    P0,
    F,
    Q,
    R,
    consensus_steps: int = 1,
    dtype: str = "float64",
    weights: str = "eq11",
    contribution: str = "component",
    icf_variant: str = "contributions",
    kcf_gain: str = "gamma_M",
    kcf_epsilon: float = 0.1,
):
    """Run one filter over recorded range–bearing data; returns ``(estimates, covariances)``.

    Parameters
    ----------
    kind : a filter's name (``"cif", "icf", "modified_icf", "kcf", "local", "ci", "hcmci"``, docs/equations.md),
        an installed plugin's, or a reference ``"file.py:ATTRIBUTE"`` (:func:`mcjax.tracking.filters.registry.get`).
    measurements : (T, n, 2) ``[range m, bearing rad]``, NaN where agent i has no
        measurement at step t. A leading run axis (B, T, n, 2) runs B runs in one batch.
    sensor_positions : (T, n, 2) sensor positions in metres (same leading axes).
    adjacency : (T, n, n) 0/1 comm graph of each step, symmetric, zero diagonal.
    x0, P0 : (4,), (4, 4) prior of ``[x, ẋ, y, ẏ]`` at the first measurement time:
        step 0 updates without predicting, later steps predict then update.
    F, Q : (4, 4) transition and *state* process-noise covariance (``G Qₐ Gᵀ``).
    R : (2, 2) measurement noise covariance (m², rad²).
    consensus_steps : L, consensus iterations per step (ICF, modified ICF).
    dtype : ``"float64"`` (default) or ``"float32"``.
    weights, contribution, icf_variant, kcf_gain : see :class:`FilterOptions`.
    kcf_epsilon : ε of the KCF consensus gain.

    Returns numpy arrays: estimates (…, T, n, 4) and covariances (…, T, n, 4, 4); the CIF
    reports its single estimate for every agent. They are read-only. The local filter and the
    modified ICF run in float64 in native kernels where a C++ compiler exists (:mod:`.native`;
    C-ordered results), else in the pure-JAX kernels (:mod:`.batched`), whose results are views
    of batch-last buffers (``numpy.ascontiguousarray`` makes a C-ordered copy). Every bad
    argument raises ValueError naming it.
    """
    try:
        kernel = batched_kernel(kind)
    except ValueError as exc:
        raise ValueError(f"kind: {exc}") from None
    if dtype not in ("float64", "float32"):
        raise ValueError(f"dtype must be 'float64' or 'float32'; got {dtype!r}")
    if dtype == "float64":
        require_x64("mcjax.tracking.filters.run_filter(dtype='float64')")
        if not x64_enabled():  # computes in what JAX offers, as the one warning above said (no more from JAX)
            dtype = "float32"
    if not isinstance(consensus_steps, (int, np.integer)) or isinstance(consensus_steps, bool) or consensus_steps < 0:
        raise ValueError(f"consensus_steps must be an integer >= 0; got {consensus_steps!r}")
    opts = FilterOptions(int(consensus_steps), weights, contribution, icf_variant, kcf_gain)

    z = _as_array("measurements", measurements, np.float64)
    if z.ndim not in (3, 4) or z.shape[-1] != 2:
        raise ValueError(f"measurements must have shape (T, n, 2) (or (B, T, n, 2)) "
                         f"[range, bearing] per step and agent; got {z.shape}")
    lead = z.shape[:-3]
    T, n = z.shape[-3], z.shape[-2]
    if T < 1 or n < 1:
        raise ValueError(f"measurements must have at least one step and one agent; got {z.shape}")
    s = _as_array("sensor_positions", sensor_positions, np.float64)
    _expect_shape("sensor_positions", s, (*lead, T, n, 2), "(one (x, y) per step and agent, like measurements)")
    a = _as_array("adjacency", adjacency, np.float64)
    _expect_shape("adjacency", a, (*lead, T, n, n), "(one n×n 0/1 matrix per step)")
    if not np.all(np.isfinite(s)):
        raise ValueError("sensor_positions must be finite")
    a = _adjacency_bytes(a)
    x0a = _as_array("x0", x0, np.float64)
    _expect_shape("x0", x0a, (4,), "([x, ẋ, y, ẏ])")
    if not np.all(np.isfinite(x0a)):
        raise ValueError("x0 must be finite")
    P0a = _as_array("P0", P0, np.float64)
    _expect_shape("P0", P0a, (4, 4), "(covariance of x0)")
    _check_spd("P0", P0a)
    Fa = _as_array("F", F, np.float64)
    _expect_shape("F", Fa, (4, 4), "(state transition)")
    if not np.all(np.isfinite(Fa)):
        raise ValueError("F must be finite")
    Qa = _as_array("Q", Q, np.float64)
    _expect_shape("Q", Qa, (4, 4), "(state process-noise covariance)")
    _check_spd("Q", Qa, allow_singular=True)
    Ra = _as_array("R", R, np.float64)
    _expect_shape("R", Ra, (2, 2), "(range–bearing noise covariance)")
    _check_spd("R", Ra)
    if (isinstance(kcf_epsilon, (bool, np.bool_)) or not isinstance(kcf_epsilon, (int, float, np.integer, np.floating))
            or not np.isfinite(kcf_epsilon) or kcf_epsilon < 0):
        raise ValueError(f"kcf_epsilon must be a finite number >= 0; got {kcf_epsilon!r}")

    dt = jnp.float64 if dtype == "float64" else jnp.float32
    if kernel is not None:
        return _run_batched(kernel, opts, z, s, a, (x0a, P0a, Fa, Qa, Ra), dtype)
    args = [jnp.asarray(v, dt) for v in (z, s, a)]
    consts = [jnp.asarray(v, dt) for v in (x0a, P0a, Fa, Qa, Ra, kcf_epsilon)]
    fn = partial(_run_one, kind, opts)
    for _ in lead:  # one vmap per leading run axis (measured faster than lax.map blocks)
        fn = jax.vmap(fn, in_axes=(0, 0, 0) + (None,) * len(consts))
    xs, Ps = fn(*args, *consts)
    return np.asarray(xs), np.asarray(Ps)
