"""The scenario contract: declarations, validation derived from them, the registry and plugins,
the README's "Writing a scenario" example and two more example scenarios run through
`mcjax sweep` and `mcjax report`, and the layering of the package."""


import re
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from click.testing import CliRunner

from mcjax import scenarios
from mcjax.base.parquet import read_metadata, read_table
from mcjax.cli import main
from mcjax.contract import Output, Param, Scenario, Setting, config_type, declare, params_type
from mcjax.scenarios import ren2017, sun2011

ROOT = Path(__file__).parents[2]


# ----------------------------------------------------------------------------- declarations


def test_setting_and_param_checks_name_the_allowed_values():
    s = Setting(3, "iterations", low=1, integer=True)
    assert s.problem(3) is None
    assert s.problem(0) == "must be an integer >= 1; got 0"
    assert s.problem(2.5) == "must be an integer >= 1; got 2.5"
    c = Setting("a", "kind", choices=("a", "b"))
    assert c.problem("c") == "must be one of a, b; got 'c'"
    m = Setting(("a",), "kinds", choices=("a", "b"), many=True)
    assert m.problem(("a", "b")) is None
    assert m.problem(("a", "a")).startswith("must be a non-empty list of distinct values from a, b")
    assert m.problem(()) is not None
    p = Param(1.0, "m", "radius", low=0.0, low_open=True, per_agent=True)
    assert p.problem(2.0, 3) is None and p.problem([1.0, 2.0, 3.0], 3) is None
    assert p.problem(0.0, 3) == "must be > 0 m; got 0.0"
    assert p.problem([1.0, 2.0], 3) == "must be a number or a list of n_agents = 3 numbers; got [1.0, 2.0]"
    assert p.problem(float("nan")) == "must be finite; got nan"
    assert p.problem("x") == "must be a number or a list of numbers; got the string 'x'"  # what it got, by kind
    assert p.problem("2.5") == ("must be a number or a list of numbers; got the string '2.5' (a number is written "
                                "without quotes: 2.5)")
    assert s.problem(True) == "must be an integer >= 1; got the boolean true"
    shaped = Param(np.zeros((2, 2)), "m", "positions", shape=("n", 2))
    assert shaped.problem(np.zeros((3, 2)), 3) is None
    assert "of shape n_agentsx2 (3x2)" in shaped.problem(np.zeros((2, 2)), 3)
    flag = Param(1.0, "", "alive", choices=(0, 1))
    assert flag.problem([1, 0], None) is None and flag.problem(0.5) == "must be 0 or 1; got 0.5"


def test_config_type_validates_every_field_and_is_hashable():
    Cfg = config_type("Cfg", dict(n_agents=Setting(2, "agents", low=1, integer=True),
                                  n_steps=Setting(5, "steps", low=1, integer=True),
                                  filters=Setting(("a",), "filters", choices=("a", "b"), many=True)),
                      __name__, lambda c: None)
    c = Cfg(filters=["b", "a"])
    assert c.filters == ("b", "a") and hash(c) == hash(Cfg(filters=("b", "a")))
    with pytest.raises(ValueError, match=r"^n_agents must be an integer >= 1; got 0$"):
        Cfg(n_agents=0)
    with pytest.raises(ValueError, match="filters must be a non-empty list"):
        Cfg(filters=("c",))


