"""The ATC diffusion Kalman filter of Cattivelli & Sayed 2010 (IEEE TAC 55(9)), the plugin package in
benchmarks/plugins/diffusion_kf/: against a numpy reference written from the paper's equations, on a complete
graph (one estimate for all, the centralised filter's), with no links (the local EKF), and installed for real
as a package that the three scenarios taking any filter run."""

import importlib.util
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import mcjax

mcjax.configure()

import jax
import jax.numpy as jnp

from mcjax.contract.filter import Model
from mcjax.tracking.filters.consensus import CIF, LOCAL, FilterOptions, Measurements
from mcjax.tracking.filters.gaussian import Gaussian
from mcjax.tracking.models.sensors import range_bearing

PLUGIN = Path(__file__).resolve().parents[3] / "benchmarks" / "plugins" / "diffusion_kf"
sys.path.insert(0, str(PLUGIN))
from mcjax_diffusion_kf import DIFFUSION_KF

sys.path.remove(str(PLUGIN))

ANGLE = jnp.array([False, True])
D = 4  # [x, ẋ, y, ẏ]


# --------------------------------------------------------------------------- a random lossy run


def _cv(dt=1.0, q=0.05):
    F = np.eye(D)
    F[0, 1] = F[2, 3] = dt
    block = q * np.array([[dt**3 / 3, dt**2 / 2], [dt**2 / 2, dt]])
    Q = np.zeros((D, D))
    Q[:2, :2] = Q[2:, 2:] = block
    return F, Q


def _run_data(n, steps, seed, link_p=0.4, miss_p=0.25, graph="random"):
    """A target on a CV path, sensors wandering around it, range–bearing measurements (NaN for some agents),
    a new symmetric graph each step (``"random"``: each link with probability ``link_p``; ``"complete"``;
    ``"empty"``)."""
    rng = np.random.default_rng(seed)
    F, Q = _cv()
    truth = np.array([0.0, 1.0, 0.0, 0.5])
    Fs, Qs, Z, S, A, Rinv = [], [], [], [], [], []
    sig = np.stack([rng.uniform(0.5, 2.0, n), rng.uniform(0.01, 0.05, n)], -1)
    for t in range(steps):
        if t > 0:
            truth = F @ truth + rng.multivariate_normal(np.zeros(D), Q)
        Fs.append(np.eye(D) if t == 0 else F)
        Qs.append(np.zeros((D, D)) if t == 0 else Q)
        sensors = truth[[0, 2]] + rng.uniform(-40.0, 40.0, (n, 2))
        z = np.array([_h(truth, s) for s in sensors]) + sig * rng.standard_normal((n, 2))
        z[:, 1] = _wrap(z[:, 1])
        z[rng.random(n) < miss_p] = np.nan
        if graph == "random":
            upper = np.triu(rng.random((n, n)) < link_p, 1)
            adj = (upper | upper.T).astype(float)
        else:
            adj = np.ones((n, n)) - np.eye(n) if graph == "complete" else np.zeros((n, n))
        Z.append(z)
        S.append(sensors)
        A.append(adj)
        Rinv.append(np.stack([np.diag(1.0 / s**2) for s in sig]))
    x0 = np.array([3.0, 0.5, -2.0, 0.0])
    P0 = np.diag([25.0, 4.0, 25.0, 4.0])
    return {"x0": x0, "P0": P0, "F": np.array(Fs), "Q": np.array(Qs), "z": np.array(Z), "sensors": np.array(S),
            "adjacency": np.array(A), "R_inv": np.array(Rinv)}


