"""Chen & Lu 2013's relaxation switch (``wind_formation``, ``step(..., temperatures)``): the tune
loss's gradient against central differences, the smooth system's approach to the exact one as
the temperatures shrink, the smooth record through ``summary`` and ``series``, and the smooth
pieces against their definitions (eq. 15's soft cap, eq. 13's path point across the join).

The set-up of the closed-loop tests puts the formation's centre ~1 km from the path (the
paper's start moved 8,375 m south) so that eq. 13's "the path within l" ramp is partly on in
the third step, and the comm radius at 3 km so that the 3,200 m side is a partial soft link;
eq. 15's cap is on in almost every step (the UAVs fly at l). Float64 throughout.
"""

from __future__ import annotations

import textwrap
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from mcjax import engine, tune
from mcjax.scenarios import chen2013 as S
from mcjax.scenarios.chen2013 import guidance

ROOT = Path(__file__).resolve().parents[3]
START = S.PAPER_START + np.array([0.0, -8375.0])
COMM = 3000.0

#: The gradient program: 6 steps (the join ramp is partly on at step 3), the kcf only, 2 runs;
#: the tune spec's two Params, and the comm radius (the soft links' derivative).
SPEC = f"""
base = "{(ROOT / 'configs' / 'chen2013.toml').as_posix()}"
[config]
n_steps = 6
filters = ["kcf"]
[params]
comm_radius = {COMM}
start = {START.tolist()}
[tune]
steps = 1
train_seeds = 2
train_base_seed = 1
heldout_seeds = 3
heldout_base_seed = 0
[tune.params.eta]
low = 1e-3
high = 0.1
scale = "log"
[tune.params.sigma_wind_process]
low = 0.05
high = 5.0
scale = "log"
[tune.params.comm_radius]
low = 1e3
high = 1e4
scale = "log"
[tune.loss]
filter = "kcf"
"""


def test_tune_loss_gradient_matches_central_differences_at_three_points(tmp_path):
    """d loss / d z (forward mode, the tune's own program: ``run_loss`` under ``jax.jacfwd``)
    against central differences of the same loss (same seeds) at three points drawn inside the
    bounds (numpy seed 2013, 10–90 % of each bound's sigmoid), to 1e-4 relative (of the entry,
    or of 1 % of the gradient's norm for a near-zero entry). Step h = 1e-3 in z: a scan over
    h = 1e-1 … 1e-6 at these points (the suite's XLA flags) gave relative differences falling
    as h², at most 1.0e-2, 1.0e-4, 1.0e-6 at h = 1e-1, 1e-2, 1e-3 (the quotient's own
    truncation error: the smooth system is smooth there), down to a round-off floor of
    1e-11 – 2e-8 from h = 1e-4; at 1e-3 the truncation is a hundred times inside the tolerance
    and the round-off far below it. Checked to fail: with the bisection's own derivative of
    eq. 13's root (no implicit-function step) the differences are 1.6e-3 – 1.6e-2 at each
    point; with the exact 0/1 links the comm radius carries no gradient."""
    p = tmp_path / "tune.toml"
    p.write_text(textwrap.dedent(SPEC))
    spec = tune.load_tune_spec(p)
    ev = tune.Evaluator(spec)
    u = np.random.default_rng(2013).uniform(0.1, 0.9, (3, len(spec.bounds)))
    h = 1e-3
    for z in np.log(u / (1.0 - u)):
        e = ev(z)
        assert e.dropped == 0 and np.all(np.isfinite(e.grad))
        fd = np.array([(ev(z + h * d).loss - ev(z - h * d).loss) / (2 * h) for d in np.eye(len(z))])
        scale = np.linalg.norm(e.grad)
        assert np.all(np.abs(e.grad) > 1e-4 * scale), (z, e.grad)  # every Param carries gradient
        for name, g, f in zip(spec.names, e.grad, fd):
            assert abs(g - f) <= 1e-4 * max(abs(g), 1e-2 * scale), (name, z, g, f)


# ------------------------------------------------------------------ the smooth system against the exact one

CFG = S.Config(n_steps=30, filters=("kcf", "cif"), faults="on")  # faults compiled in: their rates are Params
RUNS = 3