def test_every_builtin_scenario_declares_every_field_and_output():
    from mcjax.scenarios import BUILTIN

    assert set(BUILTIN) == {"leader_follower", "uuv_imm", "urban_bearing", "flocking", "wind_formation"}
    for sc in BUILTIN.values():
        cfg = sc.Config()
        assert list(sc.Params._fields) == list(sc.params_table)
        for name, p in sc.params_table.items():  # every default passes its own declaration
            assert p.unit is not None and p.description, (sc.name, name)
            assert p.problem(p.default_value(cfg), cfg.n_agents) is None, (sc.name, name)
        outs = sc.outputs(cfg)
        assert [k for k, o in outs.items() if o.role == "error"] == ["rmse"]
        assert all(o.role is None or o.role in ("error", "divergence", "nonfinite", "connectivity_mean",
                                                  "connectivity_min", "disconnected_steps", "nees")
                   for o in outs.values())
        # a NEES / NIS declares the degrees of freedom of its chi-square (the report's band)
        assert all(o.dof >= 1 for o in outs.values() if o.role in ("nees", "nis"))
        meta = sc.metadata(cfg)
        assert meta["filters"] == list(cfg.filters) and set(meta["params"]) == set(sc.params_table)
        # every filter kind the scenario offers has plain words (the report's glossary), no code in them
        kinds = sc.settings["filters"].choices  # the kinds its Config offers
        assert set(sc.filter_words) == set(kinds), sc.name
        assert all(len(w) > 20 and not re.search(r"\w+\.\w+\(|cfg\.|params\.|_step\b", w)
                   for w in sc.filter_words.values()), sc.name
        assert meta["filter_descriptions"] == {f: sc.filter_words[f] for f in cfg.filters}


@pytest.mark.parametrize("config", ["sun2011", "ren2017", "chen2022", "lou2013", "chen2013"])
def test_no_state_entry_turns_per_run_in_the_first_step(config):
    """Under the engine's vmap, an init state entry shared by all runs (a constant) that the
    step makes per-run costs a second batching of the time loop's body (~2 s of tracing for
    the closed loop): such entries start per-run (kit.per_run). A new state field that starts
    as a constant shows up here."""
    import jax
    from jax._src.interpreters import batching

    from mcjax import engine
    from mcjax.study import load_config_file

    sc, cfg, values = load_config_file(Path(__file__).resolve().parents[2] / "configs" / f"{config}.toml")
    params, keys = engine.chunk_inputs(engine.stack_points([sc.default_params(cfg, **values)]), 2, 0, 0, 2, 2)

    def per_run(x):
        return isinstance(x, batching.BatchTracer) and isinstance(x.batch_dim, int)

    turned = []

    def one(p, k):
        state = sc.init(cfg, p, engine.init_key(k))
        after, _ = sc.step(cfg, p, state, jax.random.fold_in(k, 1))
        before = jax.tree_util.tree_flatten_with_path(state)[0]
        turned.extend(jax.tree_util.keystr(path) for (path, a), b in zip(before, jax.tree.leaves(after))
                      if not per_run(a) and per_run(b))
        assert any(per_run(b) for b in jax.tree.leaves(after))  # the check sees per-run entries at all
        return 0

    jax.make_jaxpr(jax.vmap(one))(params, keys)
    assert turned == []


def test_per_run_keeps_the_values_bits():
    import jax
    import jax.numpy as jnp

    from mcjax.scenarios import kit

    x = jnp.array([-0.0, 1.5, jnp.nan, jnp.inf])
    for like in (1.0, jnp.nan, jnp.array([jnp.nan, 2.0])):
        y, flag = kit.per_run(like, x, jnp.asarray(True))
        assert y.shape == x.shape and np.array_equal(np.asarray(y).view(np.uint64), np.asarray(x).view(np.uint64))
        assert bool(flag)
    batched = jax.vmap(lambda p: kit.per_run(p, x))(jnp.array([1.0, jnp.nan, 3.0]))
    assert batched.shape == (3, 4) and np.array_equal(np.asarray(batched), np.tile(np.asarray(x), (3, 1)), equal_nan=True)


def test_default_params_rejects_unknown_fields():
    with pytest.raises(ValueError, match=r"unknown Params field\(s\) \['nope'\]; allowed: dt, "):
        sun2011.SCENARIO.default_params(nope=1.0)


def test_undeclared_outputs_are_named():
    from mcjax.study import run_rows

    sc = ren2017.SCENARIO
    cfg = sc.Config(n_agents=2, filters=("cv",))
    with pytest.raises(ValueError, match=r"undeclared: \['extra'\], declared but missing: \['rmse'"):
        run_rows(sc, cfg, {"extra": np.zeros(3)}, {"seed_index": np.arange(3)})


