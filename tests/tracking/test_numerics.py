"""mcjax.tracking.numerics against independent references (numpy.linalg, math, closed forms)."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from mcjax.tracking.numerics import (
    LAPACK_INLINE_WORK,
    UNROLL_MAX,
    eigvalsh,
    matmul,
    matvec,
    quad,
    safe_norm,
    softmax_value,
    softmin,
    spd_inverse,
    spd_logdet,
    spd_solve,
    symmetrize,
    wrap_angle,
)


def _random_spd(rng, shape, n, cond_floor=0.5):
    """Random SPD matrices (shape + (n, n)) built as A Aᵀ + c I, eigenvalues ≥ cond_floor."""
    a = rng.normal(size=tuple(shape) + (n, n))
    return a @ np.swapaxes(a, -1, -2) + cond_floor * np.eye(n)


# --------------------------------------------------------------------------- SPD kernels

SIZES = list(range(1, 9))  # covers the unrolled path (≤ UNROLL_MAX) and the jnp.linalg fallback
BATCH = (3, 7)  # one batch shape everywhere: eager op compilations are shared between tests


def test_sizes_cover_both_paths():
    assert min(SIZES) <= UNROLL_MAX < max(SIZES)


def _all3(a, b):
    return spd_inverse(a), spd_solve(a, b), spd_logdet(a)


# One jitted entry point, always called with batch shape BATCH: a single XLA compilation per n
# is shared by every SPD test below (compiling the unrolled kernels dominates the run time).
_spd_all = jax.jit(_all3)


def _spd(a, b=None):
    a = np.asarray(a, float)
    if b is None:
        b = np.ones(a.shape[:-1])
    return tuple(np.asarray(o) for o in _spd_all(jnp.asarray(a), jnp.asarray(np.asarray(b, float))))


@pytest.mark.parametrize("n", SIZES)
def test_spd_kernels_match_numpy(n):
    """Batched (3, 7, n, n) input, under jit."""
    rng = np.random.default_rng(n)
    a = _random_spd(rng, BATCH, n)
    b = rng.normal(size=BATCH + (n,))
    inv, sol, ld = _spd(a, b)
    assert inv.shape == BATCH + (n, n) and sol.shape == BATCH + (n,) and ld.shape == BATCH
    np.testing.assert_allclose(inv, np.linalg.inv(a), rtol=1e-9, atol=1e-11)
    np.testing.assert_allclose(a @ inv, np.broadcast_to(np.eye(n), a.shape), atol=1e-9)
    np.testing.assert_allclose(sol, np.linalg.solve(a, b[..., None])[..., 0], rtol=1e-9, atol=1e-10)
    sign, ref_ld = np.linalg.slogdet(a)
    assert np.all(sign == 1.0)
    np.testing.assert_allclose(ld, ref_ld, rtol=1e-11, atol=1e-11)


def test_spd_known_values():
    # [[4, 2], [2, 3]]: det 8, inverse [[3, −2], [−2, 4]]/8;  diag(2, 3, 5): log det = log 30
    a = np.broadcast_to(np.array([[4.0, 2.0], [2.0, 3.0]]), BATCH + (2, 2))
    inv, sol, ld = _spd(a)
    np.testing.assert_allclose(ld, np.full(BATCH, math.log(8.0)), rtol=1e-14)
    np.testing.assert_allclose(inv, np.broadcast_to(np.array([[3.0, -2.0], [-2.0, 4.0]]) / 8.0, a.shape),
                               rtol=1e-14)
    np.testing.assert_allclose(sol, np.broadcast_to([1.0 / 8.0, 2.0 / 8.0], BATCH + (2,)), rtol=1e-14)
    _, _, ld3 = _spd(np.broadcast_to(np.diag([2.0, 3.0, 5.0]), BATCH + (3, 3)))
    np.testing.assert_allclose(ld3, np.full(BATCH, math.log(30.0)), rtol=1e-14)


@pytest.mark.parametrize("n", [2, 7])
def test_spd_under_vmap_and_jit(n):
    """jit(vmap(vmap(·))): the kernels are traced on single, unbatched (n, n) matrices."""
    rng = np.random.default_rng(400 + n)
    a = _random_spd(rng, BATCH, n)
    b = rng.normal(size=BATCH + (n,))
    inv, sol, ld = jax.jit(jax.vmap(jax.vmap(_all3)))(jnp.asarray(a), jnp.asarray(b))
    assert inv.shape == BATCH + (n, n)
    np.testing.assert_allclose(inv, np.linalg.inv(a), rtol=1e-9, atol=1e-11)
    np.testing.assert_allclose(sol, np.linalg.solve(a, b[..., None])[..., 0], rtol=1e-9, atol=1e-10)
    np.testing.assert_allclose(ld, np.linalg.slogdet(a)[1], rtol=1e-11, atol=1e-11)


def _non_spd_cases(n):
    """Symmetric matrices that are NOT positive definite (different failing pivots)."""
    cases = [-np.eye(n)]  # negative definite: the first pivot fails
    if n >= 2:
        last = np.eye(n)
        last[n - 1, n - 1] = -1.0  # only the last pivot fails
        cases.append(last)
        indef = np.eye(n)
        indef[0, 1] = indef[1, 0] = 2.0  # positive diagonal, indefinite (eigenvalue −1)
        cases.append(indef)
        singular = np.ones((n, n))  # PSD but singular: the second pivot is exactly 0
        cases.append(singular)
    return cases


@pytest.mark.parametrize("n", SIZES)
def test_non_spd_gives_nan_and_stays_local(n):
    """A non-SPD matrix in a batch gives NaN (never a silently wrong number); its batch
    neighbours are unaffected."""
    rng = np.random.default_rng(500 + n)
    a = _random_spd(rng, BATCH, n)
    bad_idx = [(0, 1), (1, 2), (2, 3), (2, 6)]
    cases = _non_spd_cases(n)
    for idx, m in zip(bad_idx, cases):
        assert np.min(np.linalg.eigvalsh(m)) <= 1e-12  # the case really is not SPD
        a[idx] = m
    bad = np.zeros(BATCH, bool)
    for idx in bad_idx[: len(cases)]:
        bad[idx] = True
    inv, sol, ld = _spd(a)
    for k, idx in enumerate(bad_idx[: len(cases)]):
        assert not np.any(np.isfinite(inv[idx])), (idx, inv[idx])
        assert not np.any(np.isfinite(sol[idx])), (idx, sol[idx])
        if k < 3:  # strictly not positive semi-definite: NaN
            assert np.all(np.isnan(inv[idx])) and np.all(np.isnan(sol[idx])) and np.isnan(ld[idx])
        else:  # singular PSD: log det may be −inf (log 0) or NaN, never a finite number
            assert not np.isfinite(ld[idx])
    np.testing.assert_allclose(inv[~bad], np.linalg.inv(a[~bad]), rtol=1e-9, atol=1e-11)
    np.testing.assert_allclose(sol[~bad], np.linalg.solve(a[~bad], np.ones((bad.size - bad.sum(), n, 1)))[..., 0],
                               rtol=1e-9, atol=1e-10)
    np.testing.assert_allclose(ld[~bad], np.linalg.slogdet(a[~bad])[1], rtol=1e-11, atol=1e-11)


# --------------------------------------------------------------------------- products
# (every kernel below is called through jax.jit: eager dispatch compiles each primitive
#  separately and is several times slower to run for these tiny inputs)


def test_matmul_matvec_quad_match_numpy():
    rng = np.random.default_rng(1)
    a = rng.normal(size=(3, 1, 4, 5))
    b = rng.normal(size=(2, 5, 3))
    v = rng.normal(size=(2, 5))
    m = rng.normal(size=(6, 3, 4))
    p = rng.normal(size=(6, 4, 4))
    mm, mv, q = jax.jit(lambda a, b, v, m, p: (matmul(a, b), matvec(a, v), quad(m, p)))(
        *(jnp.asarray(t) for t in (a, b, v, m, p)))
    np.testing.assert_allclose(mm, a @ b, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(mv, np.einsum("...ij,...j->...i", a, v), rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(q, m @ p @ np.swapaxes(m, -1, -2), rtol=1e-12, atol=1e-12)
    assert mm.shape == (3, 2, 4, 3) and mv.shape == (3, 2, 4) and q.shape == (6, 3, 3)


def test_matmul_known_small():
    a = jnp.array([[1.0, 2.0], [3.0, 4.0]])
    b = jnp.array([[5.0, 6.0], [7.0, 8.0]])
    mm, mv = jax.jit(lambda a, b: (matmul(a, b), matvec(a, b[0] - b[1] + 1.0)))(a, b)
    np.testing.assert_array_equal(mm, [[19.0, 22.0], [43.0, 50.0]])
    np.testing.assert_array_equal(mv, [-3.0, -7.0])  # a @ [−1, −1]


# --------------------------------------------------------------------------- symmetrize


def test_symmetrize():
    rng = np.random.default_rng(2)
    a = rng.normal(size=(2, 3, 5, 5))
    a[1] = a[0] + np.swapaxes(a[0], -1, -2)  # second half: already symmetric
    s = np.asarray(jax.jit(symmetrize)(jnp.asarray(a)))
    np.testing.assert_allclose(s, 0.5 * (a + np.swapaxes(a, -1, -2)), rtol=1e-15, atol=1e-15)
    np.testing.assert_array_equal(s, np.swapaxes(s, -1, -2))
    np.testing.assert_allclose(s[1], a[1], rtol=1e-15, atol=1e-15)  # symmetric input unchanged


# --------------------------------------------------------------------------- wrap_angle

_wrap = jax.jit(wrap_angle)


def _ref_wrap(a):
    """Reference wrap to (−π, π] via the IEEE remainder."""
    r = math.remainder(a, 2.0 * math.pi)
    return math.pi if r <= -math.pi else r


def test_wrap_angle_special_values():
    pi = math.pi
    cases = {pi: pi, -pi: pi, 3 * pi: pi, -3 * pi: pi, 5 * pi: pi, 0.0: 0.0, 2 * pi: 0.0,
             -2 * pi: 0.0, pi / 2: pi / 2, -pi / 2: -pi / 2, 1.5 * pi: -0.5 * pi, -1.5 * pi: 0.5 * pi}
    got = np.asarray(_wrap(jnp.array(list(cases))))
    np.testing.assert_allclose(got, list(cases.values()), rtol=0, atol=1e-12)
    # exactly ±π (and the float 3π) map to +π: the interval is open at −π
    assert got[0] == pi and got[1] == pi and got[2] == pi
    assert np.all(got > -pi) and np.all(got <= pi)


def test_wrap_angle_range_and_reference():
    rng = np.random.default_rng(3)
    a = np.concatenate([rng.uniform(-50, 50, 2000), rng.uniform(-3.0, 3.0, 100),
                        [1e6, -1e6, 12345.678, -98765.4321, np.nextafter(-np.pi, 0.0),
                         np.nextafter(np.pi, 4.0), np.nextafter(-np.pi, -4.0), 1e-300, -1e-300]])
    got = np.asarray(_wrap(jnp.asarray(a)))
    assert np.all(got > -np.pi) and np.all(got <= np.pi)
    ref = np.array([_ref_wrap(v) for v in a])
    # circular difference (both may legitimately sit on either side of the ±π seam)
    diff = np.angle(np.exp(1j * (got - ref)))
    assert np.max(np.abs(diff)) < 1e-9
    # congruent to the input modulo 2π
    k = (a - got) / (2 * np.pi)
    np.testing.assert_allclose(k, np.round(k), atol=1e-9)
    # angles already inside (−π, π) are untouched
    np.testing.assert_allclose(got[2000:2100], a[2000:2100], rtol=0, atol=1e-15)


def test_wrap_angle_float32_range():
    a = jnp.asarray(np.array([np.pi, -np.pi, 3 * np.pi, -3 * np.pi, 100.0, -100.0], np.float32))
    got = np.asarray(_wrap(a))
    assert got.dtype == np.float32
    pi32 = np.float32(np.pi)
    assert np.all(got > -pi32) and np.all(got <= pi32)
    # float32(±3π) is not exactly ±3π, so the result may sit just inside −π: compare on the circle
    np.testing.assert_allclose(np.angle(np.exp(1j * (got[:4].astype(float) - np.pi))), 0.0, atol=1e-6)
    np.testing.assert_allclose(got[:2], pi32)  # float32 ±π itself → +π


# --------------------------------------------------------------------------- safe_norm


def test_safe_norm_matches_numpy():
    rng = np.random.default_rng(4)
    x = rng.normal(size=(5, 6, 3)) * 10.0
    x[0, 0] = 0.0
    x[0, 1] = [3.0, 4.0, 0.0]
    n_last, n_first = jax.jit(lambda x: (safe_norm(x), safe_norm(x, axis=0)))(jnp.asarray(x))
    np.testing.assert_allclose(n_last, np.linalg.norm(x, axis=-1), rtol=1e-14)
    np.testing.assert_allclose(n_first, np.linalg.norm(x, axis=0), rtol=1e-14)
    assert n_last[0, 0] == 0.0 and n_last[0, 1] == 5.0


def test_safe_norm_gradient():
    # batch: origin, a 3-4-0 vector, a random one; grad of the sum = per-row gradients
    x = np.array([[0.0, 0.0, 0.0], [3.0, 4.0, 0.0], [1.0, -2.0, 2.0]])
    g = np.asarray(jax.jit(jax.grad(lambda x: jnp.sum(safe_norm(x))))(jnp.asarray(x)))
    assert np.all(np.isfinite(g))
    np.testing.assert_array_equal(g[0], np.zeros(3))  # zero at the origin
    np.testing.assert_allclose(g[1:], x[1:] / np.linalg.norm(x[1:], axis=-1, keepdims=True), rtol=1e-14)
    j0 = np.asarray(jax.jit(jax.jacfwd(safe_norm))(jnp.zeros(3)))
    np.testing.assert_array_equal(j0, np.zeros(3))  # forward mode too


# --------------------------------------------------------------------------- softmin / softmax

_soft = jax.jit(lambda x, t: (softmin(x, t), softmax_value(x, t)))


def test_softmin_softmax_bounds_and_limit():
    rng = np.random.default_rng(5)
    x = rng.normal(size=(4, 7)) * 3.0
    n = x.shape[-1]
    mn, mx = x.min(-1), x.max(-1)
    prev_gap_min = prev_gap_max = np.inf
    tol = 1e-12 * (1 + np.abs(x).max())
    for t in [10.0, 1.0, 0.1, 1e-2, 1e-4, 1e-8]:
        smin, smax = (np.asarray(o) for o in _soft(jnp.asarray(x), t))
        # min − T log n ≤ softmin ≤ min ;  max ≤ softmax ≤ max + T log n
        assert np.all(smin <= mn + tol) and np.all(smin >= mn - t * math.log(n) - tol)
        assert np.all(smax >= mx - tol) and np.all(smax <= mx + t * math.log(n) + tol)
        gap_min, gap_max = np.max(mn - smin), np.max(smax - mx)
        assert gap_min <= prev_gap_min + tol and gap_max <= prev_gap_max + tol  # shrinks with T
        prev_gap_min, prev_gap_max = gap_min, gap_max
    np.testing.assert_allclose(smin, mn, atol=1e-7)
    np.testing.assert_allclose(smax, mx, atol=1e-7)
    # independent closed form at a moderate temperature
    t = 0.7
    smin, smax = _soft(jnp.asarray(x), t)
    np.testing.assert_allclose(smin, -t * np.log(np.sum(np.exp(-x / t), -1)), rtol=1e-13)
    np.testing.assert_allclose(smax, t * np.log(np.sum(np.exp(x / t), -1)), rtol=1e-13)


def test_softmin_closed_form_and_axis():
    # equal entries: softmin = x − T log n exactly (row 0 of the batch)
    y = np.random.default_rng(6).normal(size=(4, 7))
    y[0] = 2.0
    smin, smax = _soft(jnp.asarray(y), 0.5)
    np.testing.assert_allclose(smin[0], 2.0 - 0.5 * math.log(7), rtol=1e-14)
    np.testing.assert_allclose(smax[0], 2.0 + 0.5 * math.log(7), rtol=1e-14)
    ref = -0.3 * np.log(np.sum(np.exp(-y / 0.3), axis=0))
    np.testing.assert_allclose(jax.jit(lambda y: softmin(y, 0.3, axis=0))(jnp.asarray(y)), ref, rtol=1e-13)


def _fresh(code: str, **env) -> list[str]:
    import os
    import subprocess
    import sys

    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300,
                       env={**os.environ, **env})
    assert r.returncode == 0, r.stderr
    return r.stdout.strip().splitlines()


def test_importing_mcjax_sets_nothing_and_a_library_call_without_64_bit_mode_says_so_once():
    """No process-wide JAX setting is an import side effect: ``import mcjax`` imports no JAX,
    importing the computing modules leaves 64-bit mode off, and a library function called
    without it warns once (float32 then). mcjax.configure() switches it on; once JAX's backend
    runs, the CPU device count stays as it is."""
    out = _fresh(
        "import sys, warnings\n"
        "import mcjax\n"
        "print('jax' in sys.modules)\n"
        "import jax, numpy as np\n"
        "import mcjax.engine, mcjax.tracking.graph, mcjax.tracking.numerics\n"
        "print(jax.config.jax_enable_x64)\n"
        "a = np.ones((4, 4)) - np.eye(4)\n"
        "with warnings.catch_warnings(record=True) as caught:\n"
        "    warnings.simplefilter('always')\n"
        "    print(mcjax.tracking.graph.algebraic_connectivity(a).dtype, mcjax.tracking.graph.laplacian(a).dtype)\n"
        "print(len(caught), caught[0].category.__name__, caught[0].message)\n"
        "mcjax.configure()\n"
        "mcjax.configure()\n"
        "print(jax.config.jax_enable_x64, len(jax.devices()), mcjax.tracking.graph.algebraic_connectivity(a).dtype)\n",
        MCJAX_CPU_DEVICES="3")
    assert out[:3] == ["False", "False", "float32 float32"]
    assert out[3].startswith("1 UserWarning mcjax.tracking.graph: JAX's 64-bit mode is off") and "mcjax.configure()" in out[3]
    assert out[4] == "True 1 float64"  # the backend already ran (float32): its one device kept


def test_configure_and_the_engines_entry_points_set_64_bit_mode_and_the_cpu_devices():
    """mcjax.configure() before JAX starts: 64-bit mode and MCJAX_CPU_DEVICES devices; the
    engine's entry points call it themselves."""
    for call in ("import mcjax; mcjax.configure()", "from mcjax import engine; engine.devices()"):
        out = _fresh(f"{call}\nimport jax\nfrom mcjax import runtime\n"
                     "print(jax.config.jax_enable_x64, len(jax.devices()), runtime.settings()['x64'])",
                     MCJAX_CPU_DEVICES="3")
        assert out == ["True 3 True"], call


