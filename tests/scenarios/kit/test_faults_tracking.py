"""Faults in the two tracking scenarios with a comm graph — Sun et al. 2011 (leader–follower,
consensus information filters) and Ren & Lv 2017 (consensus IMM-UKF) — checked against facts
that do not come from the fault code: an empty comm graph, a team without sensors, a binomial
rate, a NaN that must not travel, the run's other random numbers, and the CLI's exit code."""

from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pandas as pd
import pytest
from click.testing import CliRunner
from scipy.stats import binomtest

from mcjax.cli import main
from mcjax.scenarios import ren2017
from mcjax.scenarios import sun2011 as lf
from mcjax.study import build_spec, run_sweep

ROOT = Path(__file__).resolve().parents[3]

STEPS = 25
#: Seeds of the two-point sweeps below. Ren & Lv 2017's 2 x 50 runs fill the engine's compiled
#: batch (engine.BATCH_SIZE = 100 runs), as FAULTY's sweep and test_measured_rates_are_the_params'
#: do, with the same Config: one compiled program for every sweep of that scenario in this file
#: (running 100 runs of it costs a fraction of a second; compiling it, seconds).
SEEDS = {"sun2011": 3, "ren2017": 50}
#: The error outputs every filter has (kit.error_items) and the NEES each scenario adds.
ERRORS = ("rmse", "mean_error", "final_error", "max_error", "diverged", "nonfinite", "anees")
#: Ren & Lv 2017 with the IMM (two modes) and the CV UKF (one): the CT UKF is the same one-mode
#: consensus step as the CV one with another model matrix, left out of these programs.
CASES = {"sun2011": {"planner": "none"}, "ren2017": {"filters": ["imm", "cv"]}}


def _sweep(name, zipped, config=None, params=None, seeds=None, steps=STEPS):
    seeds = SEEDS[name] if seeds is None else seeds
    spec = build_spec({"base": str(ROOT / "configs" / f"{name}.toml"),
                       "config": {"faults": "on", "n_steps": steps, **CASES[name], **(config or {})},
                       "params": params or {}, "zip": zipped}, ROOT, seeds=seeds)
    return run_sweep(spec)


def _points(df, columns):
    """The rows of point 0 and of point 1, in the same (seed, filter) order, as numpy arrays."""
    a, b = (df[df.point_id == p].sort_values(["seed_index", "filter"]) for p in (0, 1))
    assert len(a) == len(b) > 0
    return {c: (a[c].to_numpy(), b[c].to_numpy()) for c in columns}


@pytest.mark.parametrize("name", CASES)
@pytest.mark.xdist_group("test_faults_tracking")  # the Ren & Lv sweeps' one program (SEEDS): one worker
def test_every_link_lost_is_an_empty_comm_graph(name):
    """link_loss = 1 (open loop): every filter's errors are exactly those of the same runs with
    comm_radius = 0 — no message arrives, whatever carries it (one program for both points)."""
    radius = {"sun2011": 100e3, "ren2017": 450.0}[name]
    df = _sweep(name, {"link_loss": [1.0, 0.0], "comm_radius": [radius, 0.0]})
    for c, (lost, empty) in _points(df, ERRORS + ("lambda2_min", "disconnected_steps")).items():
        np.testing.assert_array_equal(lost, empty, err_msg=c)
    one = df[df.point_id == 0]
    assert (one.links_lost == 1.0).all() and (one.fault_disconnected_steps == STEPS).all()


@pytest.mark.parametrize("name", CASES)
@pytest.mark.xdist_group("test_faults_tracking")  # the Ren & Lv sweeps' one program (SEEDS): one worker
def test_every_sensor_dropped_is_a_team_without_sensors(name):
    """sensor_dropout = 1: no agent ever updates from a measurement — the errors are exactly
    those of the same runs with sensing_radius = 0 (prediction only)."""
    radius = {"sun2011": 120e3, "ren2017": 10e3}[name]
    df = _sweep(name, {"sensor_dropout": [1.0, 0.0], "sensing_radius": [radius, 0.0]})
    for c, (dropped, blind) in _points(df, ERRORS).items():
        np.testing.assert_array_equal(dropped, blind, err_msg=c)
    n = {"sun2011": 5, "ren2017": 6}[name]
    assert (df[df.point_id == 0].dropout_steps == n * STEPS).all()


def _lf_setup(planner="none"):
    cfg = lf.Config(faults="on", n_steps=40, planner=planner, plan_samples=16, plan_iterations=2)
    return cfg, lf.default_params(cfg)


def _poison(state, k, filters):
    """``state`` with agent k lost to faults and its per-agent filter states NaN."""
    poisoned = tuple(f if kind == "cif" else jax.tree.map(lambda a: a.at[k].set(jnp.nan), f)
                     for kind, f in zip(filters, state.filters))
    return state._replace(filters=poisoned, faults=state.faults._replace(alive=state.faults.alive.at[k].set(False)))