def test_dropped_out_agents_count_in_no_team_statistic():
    """kit.error_summary over 2 alive + 1 dropped agent equals plain numpy over the 2 alive."""
    from mcjax.scenarios.kit import error_summary

    rng = np.random.default_rng(0)
    e = rng.uniform(0, 10, size=(20, 2, 3))
    e[:, :, 2] = 1e6  # the dropped agent's (meaningless) error
    out = error_summary(e, np.array([1.0, 1.0, 0.0]), 4, 9.5)
    alive = e[4:, :, :2]
    np.testing.assert_allclose(out["rmse"], np.sqrt((alive**2).mean(axis=(0, 2))), rtol=1e-12)
    np.testing.assert_allclose(out["mean_error"], alive.mean(axis=(0, 2)), rtol=1e-12)
    np.testing.assert_allclose(out["max_error"], alive.max(axis=(0, 2)), rtol=1e-12)
    np.testing.assert_allclose(out["final_error"], e[-1, :, :2].mean(-1), rtol=1e-12)
    np.testing.assert_array_equal(out["diverged"], (alive > 9.5).any(axis=(0, 2)))
    none = error_summary(e, np.zeros(3), 4, 9.5)
    assert np.all(np.isnan(none["rmse"])) and not np.any(none["diverged"])


# ----------------------------------------------------------------------------- README example


def _readme_example(tmp_path):
    """Write docs/library.md's "Writing a scenario" files (scenario, config, sweep) into tmp_path
    (the example moved there from the README)."""
    text = (ROOT / "docs" / "library.md").read_text()
    section = text.split("## Writing a scenario", 1)[1].split("\n## ", 1)[0]
    files = re.findall(r"`([\w.]+)`:\n\n```(?:python|toml)\n(.*?)```", section, flags=re.S)
    assert [f for f, _ in files] == ["static_sensors.py", "static_sensors.toml", "static_sweep.toml",
                                     "static_claims.toml", "static_tune.toml"]
    for name, body in files:
        (tmp_path / name).write_text(body)
    return section


def test_readme_example_scenario_runs_through_sweep_and_report(tmp_path):
    section = _readme_example(tmp_path)
    assert len((tmp_path / "static_sensors.py").read_text().splitlines()) <= 80  # a few dozen lines
    out = tmp_path / "out"
    r = CliRunner().invoke(main, ["sweep", str(tmp_path / "static_sweep.toml"), "--out", str(out),
                                  "--seeds", "20"])
    assert r.exit_code == 0, r.output
    df = read_table(out)
    assert len(df) == 3 * 20 * 2 and set(df["filter"]) == {"local", "pooled"}
    assert not any(c.startswith("lambda2") for c in df.columns)  # no comm graph, no graph columns
    # the physics: pooling every sensor's fixes beats one's own at every sensing radius
    m = df.groupby(["sensing_radius", "filter"])["rmse"].mean().unstack()
    assert (m["pooled"] < m["local"]).all()
    # a random-walk KF's steady error is of the order of the measurement noise (2 m), not 0 or 100
    assert 0.5 < m.loc[40.0, "pooled"] < 2.0 and m.loc[40.0, "local"] < 3.0
    meta = read_metadata(out)
    assert meta["outputs"]["rmse"]["unit"] == "m" and meta["filters"] == ["local", "pooled"]
    rep = CliRunner().invoke(main, ["report", str(out)])
    assert rep.exit_code == 0, rep.output
    assert "rmse" in rep.output and "lambda2" not in rep.output
    assert (out / "report").is_dir() and list((out / "report").glob("*.png"))
    assert "mcjax sweep static_sweep.toml" in section and "mcjax report" in section


def test_docs_example_claims_file_gives_the_verdicts_the_docs_state(tmp_path):
    """docs/library.md's claims file through `mcjax check` as written (200 seeds): the two claims it
    says hold, hold; the third is undecided with the runs the docs quote; the numbers it quotes
    are the check's."""
    section = _readme_example(tmp_path)
    assert "mcjax check static_claims.toml" in section
    out = tmp_path / "check"
    r = CliRunner().invoke(main, ["check", str(tmp_path / "static_claims.toml"), "--out", str(out)])
    assert r.exit_code == 0, r.output
    table = pd.read_parquet(out / "claims.parquet").set_index("id")
    assert list(table["verdict"]) == ["holds", "holds", "undecided"]
    assert table.loc["pooled-never-diverges", "runs_to_decide"] == 381 and "(381:" in section
    low, high = table.loc["pooling-helps-at-20m", ["low", "high"]]
    assert f"[{low:.2f}, {high:.2f}]".replace("-", "−") in section