# --------------------------------------------------------------------------- eigvalsh in pieces


def _random_symmetric(rng, shape, n):
    a = rng.normal(size=tuple(shape) + (n, n))
    return a + np.swapaxes(a, -1, -2)


@pytest.mark.parametrize("n", [3, 12, 40])  # one call, pieces of several matrices, one matrix per call
def test_eigvalsh_in_pieces_is_numpys_and_jaxs_to_the_bit(n):
    assert (n == 3) == (4 * 30 * 5 * n**3 < LAPACK_INLINE_WORK) and 5 * 40**3 >= LAPACK_INLINE_WORK
    a = _random_symmetric(np.random.default_rng(n), (4, 30), n)
    got = np.asarray(jax.jit(jax.vmap(jax.vmap(eigvalsh)))(a))
    ref = np.linalg.eigvalsh(a)
    np.testing.assert_allclose(got, ref, rtol=0, atol=1e-12 * np.abs(ref).max())
    assert (got == np.asarray(jax.jit(jax.vmap(jax.vmap(jnp.linalg.eigvalsh)))(a))).all()
    assert (np.asarray(eigvalsh(a)) == got).all()  # leading axes without vmap


def test_eigvalsh_derivatives_are_central_differences():
    """dλ_i/dt of X + tD against central differences (simple eigenvalues); grad = jvp's adjoint."""
    rng = np.random.default_rng(7)
    x, d = _random_symmetric(rng, (5,), 12), _random_symmetric(rng, (5,), 12)
    _, jvp = jax.jvp(jax.vmap(eigvalsh), (x,), (d,))
    h = 1e-6
    fd = (np.linalg.eigvalsh(x + h * d) - np.linalg.eigvalsh(x - h * d)) / (2 * h)
    np.testing.assert_allclose(jvp, fd, rtol=0, atol=1e-6 * np.abs(fd).max())
    w = rng.normal(size=(5, 12))
    g = jax.grad(lambda y: jnp.sum(w * jax.vmap(eigvalsh)(y)))(x)
    np.testing.assert_allclose(np.sum(g * d), np.sum(w * np.asarray(jvp)), rtol=1e-10)


