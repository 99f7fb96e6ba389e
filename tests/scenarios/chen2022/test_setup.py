"""Chen & Hao 2022 (urban_bearing), the set-up options of issue 32 against independent references:
the bearings-only start (numpy eigen-decomposition, the sample statistics of many starts, the
information identity FIM_0 P_0 = I), the shadow hold's step limit (an invariant of the records),
and the CLI's one-line rejection of a bad ``init``."""

from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from click.testing import CliRunner

from mcjax import engine
from mcjax.cli import main
from mcjax.contract import FAST_COMPILE
from mcjax.scenarios import chen2022 as S

DEG = np.pi / 180.0
CONFIG = str((Path(__file__).parents[3] / "configs" / "chen2022.toml").resolve())


def jit(fun, **kw):
    """``jax.jit`` with the scenarios' XLA options (:data:`mcjax.contract.FAST_COMPILE`: XLA's older
    CPU fusion code generator, which compiles with much less CPU time; the engine compiles the
    scenarios' programs so). What these tests check does not depend on the code generator."""
    return jax.jit(fun, compiler_options=dict(FAST_COMPILE), **kw)


@pytest.mark.parametrize("bearing_deg", [-170.0, -45.0, 0.0, 30.0, 90.0, 135.0])
def test_first_bearing_prior_is_range_and_cross_range(bearing_deg):
    """x0 lies on the bearing at the range; P0's eigenvectors are the bearing's direction (eigenvalue
    σ_r²) and its normal ((r σ_β)²) — numpy's eigh, not the rotation the code writes."""
    uav, r, sr, sb = np.array([120.0, -40.0]), 7000.0, 1000.0, 0.2 * DEG
    beta = bearing_deg * DEG
    x0, P0 = (np.asarray(a) for a in S.first_bearing_prior(jnp.asarray(uav), beta, r, sr, sb))
    d = x0 - uav
    assert np.hypot(*d) == pytest.approx(r, rel=1e-13)
    assert np.arctan2(d[1], d[0]) == pytest.approx(beta, abs=1e-13)
    w, v = np.linalg.eigh(P0)
    np.testing.assert_allclose(w, sorted([(r * sb) ** 2, sr**2]), rtol=1e-10)
    along = v[:, np.argmax(w)]
    assert abs(abs(along @ [np.cos(beta), np.sin(beta)]) - 1.0) < 1e-12
    np.testing.assert_allclose(np.asarray(S.inv2(jnp.asarray(P0))) @ P0, np.eye(2), atol=1e-10)


def _inits(cfg, params, n):
    keys = jax.vmap(lambda s: engine.init_key(engine.run_key(0, s)))(jnp.arange(n, dtype=jnp.uint32))
    return jit(jax.vmap(lambda k: S.init(cfg, params, k)))(keys)


def test_first_bearing_start_statistics():
    """2,000 starts from the default set-up (the start has line of sight and no reflection): the
    angle of x0 seen from uav0 scatters about the true bearing with std σ_LOS, the range about the
    true range with std prior_sigma (sample std within 8 %, means within 4 standard errors);
    every filter and mode starts there; FIM_0 P_0 = I."""
    cfg = S.Config(init="first_bearing")
    p = S.default_params(cfg)
    n = 2000
    st = _inits(cfg, p, n)
    imm = st.filters[cfg.filters.index("imm")]
    x0 = np.asarray(imm.x[:, 0])
    e, u = np.asarray(p.emitter[:2]), np.asarray(p.uav0[:2])
    d = x0 - u
    ang = np.arctan2(d[:, 1], d[:, 0]) - np.arctan2(*(e - u)[::-1])
    rng = np.hypot(d[:, 0], d[:, 1]) - np.hypot(*(e - u))
    for sample, sigma in ((ang, float(p.sigma_los)), (rng, float(p.prior_sigma))):
        assert abs(sample.mean()) < 4 * sigma / np.sqrt(n)
        assert abs(sample.std() / sigma - 1.0) < 0.08
    for f in st.filters:
        np.testing.assert_array_equal(np.asarray(f.x), np.broadcast_to(np.asarray(imm.x[:, :1]), f.x.shape))
        np.testing.assert_array_equal(np.asarray(f.P), np.broadcast_to(np.asarray(imm.P[:, :1]), f.P.shape))
    prod = np.einsum("nij,njk->nik", np.asarray(st.fim[:, 0]), np.asarray(imm.P[:, 0]))
    np.testing.assert_allclose(prod, np.broadcast_to(np.eye(2), prod.shape), atol=1e-9)