def test_docs_example_scenario_tunes(tmp_path):
    """The docs' example tunes (its relaxation switch): the filters' assumed random-walk step
    goes from 0.2 m to near the target's true 1 m (the KF's error is least at the true process
    noise, a textbook fact) and the held-out RMSE falls, paired by seed. Fewer held-out seeds
    than the docs' file, the same training."""
    section = _readme_example(tmp_path)
    assert "mcjax tune static_tune.toml" in section
    spec = tmp_path / "static_tune.toml"
    spec.write_text(spec.read_text().replace("heldout_seeds = 500", "heldout_seeds = 40"))
    out = tmp_path / "tune"
    r = CliRunner().invoke(main, ["tune", str(spec), "--out", str(out)])
    assert r.exit_code == 0, r.output
    q = float(re.search(r"^q: 0\.2 -> ([0-9.]+)$", r.output, flags=re.M).group(1))
    assert 0.8 < q < 1.25, r.output
    paired = re.search(r"^pooled +rmse +[0-9.]+ +[0-9.]+ +(-[0-9.]+) +(-[0-9.]+) +(-[0-9.]+) +40$", r.output, re.M)
    assert paired is not None and float(paired.group(3)) < 0, r.output  # the whole interval below 0


# ----------------------------------------------------------------------------- two more examples

SINGLE_AGENT = '''
"""One agent, no comm graph: a 1-D random walk tracked by one Kalman filter (error in m)."""
import jax, jax.numpy as jnp
from mcjax.contract import Output, Param, Scenario, config_type, declare, params_type
from mcjax.scenarios.kit import check_common, common_settings, error_items

Config = config_type("Config", common_settings(filter_kinds=("kf",), n_agents=1, n_steps=40, warmup_steps=2,
                                               divergence_threshold=100.0), __name__, check_common)
Params = params_type("Params", dict(q=Param(1.0, "m", "walk std", low=0), r=Param(1.0, "m", "noise std",
                                    low=0, low_open=True)), __name__)

def init(cfg, p, key):
    return (jnp.zeros(()), jnp.zeros(()), jnp.ones(()))

def step(cfg, p, s, key):
    t, x, P = s
    k1, k2 = jax.random.split(key)
    t = t + p.q * jax.random.normal(k1)
    z = t + p.r * jax.random.normal(k2)
    P = P + p.q**2
    K = P / (P + p.r**2)
    x, P = x + K * (z - x), (1 - K) * P
    return (t, x, P), jnp.abs(x - t).reshape(1, 1)

def summary(cfg, e, p):
    return declare(**error_items(lambda: e, lambda: jnp.ones(1), cfg, "m"))

SCENARIO = Scenario(name="single_agent", title="one agent, no graph", Config=Config, Params=Params, init=init,
                    step=step, summary=summary)
'''

WIND = '''
"""Three agents averaging noisy wind measurements over a ring (error in m/s, with graph statistics)."""
import jax, jax.numpy as jnp
from mcjax.contract import Output, Param, Scenario, config_type, declare, params_type
from mcjax.scenarios.kit import check_common, common_settings, error_items, graph_items
from mcjax.tracking import graph

Config = config_type("Config", common_settings(filter_kinds=("mean", "consensus"), n_agents=3, n_steps=30,
                                               warmup_steps=2, divergence_threshold=50.0, error_unit="m/s"),
                     __name__, check_common)
Params = params_type("Params", dict(
    noise=Param(2.0, "m/s", "wind sensor noise std", low=0, low_open=True),
    comm_radius=Param(1.5, "m", "comm radius (agents sit 1 m apart on a line)", low=0)), __name__)

def init(cfg, p, key):
    return (jnp.zeros(()), jnp.zeros((2, cfg.n_agents)))

def step(cfg, p, s, key):
    k, est = s
    wind = 10.0
    z = wind + p.noise * jax.random.normal(key, (cfg.n_agents,))
    adj = graph.adjacency(jnp.stack([jnp.arange(3.0), jnp.zeros(3)], -1), p.comm_radius)
    W = graph.consensus_weights(adj, "metropolis")
    k = k + 1
    own = est[0] + (z - est[0]) / k
    mixed = W @ (est[1] + (z - est[1]) / k)
    est = jnp.stack([own, mixed])
    return (k, est), (jnp.abs(est - wind), graph.algebraic_connectivity(adj))

def summary(cfg, rec, p):
    return declare(**error_items(lambda: rec[0], lambda: jnp.ones(cfg.n_agents), cfg, "m/s", "wind error"),
                   **graph_items(lambda: rec[1]))

SCENARIO = Scenario(name="wind_demo", title="wind averaging demo", Config=Config, Params=Params, init=init,
                    step=step, summary=summary)
'''


