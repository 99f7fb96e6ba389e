"""Consensus messages that arrive k steps late (Config.message_delay): the KCF's step against
a numpy implementation written from the equations, the mailbox's timing, the scenario's
invariants and the filters whose structure cannot take late messages."""

from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from click.testing import CliRunner

from mcjax.cli import main
from mcjax.scenarios.kit import faults
from mcjax.study import build_spec, run_sweep
from mcjax.tracking.filters.consensus import FilterOptions, Measurements, kcf_step
from mcjax.tracking.filters.gaussian import Gaussian

ROOT = Path(__file__).resolve().parents[3]
DT, EPS, K, STEPS = 1.0, 0.3, 2, 12
F = np.array([[1, DT, 0, 0], [0, 1, 0, 0], [0, 0, 1, DT], [0, 0, 0, 1]], float)
Q = 0.5 * np.eye(4)
H = np.array([[1.0, 0, 0, 0], [0, 0, 1.0, 0]])
R = np.diag([4.0, 9.0])
A = np.array([[0, 1, 0], [1, 0, 1], [0, 1, 0]], float)  # a path of three agents


def _reference(z, x0, P0):
    """The KCF with messages K steps late, from its equations (numpy): predict, fuse the own
    measurement only, M = (P̄⁻¹ + HᵀR⁻¹H)⁻¹, x̂ = x̄ + M Hᵀ R⁻¹ (z − H x̄) + γ M Σ_j a_ij (x̄_j − x̄_i)
    at step t − K (no message before step K), γ = ε / (1 + ‖M‖_F)."""
    n = z.shape[1]
    x, P = np.repeat(x0[None], n, 0), np.repeat(P0[None], n, 0)
    priors, out = [], []
    for t in range(STEPS):
        xb = x @ F.T
        Pb = F @ P @ F.T + Q
        priors.append(xb)
        new_x, new_P = np.empty_like(x), np.empty_like(P)
        for i in range(n):
            M = np.linalg.inv(np.linalg.inv(Pb[i]) + H.T @ np.linalg.inv(R) @ H)
            x_i = xb[i] + M @ H.T @ np.linalg.inv(R) @ (z[t, i] - H @ xb[i])
            if t >= K:
                old = priors[t - K]
                x_i = x_i + EPS / (1 + np.linalg.norm(M)) * M @ sum(A[i, j] * (old[j] - old[i]) for j in range(n))
            new_x[i], new_P[i] = x_i, M
        x, P = new_x, new_P
        out.append(x.copy())
    return np.stack(out)


def test_late_kcf_is_its_equations():
    rng = np.random.default_rng(4)
    n = 3
    z = rng.normal(0, 30, (STEPS, n, 2)) + np.arange(STEPS)[:, None, None] * 5.0
    x0, P0 = np.array([0.0, 5.0, 0.0, 5.0]), np.diag([100.0, 4.0, 100.0, 4.0])
    want = _reference(z, x0, P0)

    def h(x, sensor):
        del sensor
        return jnp.stack([x[0], x[2]])

    opts = FilterOptions(kcf_gain="gamma_M")
    Y0 = np.linalg.inv(P0)
    post = Gaussian(*(jnp.asarray(np.repeat(a[None], n, 0)) for a in (x0, P0, Y0)))
    R_inv = jnp.asarray(np.repeat(np.linalg.inv(R)[None], n, 0))
    box = faults.Mailbox(jnp.asarray(np.repeat(x0[None, None], n, 1).repeat(K, 0)), jnp.zeros((K, n, n)))

    @jax.jit  # one compiled step (op by op, the first step alone took seconds)
    def step(post, box, z):
        meas = Measurements(z, jnp.zeros((n, 2)), jnp.asarray(A), R_inv, late=faults.late(box, jnp.asarray(F)))
        sent = post.x
        post = kcf_step(h, jnp.array([False, False]), opts, EPS, post, meas, jnp.asarray(F), jnp.asarray(Q))
        return post, faults.post(box, sent, jnp.asarray(A))

    for t in range(STEPS):
        post, box = step(post, box, jnp.asarray(z[t]))
        np.testing.assert_allclose(np.asarray(post.x), want[t], rtol=1e-10, atol=1e-8, err_msg=f"step {t}")