def test_first_bearing_without_line_of_sight_falls_back_to_the_prior():
    """A tall building between the start and the emitter: no bearing at uav0, so the start is the
    isotropic prior (P0 = prior_sigma² I) about the emitter."""
    cfg = S.Config(init="first_bearing")
    p = S.default_params(cfg, buildings=np.array([[100.0, 100.0, 300.0, 300.0, 300.0]]))
    st = _inits(cfg, p, 200)
    imm = st.filters[cfg.filters.index("imm")]
    s2 = float(p.prior_sigma) ** 2
    np.testing.assert_allclose(np.asarray(imm.P[:, 0]), np.broadcast_to(s2 * np.eye(2), (200, 2, 2)), rtol=1e-14)
    err = np.asarray(imm.x[:, 0]) - np.asarray(p.emitter[:2])
    assert abs(err.std() / float(p.prior_sigma) - 1.0) < 0.15


def _longest_run(flags):
    """Longest stretch of True per row, numpy."""
    best = np.zeros(len(flags), int)
    cur = np.zeros(len(flags), int)
    for t in range(flags.shape[1]):
        cur = np.where(flags[:, t], cur + 1, 0)
        best = np.maximum(best, cur)
    return best


def test_max_hold_steps_bounds_the_hold():
    """A long building north of the first leg hides the emitter from step ~7 on (FIM-only weights: the
    planner does not steer out of the shadow): with the paper's rule (0) the hold lasts as long as
    the shadow; with max_hold_steps = k no stretch of held steps is longer than k, and k is reached."""
    cfg = S.Config(n_steps=40, init="prior")
    box = np.array([[1000.0, 500.0, 6000.0, 700.0, 400.0]])
    limits = (0, 3, 7)
    points = [S.default_params(cfg, buildings=box, max_hold_steps=k, c2=0.0, c3=0.0,
                                uav0=np.array([0.0, 0.0, 200.0, 0.0]))
              for k in limits for _ in range(2)]
    params = engine.stack_points(points)
    keys = jax.vmap(lambda s: engine.run_key(0, s))(jnp.arange(len(points), dtype=jnp.uint32) % 2)
    r = jax.tree.map(np.asarray, engine.compiled(S.SCENARIO, cfg, records=True)(params, keys))
    held = r.held.astype(bool)
    longest = _longest_run(held)
    shadow = r.shadow.astype(bool)
    assert np.all(longest[:2] > 7) and shadow[:2].sum() > 20          # teeth: the paper's rule holds long
    for i, k in enumerate(limits[1:], start=1):
        assert np.all(longest[2 * i:2 * i + 2] <= k)
        assert np.all(longest[2 * i:2 * i + 2] == k)                  # and the limit is reached
    assert not np.any(r.in_building) and not np.any(r.violation)


def test_cli_rejects_a_bad_init_exit_2(tmp_path):
    spec = tmp_path / "spec.toml"
    spec.write_text(f'base = "{CONFIG}"\nseeds = 2\n[config]\nn_steps = 5\nwarmup_steps = 1\ninit = "truth"\n')
    r = CliRunner().invoke(main, ["sweep", str(spec), "--out", str(tmp_path / "o")])
    assert r.exit_code == 2, r.output
    lines = [line for line in r.output.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: config.init: ") and "first_bearing" in lines[0], r.output