@pytest.mark.parametrize("planner, k", [("none", 2), ("random", 0)])
def test_a_lost_agents_nan_state_reaches_no_neighbour_sun2011(planner, k):
    """Agent k (the leader, 0, in the closed loop: the next UAV plans) is lost at step 5 with
    its filter states poisoned with NaN: every other agent's estimate stays finite, the lost
    one stays where it was and its error leaves the statistics."""
    cfg, params = _lf_setup(planner)
    key = jax.random.PRNGKey(3)
    state = lf.init(cfg, params, key)
    step = jax.jit(lambda s, t: lf.step(cfg, params, s, jax.random.fold_in(key, t)))
    for t in range(5):
        state, _ = step(state, t)
    state = _poison(state, k, cfg.filters)
    where = np.asarray(state.uavs[k])
    records = []
    for t in range(5, 40):
        state, rec = step(state, t)
        records.append(rec)
    others = np.arange(cfg.n_agents) != k
    for rec in records:
        assert np.isfinite(np.asarray(rec.error)[:, others]).all()
        assert np.isnan(np.asarray(rec.error)[1:, k]).all()  # (filter 0 is the CIF: no agent state)
        assert np.asarray(rec.adjacency)[k].sum() == 0
        assert np.isnan(np.asarray(rec.measurements)[k]).all()
    np.testing.assert_array_equal(np.asarray(state.uavs[k]), where)
    stacked = jax.tree.map(lambda *a: jnp.stack(a), *records)
    out = lf.reduce(cfg, stacked, params)
    assert np.isfinite(np.asarray(out["rmse"])).all() and np.asarray(out["agents_lost"]) == 1


def test_a_lost_uuvs_nan_state_reaches_no_neighbour_ren2017():
    cfg = ren2017.Config(faults="on", n_steps=30, filters=tuple(CASES["ren2017"]["filters"]))
    params = ren2017.default_params(cfg)
    key = jax.random.PRNGKey(5)
    state = ren2017.init(cfg, params, key)
    step = jax.jit(lambda s, t: ren2017.step(cfg, params, s, jax.random.fold_in(key, t)))
    for t in range(4):
        state, _ = step(state, t)
    state = _poison(state, 1, ("imm",) * len(cfg.filters))
    for t in range(4, 30):
        state, rec = step(state, t)
        assert np.isfinite(np.asarray(rec.error)[:, [0, 2, 3, 4, 5]]).all()
        assert np.isnan(np.asarray(rec.error)[:, 1]).all()


def test_faults_change_no_other_random_number():
    """With every fault on, the true target and every measurement an agent still takes are
    those of the run without faults (their own key stream). (One filter, the local one, in
    both runs: in the open loop the target and the measurements do not depend on the filters,
    and the two programs compile 3x faster than with all five.)"""
    cfg_off = lf.Config(n_steps=30, filters=("local",))
    cfg_on = lf.Config(n_steps=30, filters=("local",), faults="on")
    on = lf.default_params(cfg_on)._replace(link_loss=0.4, link_burst=3.0, sensor_dropout=0.3, agent_loss_rate=0.02)
    key = jax.random.PRNGKey(11)

    def records(cfg, params):
        def body(s, t):
            return lf.step(cfg, params, s, jax.random.fold_in(key, t))
        return jax.jit(lambda: jax.lax.scan(body, lf.init(cfg, params, key), jnp.arange(30))[1])()

    a, b = records(cfg_off, lf.default_params(cfg_off)), records(cfg_on, on)
    np.testing.assert_array_equal(np.asarray(a.target), np.asarray(b.target))
    za, zb = np.asarray(a.measurements), np.asarray(b.measurements)
    taken = np.isfinite(zb)
    assert 0 < taken.mean() < np.isfinite(za).mean()  # some were dropped, some kept
    np.testing.assert_array_equal(za[taken], zb[taken])


def _within(k, n, p):
    ci = binomtest(int(k), int(n)).proportion_ci(confidence_level=0.999)
    assert ci.low <= p <= ci.high, (k / n, p, ci)


@pytest.mark.xdist_group("test_faults_tracking")  # the Ren & Lv sweeps' one program (SEEDS): one worker
def test_measured_rates_are_the_params():
    """Over a sweep's runs, the fraction of link-steps lost, of agent-steps with a dropout and
    of agents lost by the end match the Params (binomial intervals); losses stop at min_alive."""
    seeds, steps, n, ring = 60, STEPS, 6, 6  # ren2017: six UUVs on a ring, its six links always in range
    df = _sweep("ren2017", {"link_loss": [0.25, 0.0, 0.0], "sensor_dropout": [0.2, 0.0, 0.0],
                            "agent_loss_rate": [0.0, 0.02, 0.2], "min_alive": [1, 0, 3]}, seeds=seeds, steps=steps)
    runs = [df[(df.point_id == p) & (df["filter"] == "imm")] for p in range(3)]
    _within(round(runs[0].links_lost.sum() * ring * steps), seeds * ring * steps, 0.25)
    _within(runs[0].dropout_steps.sum(), seeds * n * steps, 0.2)
    _within(runs[1].agents_lost.sum(), seeds * n, 1 - (1 - 0.02) ** steps)
    assert (runs[2].agents_lost == n - 3).all()


