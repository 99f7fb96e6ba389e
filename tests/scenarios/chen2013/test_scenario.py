"""Chen & Lu 2013: the path-correction guidance (eqs. 13–16) against scipy and geometry, and
the wind/formation scenario against its invariants (the filter itself: tests/tracking/filters/test_prior_consensus_kcf.py)."""

import functools
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from click.testing import CliRunner
from scipy.optimize import brentq

from mcjax import engine
from mcjax.cli import main
from mcjax.scenarios import chen2013 as S
from mcjax.scenarios.chen2013 import guidance

CONFIG = str((Path(__file__).parents[3] / "configs" / "chen2013.toml").resolve())
AMP, SCALE = 2000.0 / 3.0, 1200.0


def _psi_np(x):
    return AMP * np.sin(x / SCALE)


def _largest_root_scipy(x0, y0, l):
    """The largest root of (x − x0)² + (ψ(x) − y0)² = l², bracketed on a grid 100× finer
    than mcjax's, then located by brentq; None if the curve never enters the circle."""
    g = lambda x: (x - x0) ** 2 + (_psi_np(x) - y0) ** 2 - l ** 2  # noqa: E731
    xs = np.linspace(x0 - l, x0 + l, 12801)
    gs = g(xs)
    inside = np.nonzero(gs <= 0)[0]
    if inside.size == 0:
        return None
    i = inside[-1]
    if i == xs.size - 1:
        return xs[-1]
    return brentq(g, xs[i], xs[i + 1], xtol=1e-12, rtol=1e-15)


def test_eq13_forward_root_matches_brentq_on_2000_cases():
    """Eq. 13: the point lies on the curve at distance l (to 1e-6 m), is the largest root,
    and equals scipy's brentq on a finer bracket — over 2,000 random predicted centres near
    and far from the path and look-aheads 200–2,000 m."""
    rng = np.random.default_rng(0)
    n = 2000
    x0 = rng.uniform(0, 60000, n)
    l = rng.uniform(200, 2000, n)
    y0 = _psi_np(x0) + rng.uniform(-1.5, 1.5, n) * (l + AMP)
    psi = guidance.sine_path(AMP, SCALE)
    roots, found = jax.jit(jax.vmap(lambda c, ll: guidance.forward_root(psi, c, ll)))(
        jnp.stack([x0, y0], 1), jnp.asarray(l))
    roots, found = np.asarray(roots), np.asarray(found)
    ref = [_largest_root_scipy(*a) for a in zip(x0, y0, l)]
    has = np.array([r is not None for r in ref])
    assert 0.2 < has.mean() < 0.9  # both kinds of case are exercised
    np.testing.assert_array_equal(found, has)
    r_ref = np.array([r for r in ref if r is not None])
    np.testing.assert_allclose(roots[has], r_ref, rtol=0, atol=1e-6)
    dist = np.hypot(roots[has] - x0[has], _psi_np(roots[has]) - y0[has])
    np.testing.assert_allclose(dist, l[has], rtol=0, atol=1e-6)
    # no root beyond: the curve is outside the circle at every sampled x past the root
    for k in np.nonzero(has)[0][:200]:
        xs = np.linspace(roots[k] + 1e-3, x0[k] + l[k], 200)
        assert np.all((xs - x0[k]) ** 2 + (_psi_np(xs) - y0[k]) ** 2 > l[k] ** 2 - 1e-6)


def test_next_centre_approach_rule_and_step_length():
    """With no forward root the centre moves exactly l towards (x̃ + l, ψ(x̃ + l)); with one,
    onto the curve ahead. Either way the move is l."""
    psi = guidance.sine_path(AMP, SCALE)
    far = jnp.array([10666.7, 9333.3])           # the paper's starting centroid, ~9 km off the path
    p = guidance.next_centre(psi, far, 1000.0)
    assert not bool(p.on_path)
    aim = np.array([far[0] + 1000.0, _psi_np(far[0] + 1000.0)])
    u = (aim - np.asarray(far)) / np.linalg.norm(aim - np.asarray(far))
    np.testing.assert_allclose(np.asarray(p.point), np.asarray(far) + 1000.0 * u, rtol=1e-12)
    near = jnp.array([5000.0, _psi_np(5000.0) + 300.0])
    q = guidance.next_centre(psi, near, 1000.0)
    assert bool(q.on_path) and float(q.point[0]) > 5000.0
    np.testing.assert_allclose(float(q.point[1]), _psi_np(float(q.point[0])), atol=1e-9)
    np.testing.assert_allclose(np.linalg.norm(np.asarray(q.point - near)), 1000.0, atol=1e-6)