def _example(tmp_path, name, source, grid):
    (tmp_path / f"{name}.py").write_text(textwrap.dedent(source))
    (tmp_path / f"{name}.toml").write_text(f'scenario = "{name}.py:SCENARIO"\nseeds = 8\n')
    (tmp_path / f"{name}_sweep.toml").write_text(f'base = "{name}.toml"\n[grid]\n{grid}\n')
    out = tmp_path / f"out_{name}"
    r = CliRunner().invoke(main, ["sweep", str(tmp_path / f"{name}_sweep.toml"), "--out", str(out)])
    assert r.exit_code == 0, r.output
    rep = CliRunner().invoke(main, ["report", str(out), "--format", "markdown"])
    assert rep.exit_code == 0, rep.output
    return out, r.output, rep.output


def test_single_agent_scenario_without_graph_reports(tmp_path):
    out, sweep_out, report_out = _example(tmp_path, "single_agent", SINGLE_AGENT, "r = [0.5, 2.0]")
    df = read_table(out)
    assert not any(c.startswith("lambda2") or c == "disconnected_steps" for c in df.columns)
    m = df.groupby("r")["rmse"].mean()
    assert m[0.5] < m[2.0]  # noisier sensor, larger error
    for text in (sweep_out, report_out):
        assert "m/s" not in text and "lambda2" not in text
    assert re.search(r"rmse.*\bm\b", report_out)
    names = {p.name for p in (out / "report").glob("*.png")}
    assert names and not any("lambda2" in n or "connectivity" in n for n in names)


def test_error_metric_in_m_per_s_is_labelled_so(tmp_path):
    out, sweep_out, report_out = _example(tmp_path, "wind_demo", WIND, "noise = [1.0, 4.0]")
    meta = read_metadata(out)
    assert meta["outputs"]["rmse"]["unit"] == "m/s" and meta["params"]["noise"]["unit"] == "m/s"
    assert "m/s" in report_out and "[m]" not in report_out
    df = read_table(out)
    m = df.groupby(["noise", "filter"])["rmse"].mean().unstack()
    assert (m["consensus"] < m["mean"]).all()  # averaging over neighbours beats one's own average
    assert (df["lambda2_min"] > 0).all()  # a connected line of three


# ----------------------------------------------------------------------------- registry and plugins


def test_unknown_scenario_lists_the_known_ones(tmp_path):
    cfg = tmp_path / "c.toml"
    cfg.write_text('scenario = "nope"\n')
    spec = tmp_path / "s.toml"
    spec.write_text('base = "c.toml"\n')
    r = CliRunner().invoke(main, ["sweep", str(spec), "--out", str(tmp_path / "o")])
    assert r.exit_code == 2
    assert "scenario must be one of leader_follower, uuv_imm" in r.output and "'nope'" in r.output
    r = CliRunner().invoke(main, ["list", "nope"])
    assert r.exit_code == 2 and "leader_follower" in r.output