def _params(**values):
    p = S.default_params(CFG)._replace(start=jnp.asarray(START), comm_radius=jnp.asarray(COMM),
                                       **{k: jnp.asarray(v, jnp.float64) for k, v in values.items()})
    return jax.tree.map(lambda a: jnp.broadcast_to(jnp.asarray(a), (RUNS,) + jnp.shape(a)), p)


def _outputs(params, keys, temperatures):
    recs = engine.simulate(S.SCENARIO, CFG, params, keys, records=True, temperatures=temperatures)
    return (recs, jax.vmap(lambda r, p: S.reduce(CFG, r, p))(recs, params),
            jax.vmap(lambda r, p: S.timeseries(CFG, r, p))(recs, params))


@pytest.fixture(scope="module")
def programs():
    """The exact and the smooth system (temperatures an argument: one program for every level)."""
    return jax.jit(lambda p, k: _outputs(p, k, None)), jax.jit(_outputs)


def _level(factor):
    return S.Temperatures(*(jnp.asarray(factor * t) for t in S.Temperatures()))


KEYS = engine.run_keys(7, np.arange(RUNS))


def test_smooth_system_approaches_the_exact_one_as_the_temperatures_shrink(programs):
    """At the default temperatures and at 1/10 and 1/100 of them, the largest difference of any
    UAV's position and of each run's and filter's RMS wind error (the ``error`` role) from the
    exact system falls strictly from level to level, and at the last (links 10 m, path 1 m,
    cap 0.1 m) the positions are within 1 m and the RMSE within 1e-3 m/s. Why it must: each
    smooth piece equals its exact one outside a band of its temperature's width (the path's
    ramps exactly; links and the cap's kink exponentially), and inside it differs by at most
    that width (the soft cap by ≤ T·log 2 per step), so over 30 steps of a stable formation the
    gap shrinks with the temperature. At the default level the join ramp is partly on (a weight
    strictly inside (0, 1)): the set-up exercises it."""
    exact, smooth = programs
    p = _params()
    ex = exact(p, KEYS)
    pos, rmse = [], []
    for k, f in enumerate((1.0, 0.1, 0.01)):
        sm = smooth(p, KEYS, _level(f))
        if k == 0:
            o = np.asarray(sm[0].on_path)
            assert np.any((o > 0.01) & (o < 0.99)), o
        pos.append(float(jnp.max(jnp.abs(sm[0].positions - ex[0].positions))))
        rmse.append(float(jnp.max(jnp.abs(sm[1]["rmse"] - ex[1]["rmse"]))))
    assert pos[0] > pos[1] > pos[2] and rmse[0] > rmse[1] > rmse[2], (pos, rmse)
    assert pos[2] < 1.0 and rmse[2] < 1e-3, (pos, rmse)


def test_smooth_record_reduces_to_finite_outputs_with_faults(programs):
    """With temperatures on and faults drawn (lost links, dropouts, lost UAVs), the record has the
    exact one's structure and shapes (on_path and capped weights in [0, 1]), and ``summary`` and
    ``series`` reduce it: every output and series is finite wherever the exact one is."""
    exact, smooth = programs
    p = _params(link_loss=0.3, sensor_dropout=0.2, agent_loss_rate=0.02)
    ex, sm = exact(p, KEYS), smooth(p, KEYS, _level(1.0))
    assert int(np.sum(~np.asarray(ex[0].faults.alive))) > 0  # some UAV was lost
    assert jax.tree.structure(ex[0]) == jax.tree.structure(sm[0])
    assert jax.tree.map(jnp.shape, ex[0]) == jax.tree.map(jnp.shape, sm[0])
    for w in (sm[0].on_path, sm[0].capped):
        assert jnp.issubdtype(w.dtype, jnp.floating) and bool(jnp.all((w >= 0) & (w <= 1)))
    for e, s in ((ex[1], sm[1]), (ex[2], sm[2])):
        assert set(e) == set(s)
        for k in e:
            a, b = np.asarray(e[k], float), np.asarray(s[k], float)
            assert np.all(np.isfinite(b) | ~np.isfinite(a)), k


# ------------------------------------------------------------------ the smooth pieces