def test_cap_step_eq15():
    rng = np.random.default_rng(1)
    v = rng.normal(0, 1500, (5000, 2))
    out = np.asarray(guidance.cap_step(jnp.asarray(v), 1000.0))
    norm = np.linalg.norm(v, axis=1)
    np.testing.assert_allclose(np.linalg.norm(out, axis=1), np.minimum(norm, 1000.0), rtol=1e-12)
    np.testing.assert_allclose(out[norm <= 1000], v[norm <= 1000])             # short steps unchanged
    cos = np.sum(out * v, 1) / (np.linalg.norm(out, axis=1) * norm)
    np.testing.assert_allclose(cos, 1.0, atol=1e-12)                           # direction kept
    assert np.all(np.isfinite(np.asarray(guidance.cap_step(jnp.zeros((1, 2)), 1000.0))))


def test_paper_offsets_give_the_3200_2062_2062_formation():
    """The reference vectors read as d_13, d_32 (sign restored), d_12: slots about the centroid
    (summing to 0) whose pairwise offsets are the chain's."""
    chain = jnp.asarray(S.PAPER_OFFSETS)
    d = np.asarray(guidance.centre_offsets(chain))
    np.testing.assert_allclose(d.sum(0), 0.0, atol=1e-9)
    np.testing.assert_allclose(d[1] - d[0], [0, 3200])        # d_12
    np.testing.assert_allclose(d[2] - d[1], [1300, -1600])    # d_23 = -d_32
    np.testing.assert_allclose(d[2] - d[0], [1300, 1600])     # d_13
    ref = np.asarray(S.reference_distances(S.Config(), chain))
    np.testing.assert_allclose(ref, [3200.0, np.hypot(1300, 1600), np.hypot(1300, 1600)])


def test_formation_term_sign():
    """Eq. 12's term η (X_j − X_i − d_ij) as printed; negated by the corrective reading."""
    rng = np.random.default_rng(2)
    pos = rng.normal(0, 1000, (3, 2))
    d = np.asarray(guidance.centre_offsets(jnp.asarray(S.PAPER_OFFSETS)))
    p = S.default_params(S.Config(), eta=0.02)
    want = np.array([[0.02 * (pos[j] - pos[i] - (d[j] - d[i])) for j in range(3)] for i in range(3)])
    got = np.asarray(S.formation_term(S.Config(formation_sign="printed"), p, jnp.asarray(pos), jnp.asarray(d)))
    np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-12)
    got = np.asarray(S.formation_term(S.Config(), p, jnp.asarray(pos), jnp.asarray(d)))
    np.testing.assert_allclose(got, -want, rtol=1e-12, atol=1e-12)


@functools.cache
def _reduce(cfg):
    """The scenario's ``reduce`` over a batch of records, jitted once per Config (the Params an
    argument): compiled, not run op by op."""
    return jax.jit(jax.vmap(lambda r, p: S.reduce(cfg, r, p), (0, None)))


def _run(cfg, runs=40, **params):
    """(per-run outputs, records) of ``runs`` seeds: the records from the engine, the outputs
    reduced from them by the scenario's ``reduce``."""
    p = S.default_params(cfg, **params)
    rec = [o for *_, o in engine.run_chunks(S.SCENARIO, cfg, engine.stack_points([p]), runs, chunk_size=runs,
                                            records=True)][0]
    out = _reduce(cfg)(jax.tree.map(jnp.asarray, rec), p)
    return {k: np.asarray(v) for k, v in out.items()}, rec


@pytest.fixture(scope="module")
def paper_runs():
    return _run(S.Config(n_steps=60), runs=40)


@pytest.mark.xdist_group("test_wind_formation")  # one worker builds the module fixture once
def test_paper_setup_table1_raw_row_formation_and_limits(paper_runs):
    out, rec = paper_runs
    kcf = S.Config().filters.index("kcf")
    T = 60
    # the raw row: |uniform(-10, 10)| has mean 5 and the largest of T draws has mean 10 T/(T+1)
    for ax in "xy":
        assert abs(out[f"raw_mean_{ax}"].mean() - 5.0) < 0.25
        assert abs(out[f"raw_max_{ax}"].mean() - 10.0 * T / (T + 1)) < 0.5
        # filtering beats averaging three measurements once
        assert out[f"wind_mean_{ax}"][:, kcf].mean() < out[f"raw_mean_{ax}"].mean() / np.sqrt(3)
    # recorded raw errors are within the noise bound; estimates are finite
    assert np.all(rec.raw_error <= 10.0) and not out["nonfinite"].any()
    # the applied air step never exceeds l
    air = np.linalg.norm(np.diff(rec.positions, axis=1) - 10.0 * np.asarray(S.wind(S.default_params(), np.float64)),
                         axis=-1)
    assert air.max() <= 1000.0 * (1 + 1e-12) and out["max_air_step"].max() <= 1000.0 * (1 + 1e-12)
    # the formation settles within 50 m by step 12 and stays; the centre joins the path
    assert np.all(out["settle_step"] <= 12)
    ref = np.array([3200.0, np.hypot(1300, 1600), np.hypot(1300, 1600)])
    assert np.all(np.abs(rec.distances[:, 12:] - ref) <= 50.0)
    assert np.all(np.isfinite(out["join_step"])) and np.all(out["path_error_max"] < 100.0)