def _plugin(tmp_path) -> Path:
    """An installed distribution in a folder: a package plus a .dist-info with the entry point."""
    site = tmp_path / "site"
    pkg = site / "mcjax_demo_plugin"
    pkg.mkdir(parents=True)
    (pkg / "__init__.py").write_text(textwrap.dedent(SINGLE_AGENT).replace('name="single_agent"',
                                                                           'name="demo_plugin"'))
    info = site / "mcjax_demo_plugin-0.1.dist-info"
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: mcjax-demo-plugin\nVersion: 0.1\n")
    (info / "entry_points.txt").write_text("[mcjax.scenarios]\ndemo_plugin = mcjax_demo_plugin:SCENARIO\n")
    return site


def test_plugin_scenario_registers_through_entry_points(tmp_path, monkeypatch):
    site = _plugin(tmp_path)
    monkeypatch.syspath_prepend(str(site))
    assert "demo_plugin" in scenarios.known()
    r = CliRunner().invoke(main, ["list"])
    assert r.exit_code == 0 and "demo_plugin" in r.output and "one agent, no graph" in r.output
    (tmp_path / "p.toml").write_text('scenario = "demo_plugin"\nseeds = 4\n')
    (tmp_path / "s.toml").write_text('base = "p.toml"\n[grid]\nq = [0.5, 1.0]\n')
    r = CliRunner().invoke(main, ["sweep", str(tmp_path / "s.toml"), "--out", str(tmp_path / "o")])
    assert r.exit_code == 0, r.output
    assert len(read_table(tmp_path / "o")) == 8 and read_metadata(tmp_path / "o")["scenario"] == "demo_plugin"


def test_plugin_is_seen_by_a_real_process(tmp_path):
    import os

    site = _plugin(tmp_path)
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(site), os.environ.get("PYTHONPATH", "")])}
    r = subprocess.run([sys.executable, "-m", "mcjax.cli", "list", "demo_plugin"], capture_output=True, text=True,
                       env=env, timeout=300)
    assert r.returncode == 0, r.stderr
    assert "demo_plugin: one agent, no graph" in r.stdout and "walk std" in r.stdout


# ----------------------------------------------------------------------------- architecture