def _run_filter(f, data, options=None, centralised=False):
    """The filter ``f``'s step, jitted once, scanned over the run; its posteriors (steps, n, ·)."""
    n = data["z"].shape[1]
    options = FilterOptions() if options is None else options
    x0, P0 = jnp.asarray(data["x0"]), jnp.asarray(data["P0"])
    post = Gaussian(x0, P0, jnp.linalg.inv(P0))
    if not centralised:
        post = jax.tree.map(lambda a: jnp.broadcast_to(a, (n,) + a.shape), post)

    @jax.jit
    def run(post, seq):
        def body(post, s):
            F, Q, z, sensors, adj, R_inv = s
            new = f.step(Model(range_bearing, ANGLE, F, Q, options), post, Measurements(z, sensors, adj, R_inv))
            return new, new

        return jax.lax.scan(body, post, seq)[1]

    seq = tuple(jnp.asarray(data[k]) for k in ("F", "Q", "z", "sensors", "adjacency", "R_inv"))
    return jax.tree.map(np.asarray, run(post, seq))


# --------------------------------------------------------------------------- the reference, from the paper


def _wrap(a):
    return (np.asarray(a) + np.pi) % (2 * np.pi) - np.pi


def _h(x, s):
    """Range–bearing of the target position p = (x[0], x[2]) from a sensor at s."""
    dx, dy = x[0] - s[0], x[2] - s[1]
    return np.array([np.hypot(dx, dy), np.arctan2(dy, dx)])


def _H(x, s):
    """∂h/∂x by hand."""
    dx, dy = x[0] - s[0], x[2] - s[1]
    r2 = dx * dx + dy * dy
    r = np.sqrt(r2)
    return np.array([[dx / r, 0.0, dy / r, 0.0], [-dy / r2, 0.0, dx / r2, 0.0]])


def _combination_weights(adj, kind):
    """c_{l,k} as a matrix C[k, l] (row k sums to one over N_k ∪ {k})."""
    n = adj.shape[0]
    deg = adj.sum(1)
    C = np.zeros((n, n))
    for k in range(n):
        for l in range(n):
            if l != k and adj[k, l]:
                C[k, l] = 1 / (1 + deg[k]) if kind == "eq11" else 1 / (1 + max(deg[k], deg[l]))
        C[k, k] = 1 / (1 + deg[k]) if kind == "eq11" else 1 - C[k].sum()
    return C


def _reference(data, kind):
    """Cattivelli & Sayed 2010's ATC diffusion KF, EKF form, in plain numpy loops over nodes and neighbours."""
    n = data["z"].shape[1]
    x = [data["x0"].copy() for _ in range(n)]
    P = [data["P0"].copy() for _ in range(n)]
    xs, Ps = [], []
    eye = np.eye(D)
    for t in range(data["z"].shape[0]):
        F, Q, z, s, adj, Rinv = (data[k][t] for k in ("F", "Q", "z", "sensors", "adjacency", "R_inv"))
        psi, P_new = [], []
        for k in range(n):
            xb = F @ x[k]                                    # time update
            Pb = F @ P[k] @ F.T + Q
            info = np.linalg.solve(Pb, eye)                  # P̄_k⁻¹
            vec = info @ xb                                  # P̄_k⁻¹ x̄_k
            for l in range(n):                               # incremental update over N_k ∪ {k}
                if (l == k or adj[k, l]) and np.all(np.isfinite(z[l])):
                    H = _H(xb, s[l])                         # linearised at node k's own prediction
                    nu = z[l] - _h(xb, s[l])
                    nu[1] = _wrap(nu[1])
                    info = info + H.T @ Rinv[l] @ H
                    vec = vec + H.T @ Rinv[l] @ (nu + H @ xb)
            P_new.append(np.linalg.solve(info, eye))
            psi.append(np.linalg.solve(info, vec))
        C = _combination_weights(adj, kind)
        x = [sum(C[k, l] * psi[l] for l in range(n) if l == k or adj[k, l]) for k in range(n)]  # combine
        P = P_new
        xs.append(np.array(x))
        Ps.append(np.array(P))
    return np.array(xs), np.array(Ps)