@pytest.mark.xdist_group("test_wind_formation")  # paper_runs' program, in its worker
def test_complete_graph_kcf_equals_centralised_when_eta_is_zero():
    """On the paper's complete graph with η = 0, eq. 9 with max-degree weights averages equal
    priors and adds all three measurements: every UAV's estimate is the centralised filter's
    at every step (and the formation stays exact, every UAV compensating the same wind)."""
    cfg = S.Config(n_steps=60)   # the paper_runs fixture's Config: no new compilation
    out, rec = _run(cfg, runs=40, eta=0.0)   # 40 runs: the same batch program
    k, c = cfg.filters.index("kcf"), cfg.filters.index("cif")
    np.testing.assert_allclose(rec.error[:, :, k], rec.error[:, :, c], rtol=1e-9, atol=1e-12)
    assert np.abs(rec.error[:, :, k] - rec.error[:, :, cfg.filters.index("local")]).max() > 0.1


@pytest.mark.xdist_group("test_wind_formation")  # paper_runs' program, in its worker
def test_broken_graph_and_gaussian_noise_run():
    """comm_radius below every side: no consensus (λ2 = 0 once in formation) — the kcf is then
    each UAV's own filter; Gaussian noise: raw mean |N(0, σ²)| = σ √(2/π)."""
    cfg = S.Config(n_steps=60)   # the paper_runs fixture's Config and 40 runs: its program
    out, rec = _run(cfg, runs=40, comm_radius=500.0)
    k, loc = cfg.filters.index("kcf"), cfg.filters.index("local")
    assert out["disconnected_steps"].min() >= 30
    # after the graph empties the kcf and the local filters are the same recursion on the same data,
    # but they entered it with different posteriors, so only compare that both are sensible
    assert np.all(out["wind_mean_x"][:, [k, loc]] < 10.0)
    # the raw measurement errors do not depend on the filters: the Gaussian run has only the local
    # one (a smaller program to compile)
    gauss = S.Config(n_steps=40, wind_noise="gaussian", filters=("local",))
    out, _ = _run(gauss, runs=30, comm_radius=500.0)
    assert abs(out["raw_mean_x"].mean() - 10.0 * np.sqrt(2 / np.pi)) < 0.6


BAD = {
    "offsets_open": ("offsets", {"offsets": [[0.0, 3200.0], [1300.0, -1600.0], [1300.0, 1500.0]]}),
}


def test_check_params_names_the_field():
    assert S.check_params(S.Config(), {}) == []
    bad = S.check_params(S.Config(), BAD["offsets_open"][1])
    assert bad and bad[0][0] == "offsets" and "sum" in bad[0][1]
    # with a sweep-point axis, one open formation among closed ones is still caught
    points = np.stack([S.PAPER_OFFSETS, np.asarray(BAD["offsets_open"][1]["offsets"])])
    assert [f for f, _ in S.check_params(S.Config(), {"offsets": points})] == ["offsets"]
    assert S.check_params(S.Config(), {"offsets": np.stack([S.PAPER_OFFSETS] * 2)}) == []


def _spec(tmp_path, config="", params=""):
    spec = tmp_path / "spec.toml"
    spec.write_text(f'base = "{CONFIG}"\nseeds = 2\n[config]\nn_steps = 5\n{config}[params]\n{params}')
    return spec


@pytest.mark.parametrize("params,where", [
    ("offsets = [[0.0, 3200.0], [1300.0, -1600.0], [1300.0, 1500.0]]\n", "params.offsets: must be pairwise offsets that close"),
    ("offsets = [[0.0, 3200.0], [1300.0, 1600.0]]\n", "params.offsets: must be of shape n_agents"),
    ("step_length = 0.0\n", "params.step_length: must be > 0"),
    ("eta = -0.1\n", "params.eta: must be >= 0"),
    ("noise_scale = 0.0\n", "params.noise_scale: must be > 0"),
])
def test_cli_rejects_bad_input_exit_2_nothing_written(tmp_path, params, where):
    out = tmp_path / "o"
    r = CliRunner().invoke(main, ["sweep", str(_spec(tmp_path, params=params)), "--out", str(out)])
    assert r.exit_code == 2, r.output
    lines = [line for line in r.output.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: " + where), r.output
    assert not out.exists()


def test_cli_rejects_bad_config(tmp_path):
    for config, where in (('report_agent = 4\n', "config.report_agent: must be an integer in [1, n_agents = 3]"),
                          ('n_agents = 1\n', "config.n_agents: must be an integer >= 2"),
                          ('wind_noise = "laplace"\n', "config.wind_noise: must be one of uniform, gaussian")):
        r = CliRunner().invoke(main, ["sweep", str(_spec(tmp_path, config=config)), "--out", str(tmp_path / "o")])
        assert r.exit_code == 2 and r.output.strip().startswith("error: " + where), r.output


def test_spec_validates_and_library_raises():
    from mcjax.study import load_config_file

    loaded = load_config_file(CONFIG)
    assert loaded[0] is S.SCENARIO and loaded[1] == S.Config()
    with pytest.raises(ValueError, match="report_agent"):
        S.Config(report_agent=5)