def test_graph_functions_give_float64_for_float64_input_in_a_fresh_process():
    """After mcjax.configure(), float64 input computes in float64 and float32 in float32;
    without it (importing mcjax changes no JAX setting) the library says so in one warning."""
    use = ("import numpy as np\nfrom mcjax.tracking.graph import algebraic_connectivity, laplacian\n"
           "a = np.ones((4, 4)) - np.eye(4)\n"
           "print(algebraic_connectivity(a).dtype, laplacian(a).dtype,"
           " algebraic_connectivity(a.astype(np.float32)).dtype)")
    r = subprocess.run([sys.executable, "-c", "import mcjax; mcjax.configure()\n" + use], capture_output=True,
                       text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    assert r.stdout.split() == ["float64", "float64", "float32"]
    r = subprocess.run([sys.executable, "-W", "always::UserWarning", "-c", use], capture_output=True, text=True,
                       timeout=300)
    assert r.returncode == 0, r.stderr
    assert r.stdout.split() == ["float32", "float32", "float32"]
    assert r.stderr.count("64-bit mode is off") == 1 and "mcjax.configure()" in r.stderr, r.stderr


def test_base_values_are_rechecked_against_the_specs_config(tmp_path):
    """The base config's per-agent values must fit a spec that changes n_agents."""
    spec = tmp_path / "s.toml"
    spec.write_text(f'base = "{ROOT / "configs" / "sun2011.toml"}"\n[config]\nn_agents = 3\n')
    r = CliRunner().invoke(main, ["sweep", str(spec), "--dry-run"])
    assert r.exit_code == 2
    assert "sun2011.toml: params.initial_positions: must be of shape n_agentsx2 (3x2)" in r.output


def test_configs_and_params_pickle():
    """Config and Params built from declarations survive pickling (worker processes need it)."""
    import pickle

    from mcjax.scenarios import BUILTIN

    for sc in BUILTIN.values():
        cfg = sc.Config(n_steps=30)
        again = pickle.loads(pickle.dumps(cfg))
        assert again == cfg and hash(again) == hash(cfg) and type(again) is sc.Config
        p = pickle.loads(pickle.dumps(sc.default_params(cfg)))
        assert type(p) is sc.Params and all(np.array_equal(a, b) for a, b in zip(p, sc.default_params(cfg)))


# ----------------------------------------------------------------------------- the contract at construction


def _toy(**changes):
    """A minimal valid scenario's fields (``changes`` replace some; ``outputs=`` / ``series_outputs=``:
    a summary / series declaring those outputs, each with a zero value)."""
    from mcjax.scenarios.kit import check_common, common_settings

    fields = dict(name="toy", title="toy", Config=config_type("Config", common_settings(
        filter_kinds=("kf",), n_agents=1, n_steps=4, warmup_steps=0, divergence_threshold=1.0), __name__,
        check_common), Params=params_type("Params", dict(q=Param(1.0, "m", "q")), __name__),
        init=lambda cfg, p, key: 0.0, step=lambda cfg, p, s, key: (s, s), summary=_summary)
    for given, field in (("outputs", "summary"), ("series_outputs", "series")):
        if given in changes:
            declared = changes.pop(given)
            changes[field] = lambda cfg, r, p, declared=declared: {k: (o, lambda: 0.0) for k, o in declared.items()}
    fields.update(changes)
    return fields


def test_an_unknown_role_fails_at_construction_in_one_line():
    bad = {"rmse": Output("m", "error", True, "error"), "spread": Output("m", "spread", True, "erorr")}
    with pytest.raises(ValueError) as err:
        Scenario(**_toy(outputs=bad))
    message = str(err.value)
    assert "\n" not in message and "'spread'" in message and "'erorr'" in message
    assert "scenario 'toy'" in message and "allowed roles: error, divergence, nonfinite" in message


@pytest.mark.parametrize("roles", [(None, None), ("error", "error")])
def test_zero_or_two_error_roles_fail_at_construction(roles):
    outs = {f"o{i}": Output("m", "an output", True, r) for i, r in enumerate(roles)}
    with pytest.raises(ValueError, match="role 'error'") as err:
        Scenario(**_toy(outputs=outs))
    assert "\n" not in str(err.value)


def test_bad_output_fields_and_timeseries_roles_fail_at_construction():
    for bad, field in ((Output(1, "x"), "unit"), (Output("m", "x", "yes"), "per_filter"), (("m", "x"), "Output(")):
        with pytest.raises(ValueError, match=re.escape(field)):
            Scenario(**_toy(outputs={"rmse": Output("m", "e", True, "error"), "other": bad}))
    with pytest.raises(ValueError, match=r"timeseries_outputs\(Config\(\)\): output 'e' has the unknown role 'x'"):
        Scenario(**_toy(series_outputs={"e": Output("m", "e", role="x")}))


@pytest.mark.parametrize("missing", ["n_agents", "n_steps", "filters"])
def test_a_config_without_a_required_field_is_a_value_error(missing):
    settings = dict(n_agents=Setting(1, "agents", low=1, integer=True), n_steps=Setting(4, "steps", low=1, integer=True),
                    filters=Setting(("kf",), "filters", choices=("kf",), many=True))
    del settings[missing]
    with pytest.raises(ValueError, match=f"Config must declare '{missing}'"):
        Scenario(**_toy(Config=config_type("Config", settings, __name__)))


def test_a_summary_is_the_one_way_to_declare_outputs():
    with pytest.raises(ValueError, match="summary is missing"):
        Scenario(**_toy(summary=None))
    # reduce and outputs derive from the summary; a scenario written against the earlier contract gets one line
    with pytest.raises(ValueError) as err:
        Scenario(**_toy(reduce=lambda cfg, r, p: {}))
    message = str(err.value)
    assert "\n" not in message and "reduce= is no longer a field" in message and "summary=" in message
    assert "docs/library.md" in message and "CHANGELOG.md" in message
    fields = {k: v for k, v in _toy().items() if k != "summary"}
    with pytest.raises(ValueError, match="timeseries= and timeseries_outputs= are no longer fields .* series="):
        Scenario(**fields, summary=_summary, timeseries=lambda cfg, r, p: {}, timeseries_outputs=lambda cfg: {})
    with pytest.raises(ValueError, match="output 'x' must be"):
        declare(x=Output("m", "x"))


def _summary(cfg, records, params):
    """A scenario's outputs declared once: the kit's error summary and one more output."""
    from functools import cache

    from mcjax.scenarios import kit

    errors = cache(lambda: np.asarray(records)[..., None])
    return declare(**kit.error_items(errors, lambda: np.ones(1), cfg, "m"),
                   last=(Output("m", "the last error", False), lambda: errors()[-1, 0, 0]))


def test_a_summary_declares_each_output_once_for_outputs_and_reduce():
    import jax.numpy as jnp

    sc = Scenario(**_toy())
    cfg = sc.Config()
    values = sc.reduce(cfg, jnp.array([[0.5], [2.0], [1.0]]), sc.default_params(cfg))
    declared = sc.outputs(cfg)
    assert list(values) == list(declared) == [*kit_error_names(), "last"]
    assert declared["rmse"].role == "error" and declared["last"] == Output("m", "the last error", False)
    assert float(values["last"]) == 1.0 and np.allclose(values["rmse"], np.sqrt((0.25 + 4 + 1) / 3))
    for sc in scenarios.BUILTIN.values():  # the built-in scenarios are declared so too
        assert sc.summary is not None and sc.series is not None


def kit_error_names():
    from mcjax.scenarios.kit import error_outputs

    return list(error_outputs())


@pytest.mark.parametrize("name", ["leader_follower", "uuv_imm", "urban_bearing", "flocking", "wind_formation"])
def test_builtin_reduce_and_timeseries_give_exactly_the_declared_outputs(name):
    import jax

    sc = scenarios.BUILTIN[name]
    cfg = sc.Config(n_steps=3, warmup_steps=0)
    p = sc.default_params(cfg)
    # shapes only (traced, not compiled): the records of three steps, then what reduce and timeseries make of them
    state = jax.eval_shape(lambda: sc.init(cfg, p, jax.random.PRNGKey(0)))
    keys = jax.random.split(jax.random.PRNGKey(1), 3)
    records = jax.eval_shape(lambda s: jax.lax.scan(lambda s, k: sc.step(cfg, p, s, k), s, keys)[1], state)
    out = jax.eval_shape(lambda r: sc.reduce(cfg, r, p), records)
    series = jax.eval_shape(lambda r: sc.timeseries(cfg, r, p), records)
    F = len(cfg.filters)
    assert sorted(out) == sorted(sc.outputs(cfg)) and sorted(series) == sorted(sc.timeseries_outputs(cfg))
    for key, o in sc.outputs(cfg).items():
        assert out[key].shape == ((F,) if o.per_filter else ()), key
    for key, o in sc.timeseries_outputs(cfg).items():
        assert series[key].shape == ((3, F) if o.per_filter else (3,)), key


def test_a_file_scenario_of_the_earlier_contract_gets_one_line_and_exit_2(tmp_path):
    """A user's scenario file still passing ``reduce=`` / ``outputs=``: `mcjax list` and `mcjax run` say in one
    line what replaced them and where to read (not a TypeError traceback)."""
    from click.testing import CliRunner

    from mcjax.cli import main

    (tmp_path / "old.py").write_text(
        "import dataclasses\nfrom mcjax.scenarios import sun2011\n"
        "fields = {f.name: getattr(sun2011.SCENARIO, f.name) for f in dataclasses.fields(sun2011.SCENARIO) if f.init}\n"
        "del fields['summary']\n"
        "SCENARIO = type(sun2011.SCENARIO)(**{**fields, 'name': 'old'}, reduce=lambda c, r, p: {}, "
        "outputs=lambda c: {})\n")
    (tmp_path / "old.toml").write_text('scenario = "old.py:SCENARIO"\n')
    for args in (["list", str(tmp_path / "old.py") + ":SCENARIO"], ["run", str(tmp_path / "old.toml"), "--seeds", "2"]):
        r = CliRunner().invoke(main, args)
        assert r.exit_code == 2, r.output
        lines = r.output.strip().splitlines()
        assert len(lines) == 1 and "Traceback" not in r.output, r.output
        assert "reduce= and outputs= are no longer fields" in lines[0] and "summary=" in lines[0], lines[0]
        assert "docs/library.md" in lines[0], lines[0]