def test_eigvalsh_on_every_device_at_once_does_not_hang(tmp_path):
    """Every CPU device runs a program of batched eigenvalues at once: with ``jnp.linalg.eigvalsh``
    this hangs on a 2-core machine (jaxlib hands the batch to pool threads the devices occupy;
    measured 2026-12-04); in pieces it completes, the same bits on every device."""
    import subprocess
    import sys

    script = tmp_path / "every_device.py"
    script.write_text("""
import os, threading
import jax, numpy as np
jax.config.update("jax_num_cpu_devices", max(2, os.cpu_count() or 1))
jax.config.update("jax_enable_x64", True)
from mcjax.tracking.numerics import eigvalsh

def program(x):
    def step(c, _):
        lam = jax.vmap(eigvalsh)(c)
        return c + 1e-3 * lam[:, :1, None], lam[:, 1]
    return jax.lax.scan(step, x, None, length=20)[1]

f = jax.jit(program)
a = np.random.default_rng(0).normal(size=(100, 20, 20))
a = a + np.swapaxes(a, -1, -2)
xs = [jax.device_put(a, d) for d in jax.devices()]
first = [np.asarray(f(x)) for x in xs]
def work(x):
    for _ in range(20):
        np.asarray(f(x))
threads = [threading.Thread(target=work, args=(x,)) for x in xs]
[t.start() for t in threads]
[t.join() for t in threads]
print(len(xs), all((o == first[0]).all() for o in first))
""")
    out = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, timeout=240, check=True)
    devices, same = out.stdout.split()
    assert int(devices) >= 2 and same == "True"