def _cli_error(tmp_path, lines, config):
    spec = tmp_path / "s.toml"
    spec.write_text(f'base = "{ROOT / "configs"}/sun2011.toml"\nseeds = 2\n[config]\n{config}[params]\n{lines}\n')
    out = tmp_path / "out"
    r = CliRunner().invoke(main, ["sweep", str(spec), "--out", str(out)])
    return r, out


@pytest.mark.parametrize("lines, config, field", [
    ("link_loss = 1.5", 'faults = "on"\n', "link_loss"),
    ("agent_loss_rate = -0.1", 'faults = "on"\n', "agent_loss_rate"),
    ("sensor_dropout = 2", 'faults = "on"\n', "sensor_dropout"),
    ("min_alive = 6", 'faults = "on"\n', "min_alive"),
    ("link_loss = 0.2\nlink_burst = 0.5", 'faults = "on"\n', "link_burst"),
    ("link_loss = 0.2", "", "link_loss"),  # faults off
    ("", 'faults = "yes"\n', "faults"),
])
def test_bad_fault_input_exits_2_with_one_line_naming_the_field(tmp_path, lines, config, field):
    r, out = _cli_error(tmp_path, lines, config)
    assert r.exit_code == 2, r.output
    text = r.output.strip()
    assert len(text.splitlines()) == 1 and field in text, text
    assert not out.exists()


FAULTY = """base = "{base}"
seeds = 50
chunk_size = 4
[config]
faults = "on"
n_steps = 25
filters = ["imm", "cv"]
[params]
link_burst = 3.0
agent_loss_rate = 0.03
sensor_dropout = 0.1
[grid]
link_loss = [0.1, 0.4]
"""


def faulty_spec(folder: Path) -> Path:
    """A small Ren & Lv 2017 sweep with every fault drawn (two points, 50 seeds: one batch of the
    engine's 100 runs; chunks of 4 runs asked for, rounded up to the batch): the Config and the
    compiled program of the other Ren & Lv sweeps of this file (CASES)."""
    path = folder / "faulty.toml"
    path.write_text(FAULTY.format(base=ROOT / "configs" / "ren2017.toml"))
    return path


@pytest.mark.xdist_group("test_faults_tracking")  # the Ren & Lv sweeps' one program (SEEDS): one worker
def test_same_faults_on_one_or_two_devices(tmp_path):
    """The fault draws follow the run keys: the dataset of a faulty sweep is the same in this
    process (one device) and in a CLI process with two CPU devices (and another chunk size)."""
    import os
    import subprocess
    import sys

    from mcjax.base.parquet import read_table

    spec = faulty_spec(tmp_path)
    r = CliRunner().invoke(main, ["sweep", str(spec), "--out", str(tmp_path / "one")])
    assert r.exit_code == 0, r.output
    env = {**os.environ, "MCJAX_CPU_DEVICES": "2"}
    subprocess.run([sys.executable, "-m", "mcjax.cli", "sweep", str(spec), "--out", str(tmp_path / "two"),
                    "--chunk-size", "12"], check=True, env=env, timeout=600, capture_output=True)
    one, two = read_table(tmp_path / "one"), read_table(tmp_path / "two")
    assert one.agents_lost.sum() > 0 and one.dropout_steps.sum() > 0 and one.links_lost.min() > 0
    pd.testing.assert_frame_equal(one, two, check_exact=True)


def test_the_docs_faulty_sensors_example(tmp_path):
    """docs/library.md's faulty_sensors example runs as written: with every link lost the
    shared filter is the local one exactly, with the radio working it beats it, and with
    every sensor dropped out no filter ever updates (the prior, predicted: the same numbers)."""
    import re

    text = (ROOT / "docs" / "library.md").read_text(encoding="utf-8")
    blocks = re.findall(r"```(?:python|toml)\n(.*?)```", text.split("## Faults in a scenario of your own")[1], re.S)
    for name, body in zip(("faulty_sensors.py", "faulty_sensors.toml", "faulty_sweep.toml"), blocks):
        (tmp_path / name).write_text(body, encoding="utf-8")
    from mcjax.study import load_spec

    study = load_spec(tmp_path / "faulty_sweep.toml", seeds=20)
    df = run_sweep(study)
    rm = {(round(loss, 2), f): g.sort_values("seed_index").rmse.to_numpy()
          for (loss, f), g in df.groupby(["link_loss", "filter"])}
    np.testing.assert_array_equal(rm[(1.0, "shared")], rm[(1.0, "local")])
    assert rm[(0.0, "shared")].mean() < 0.8 * rm[(0.0, "local")].mean()
    assert (df[df.link_loss == 1.0].links_lost == 1.0).all()
    # 80 seeds: the 4 x 20 runs of the sweep above, so the same compiled batch program
    blind = build_spec({"base": str(tmp_path / "faulty_sensors.toml"), "params": {"sensor_dropout": 1.0}},
                       tmp_path, seeds=80)
    none = run_sweep(blind)
    by = {f: g.sort_values("seed_index").rmse.to_numpy() for f, g in none.groupby("filter")}
    np.testing.assert_array_equal(by["shared"], by["local"])  # no fix: both only predict, from the same prior
    assert (none.dropout_steps == 4 * 60).all()