def _rel(a, b):
    """Largest |a − b| over each step's agents, relative to the largest |b| of that step."""
    axes = tuple(range(1, a.ndim))
    return float(np.max(np.max(np.abs(a - b), axis=axes) / np.max(np.abs(b), axis=axes)))


# --------------------------------------------------------------------------- tests


@pytest.mark.parametrize("weights, exchange", [("eq11", "dense"), ("metropolis", "dense"),
                                               ("metropolis", "sparse")])
def test_it_is_the_papers_filter_over_a_changing_lossy_graph(weights, exchange):
    """200 steps of a random symmetric graph, some agents without a measurement: the plugin's step (jitted,
    scanned) against the numpy reference written from the paper's equations."""
    data = _run_data(n=6, steps=200, seed=7)
    options = FilterOptions(weights=weights, exchange=exchange, max_neighbours=5)
    got = _run_filter(DIFFUSION_KF, data, options)
    x_ref, P_ref = _reference(data, weights)
    assert np.all(np.isfinite(got.x)) and np.all(np.isfinite(got.P))
    rel_x, rel_P = _rel(got.x, x_ref), _rel(got.P, P_ref)
    print(f"diffusion_kf vs numpy reference ({weights}, {exchange}): max rel x {rel_x:.2e}, P {rel_P:.2e}")
    assert rel_x <= 1e-9 and rel_P <= 1e-9
    np.testing.assert_allclose(got.Y, np.linalg.inv(got.P), rtol=1e-8, atol=1e-10)
    # the run is one of diffusion: agents' estimates differ (the graph is not complete), and the fusion helps
    assert np.ptp(got.x[-1], axis=0).max() > 0


def test_on_a_complete_graph_with_uniform_weights_every_agent_holds_the_centralised_estimate():
    """Max-degree weights on a complete graph are 1/n everywhere (Chen & Lu 2013 eq. 7: a_ij/n and
    1 − (n−1)/n): every node pools every measurement and combines equal ψ's — all agents hold one estimate,
    the centralised information filter's."""
    data = _run_data(n=5, steps=40, seed=3, graph="complete")
    got = _run_filter(DIFFUSION_KF, data, FilterOptions(weights="max_degree"))
    for a in (got.x, got.P):
        assert _rel(a, np.broadcast_to(a[:, :1], a.shape)) <= 1e-12
    cif = _run_filter(CIF, data, centralised=True)
    assert _rel(got.x, np.broadcast_to(cif.x[:, None], got.x.shape)) <= 1e-9
    assert _rel(got.P, np.broadcast_to(cif.P[:, None], got.P.shape)) <= 1e-9


def test_with_no_links_it_is_the_local_ekf():
    data = _run_data(n=5, steps=60, seed=11, graph="empty")
    got = _run_filter(DIFFUSION_KF, data)
    local = _run_filter(LOCAL, data)
    assert _rel(got.x, local.x) <= 1e-12 and _rel(got.P, local.P) <= 1e-12


def test_the_record_and_its_traits():
    assert DIFFUSION_KF.name == "diffusion_kf" and "Cattivelli & Sayed 2010" in DIFFUSION_KF.reference
    t = DIFFUSION_KF.traits
    assert (t.centralised, t.late_messages, t.messages, t.weights, t.consensus_only) == (False, False, True, "any",
                                                                                          False)