def test_soft_cap_is_the_softmin_of_eq15_and_tends_to_the_cap():
    """Eq. 15's soft cap flies ``a`` with length −T log(e^(−|a|/T) + e^(−l/T)) (a numpy
    reference), never longer than |a| or l; its length's derivative in |a| is continuous at
    |a| = l (½ there, the exact cap's jumps from 1 to 0) and it tends to the cap as T → 0."""
    rng = np.random.default_rng(15)
    a = rng.normal(0.0, 1.0, (200, 2)) * rng.uniform(100.0, 2000.0, (200, 1))
    l, T = 1000.0, 10.0
    cap = jax.jit(S.smooth_cap)
    got = np.asarray(cap(jnp.asarray(a), l, T))
    norm = np.linalg.norm(a, axis=1)
    length = -T * np.logaddexp(-norm / T, -l / T)
    np.testing.assert_allclose(got, a * (length / norm)[:, None], rtol=1e-12)
    assert np.all(np.linalg.norm(got, axis=1) <= np.minimum(norm, l) + 1e-9)
    along = jax.jit(jax.grad(lambda s: jnp.linalg.norm(S.smooth_cap(jnp.stack([s, 0.0]), l, T))))
    np.testing.assert_allclose(float(along(l)), 0.5, rtol=1e-12)
    assert abs(float(along(l + 1e-3)) - float(along(l - 1e-3))) < 1e-4
    exact = np.asarray(guidance.cap_step(jnp.asarray(a), l))
    assert np.max(np.abs(np.asarray(cap(jnp.asarray(a), l, 1e-3)) - exact)) < 1e-3 * np.log(2) + 1e-9


def test_smooth_path_point_is_continuous_across_the_join_and_exact_outside_its_bands():
    """Eq. 13's point as the predicted centre moves down, 0.1 m at a time, from 100 m above the
    place where the path just comes within l (a tangency, ~56 m above the point l over the
    path) to 150 m below the point l over the path; the largest root also passes x̃ there (the
    "ahead" switch). The exact point jumps (> 100 m). The smooth one (T = 100 m) is continuous:
    halving the spacing halves every increment (to 60 %; a jump would keep its size). Where
    neither ramp is on — the path farther than l; or within l − T with the root more than T/2
    ahead; or the root more than T/2 behind — it is the exact point."""
    psi = guidance.sine_path(2000.0 / 3.0, 1200.0)
    l, T, x = 1000.0, 100.0, 5000.0
    ys = float(psi(x)) + l + np.arange(100.0, -150.0, -0.05)[:-1]  # an odd count: pairs of fine steps

    def exact(y):
        return guidance.next_centre(psi, jnp.stack([x, y]), l), guidance.forward_root(psi, jnp.stack([x, y]), l)[0]

    (e, _), root = jax.jit(jax.vmap(exact))(ys)
    sm = jax.jit(jax.vmap(lambda y: S.smooth_next_centre(psi, jnp.stack([x, y]), l, 128, T)))(ys)
    e, s, w, root = np.asarray(e), np.asarray(sm.point), np.asarray(sm.on_path), np.asarray(root) - x
    assert np.max(np.linalg.norm(np.diff(e[::2], axis=0), axis=1)) > 100.0
    coarse = np.linalg.norm(np.diff(s[::2], axis=0), axis=1)             # spacing 0.1 m
    fine = np.linalg.norm(np.diff(s, axis=0), axis=1).reshape(-1, 2)      # spacing 0.05 m, two per coarse one
    assert np.all(fine.max(axis=1) <= 0.6 * coarse + 1e-9)
    assert np.all((w >= 0) & (w <= 1)) and np.any((w > 0.01) & (w < 0.99))
    xx = np.linspace(x - l, x + l, 20001)
    dx, path = xx - x, 2000.0 / 3.0 * np.sin(xx / 1200.0)  # numpy: the path sampled once for every y
    d = np.array([np.min(np.hypot(dx, path - y)) for y in ys])
    outside = (d > l + 1.0) | ((d < l - T - 1.0) & (root > T / 2 + 1.0)) | (root < -T / 2 - 1.0)
    assert outside.sum() > len(ys) / 3
    np.testing.assert_allclose(s[outside], e[outside], rtol=0, atol=1e-6)