def test_mailbox_delivers_what_was_sent_k_steps_ago():
    """After steps 0 … t−1 sent estimates e_s (posteriors before step s) and links L_s, step t
    receives F e_{t−k} (the prediction sent at step t−k) over L_{t−k}; before step k, nothing."""
    k, n = 3, 2

    class Cfg:
        message_delay, n_agents = k, n

    x0 = jnp.array([1.0, 2.0])
    box = faults.mailbox(Cfg, x0)
    Fm = jnp.array([[1.0, 1.0], [0.0, 1.0]])
    sent = [jnp.full((n, 2), 10.0 * s) + jnp.arange(n)[:, None] for s in range(8)]
    links = [jnp.full((n, n), float(s + 1)) for s in range(8)]
    for t in range(8):
        got = faults.late(box, Fm)
        if t < k:
            np.testing.assert_array_equal(np.asarray(got.adjacency), 0.0)
            np.testing.assert_array_equal(np.asarray(got.means), np.asarray(jnp.broadcast_to(Fm @ x0, (n, 2))))
        else:
            np.testing.assert_array_equal(np.asarray(got.means), np.asarray(sent[t - k] @ Fm.T))
            np.testing.assert_array_equal(np.asarray(got.adjacency), np.asarray(links[t - k]))
        box = faults.post(box, sent[t], links[t])
    assert faults.mailbox(type("C", (), {"message_delay": 0, "n_agents": n}), x0) is None


def _rows(config, params=None):
    spec = build_spec({"base": str(ROOT / "configs" / "sun2011.toml"),
                       "config": {"planner": "none", "filters": ["kcf", "local"], "n_steps": 30, **config},
                       "params": params or {}}, ROOT, seeds=3)
    df = run_sweep(spec).sort_values(["seed_index", "filter"])
    return {f: g.rmse.to_numpy() for f, g in df.groupby("filter")}


def test_late_kcf_without_consensus_gain_is_the_local_filter():
    """With messages late the neighbours' (old) measurements are not fused, so with ε = 0 the
    KCF is the local EKF (to rounding: one is in moment form, the other in information form);
    on time, it fuses them and is not."""
    late = _rows({"message_delay": 2}, {"kcf_epsilon": 0.0})
    np.testing.assert_allclose(late["kcf"], late["local"], rtol=1e-9)
    on_time = _rows({}, {"kcf_epsilon": 0.0})
    assert np.all(np.abs(on_time["kcf"] - on_time["local"]) > 1e-3 * on_time["local"])
    consensus = _rows({"message_delay": 2})
    assert np.all(np.abs(consensus["kcf"] - consensus["local"]) > 1e-6 * consensus["local"])


@pytest.mark.parametrize("config, field", [
    ('message_delay = 1\nplanner = "none"\nfilters = ["kcf", "icf"]', "filters"),
    ("message_delay = 1", "filters"),  # the closed loop plans from the modified ICF
    ('message_delay = 1\nplanner = "none"\nfilters = ["kcf"]\nkcf_gain = "prior_consensus"', "kcf_gain"),
    ("message_delay = -1", "message_delay"),
])
def test_filters_that_cannot_take_late_messages_are_refused(tmp_path, config, field):
    spec = tmp_path / "s.toml"
    spec.write_text(f'base = "{ROOT / "configs"}/sun2011.toml"\nseeds = 2\n[config]\n{config}\n')
    r = CliRunner().invoke(main, ["sweep", str(spec), "--out", str(tmp_path / "out")])
    assert r.exit_code == 2, r.output
    text = r.output.strip()
    assert len(text.splitlines()) == 1 and field in text, text
    assert not (tmp_path / "out").exists()


def test_late_messages_in_the_flock_leave_the_control_alone():
    """Lou et al. 2013: with the flock steering to the true target (control_reference = truth),
    late KCF messages change the KCF's estimates, not the flock (its control is sensed, not
    sent) nor the local filter — to rounding: the two are different programs."""
    def rows(delay):
        spec = build_spec({"base": str(ROOT / "configs" / "lou2013.toml"),
                           "config": {"n_steps": 30, "n_agents": 12, "start_layout": "lattice",
                                      "control_reference": "truth", "message_delay": delay}}, ROOT, seeds=2)
        return run_sweep(spec).sort_values(["seed_index", "filter"])

    base, late = rows(0), rows(3)
    for c in ["energy_end", "min_distance", "edges_removed", "final_speed_mismatch", "lambda2_min"]:
        np.testing.assert_allclose(base[c].to_numpy(), late[c].to_numpy(), rtol=1e-12, atol=1e-12, err_msg=c)
    local = (base["filter"] == "local").to_numpy()
    np.testing.assert_allclose(base[local].rmse.to_numpy(), late[local].rmse.to_numpy(), rtol=1e-12)
    kcf_base, kcf_late = base[~local].rmse.to_numpy(), late[~local].rmse.to_numpy()
    assert np.all(np.abs(kcf_late - kcf_base) > 1e-6 * kcf_base)