#: Run in a subprocess with only the installed plugin on the path: each scenario that takes any filter, with
#: faults, its small config of tests/tracking/filters/test_registry.py.
SCRIPT = r'''
import json, sys
import jax, numpy as np
from mcjax import configure, engine, scenarios
from mcjax.tracking.filters import registry

configure()
report = {"origin": registry.origin("diffusion_kf") if registry.get("diffusion_kf") else None}
for name, extra in [("leader_follower", dict(planner="none", faults="on")),
                    ("flocking", dict(n_agents=6, faults="on")),
                    ("wind_formation", dict(faults="on"))]:
    sc = scenarios.get(name)
    cfg = sc.Config(filters=("local", "diffusion_kf"), n_steps=10, warmup_steps=2, **extra)
    params = engine.stack_points([sc.default_params(cfg, link_loss=0.2, sensor_dropout=0.1)])
    out = engine.simulate(sc, cfg, jax.tree.map(lambda a: np.repeat(a, 3, axis=0), params),
                          jax.random.split(jax.random.key(2), 3))
    declared = sc.outputs(cfg)
    rows = {}
    for key, o in declared.items():
        if key in out and o.per_filter:
            a = np.asarray(out[key], np.float64).reshape(3, 2, -1)
            rows[key] = [np.isfinite(a[:, f]).all(axis=-1).tolist() for f in (0, 1)]
    report[name] = dict(missing=sorted(set(declared) - set(out)), extra=sorted(set(out) - set(declared)),
                        links_lost=float(np.asarray(out["links_lost"]).sum()), finite=rows)
print("REPORT " + json.dumps(report))
'''


def _offline_build_missing() -> str:
    """Why pip cannot build a wheel here without the network, or "" if it can: setuptools builds it, with
    its own bdist_wheel from setuptools 70.1 on, with the ``wheel`` package's before."""
    if importlib.util.find_spec("setuptools") is None:
        return "setuptools is not installed"
    import setuptools

    version = tuple(int(p) for p in setuptools.__version__.split(".")[:2] if p.isdigit())
    if version < (70, 1) and importlib.util.find_spec("wheel") is None:
        return (f"setuptools {setuptools.__version__} has no bdist_wheel of its own (from 70.1) and the 'wheel' "
                "package is not installed")
    return ""


def test_installed_as_a_package_it_is_listed_and_runs_in_the_three_scenarios(tmp_path):
    reason = _offline_build_missing()
    if reason:
        pytest.skip(f"pip cannot build the plugin offline (--no-build-isolation): {reason}")
    source = tmp_path / "src"  # a copy, so that the build leaves nothing in the repository
    shutil.copytree(PLUGIN, source, ignore=shutil.ignore_patterns("build", "*.egg-info", "__pycache__"))
    target = tmp_path / "site"
    env = {**os.environ, "PIP_NO_INDEX": "1", "PIP_DISABLE_PIP_VERSION_CHECK": "1"}
    pip = subprocess.run([sys.executable, "-m", "pip", "install", "--no-deps", "--no-build-isolation", "--quiet",
                          "--target", str(target), str(source)], check=False, capture_output=True, text=True,
                         env=env, timeout=300)
    assert pip.returncode == 0, pip.stderr
    env["PYTHONPATH"] = os.pathsep.join([str(target), *[p for p in sys.path if p]])
    listed = subprocess.run([sys.executable, "-m", "mcjax", "list", "filters"], check=False, capture_output=True,
                            text=True, env=env, cwd=tmp_path, timeout=300)
    assert listed.returncode == 0, listed.stderr
    line = next((x for x in listed.stdout.splitlines() if x.startswith("diffusion_kf ")), "")
    assert "[plugin:" in line, listed.stdout
    assert "Cattivelli & Sayed 2010" in listed.stdout
    run = subprocess.run([sys.executable, "-c", SCRIPT], check=False, capture_output=True, text=True, env=env,
                         cwd=tmp_path, timeout=600)
    assert run.returncode == 0, run.stderr[-3000:]
    report = json.loads(run.stdout.split("REPORT ", 1)[1])
    assert str(target) in report["origin"]  # the installed copy, not the repository's
    for name in ("leader_follower", "flocking", "wind_formation"):
        r = report[name]
        assert r["missing"] == [] and r["extra"] == [], (name, r)
        assert r["links_lost"] > 0, name  # the faults were drawn
        assert r["finite"], name
        for key, (local, ours) in r["finite"].items():
            assert sum(ours) >= 2 and sum(ours) >= sum(local) - 1, (name, key, local, ours)
