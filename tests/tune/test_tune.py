"""``mcjax tune``: gradients through the loop, the [tune] table, resume, the CLI.

Compilation is what costs here (the file's budget is 60 s), so every test of the scenario
shares ONE small gradient program (an open-loop leader_follower run of 4 steps with 2 UAVs
and the modified ICF: its gradient goes through the dynamics, the smooth sensing gate, the
smooth comm graph and component sizes, the consensus filter and the loss) and ONE exact
program (the held-out evaluation of the CLI test). The gradient truncation
(``gradient_window``) is checked exactly on a toy scenario that compiles in a second; reverse
mode adds one more program of the same small run. The planner's own derivative (α_I, α_L, α_C
through its unrolled Adam) is checked on the planner alone in tests/tracking/test_planning.py: through
the closed loop it compiles for minutes on a loaded 2-core machine (docs/tune.md).
"""

from __future__ import annotations

import json
import textwrap
import threading
from pathlib import Path
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import pandas as pd
import pytest
from click.testing import CliRunner

from mcjax import scenarios, tune
from mcjax.cli import main
from mcjax.contract.relaxation import Relaxation
from mcjax.study import SpecError

ROOT = Path(__file__).resolve().parents[2]
BASE = (ROOT / "configs" / "sun2011.toml").as_posix()

#: The shared small program: 2 UAVs, 4 steps, open loop, modified ICF only, 2 training runs.
SPEC = f"""
base = "{BASE}"
[config]
n_agents = 2
n_steps = 4
warmup_steps = 1
filters = ["modified_icf"]
planner = "none"
[params]
comm_radius = 70e3
initial_positions = [[20e3, 150e3], [80e3, 150e3]]
initial_headings = [0.0, 0.0]   # one per UAV, so a test may turn one away (same program)
alive = [1, 1]
[tune]
steps = 2
learning_rate = 0.05
train_seeds = 2
train_base_seed = 1
heldout_seeds = 3
heldout_base_seed = 0
checkpoint_every = 4
[tune.params.comm_radius]
low = 20e3
high = 200e3
scale = "log"
[tune.params.sensing_radius]
low = 50e3
high = 400e3
scale = "log"
[tune.params.sigma_accel]
low = 1.0
high = 500.0
scale = "log"
[tune.params.uav_speed]
low = 500.0
high = 1200.0
[tune.loss]
filter = "modified_icf"
divergence_temperature = 200.0
[tune.relaxation]
sensing = 2000.0
comm = 2000.0
"""


def _write(tmp_path: Path, text: str = SPEC, name: str = "tune.toml") -> Path:
    p = tmp_path / name
    p.write_text(textwrap.dedent(text))
    return p


@pytest.fixture(scope="module")
def spec_file(tmp_path_factory) -> Path:
    return _write(tmp_path_factory.mktemp("tune"))


@pytest.fixture(scope="module")
def spec(spec_file) -> tune.TuneSpec:
    return tune.load_tune_spec(spec_file)


@pytest.fixture(scope="module")
def exact_warm(spec):
    """The exact program of the held-out evaluation, compiled (by running a small evaluation of
    the same shape) in a thread while the main thread compiles the gradient program: the two
    compilations overlap on a 2-core machine, and the CLI test finds the exact one ready."""
    from mcjax.study import run_sweep

    box: dict = {}

    def work():
        try:
            box["rows"] = run_sweep(tune.evaluation_spec(spec, spec.initial() * 1.01))
        except BaseException as exc:  # noqa: BLE001 - reported by the test that joins
            box["error"] = exc

    thread = threading.Thread(target=work, daemon=True)
    thread.start()
    return thread, box


@pytest.fixture(scope="module")
def evaluator(spec, exact_warm) -> tune.Evaluator:
    return tune.Evaluator(spec)


def _with_base(spec, **values) -> tune.TuneSpec:
    """The same program with other (untuned) Params values."""
    import dataclasses

    sweep = dataclasses.replace(spec.study, base_params=spec.study.base_params._replace(
        **{k: np.asarray(v, np.float64) for k, v in values.items()}))
    return dataclasses.replace(spec, study=sweep)


# ------------------------------------------------------------------ transforms and spec


@pytest.mark.xdist_group("test_tune")  # one worker builds the module fixture once
def test_transform_round_trip_stays_inside_bounds(spec):
    z = tune.to_unconstrained(spec.bounds, spec.initial())
    np.testing.assert_allclose(np.asarray(tune.from_unconstrained(spec.bounds, jnp.asarray(z))), spec.initial(),
                               rtol=1e-12)
    far = np.asarray(tune.from_unconstrained(spec.bounds, jnp.asarray([30.0, -30.0, 30.0, -30.0])))
    for b, v in zip(spec.bounds, far):
        assert b.low <= v <= b.high


BAD = [
    ("[tune.params.alpha_Q]\nlow = 1.0\nhigh = 2.0", "tune.params.alpha_Q: unknown Param"),
    ("[tune.params.horizon]\nlow = 1.0\nhigh = 5.0", "tune.params.horizon: horizon is not continuous"),
    ("[tune.params.alive]\nlow = 0.0\nhigh = 1.0", "tune.params.alive: alive is not continuous"),
    ("[tune.params.plan_iterations]\nlow = 1.0\nhigh = 5.0", "tune.params.plan_iterations: plan_iterations is a Config field"),
    ("[tune.params.initial_positions]\nlow = 1.0\nhigh = 5.0", "tune.params.initial_positions: initial_positions is an array"),
    ("[tune.params.link_loss]\nlow = 0.1\nhigh = 0.5", "tune.params.link_loss: link_loss has no smooth path"),
    ("[tune.params.alpha_I]\nlow = 100.0\nhigh = 10.0", "tune.params.alpha_I: bounds reversed"),
    ("[tune.params.alpha_I]\nlow = 2000.0\nhigh = 3000.0", "tune.params.alpha_I: the initial value"),
    ("[tune.params.alpha_I]\nlow = 10.0\nhigh = 3000.0\ninitial = 5.0", "tune.params.alpha_I.initial: must lie"),
    ("[tune.params.alpha_I]\nlow = -10.0\nhigh = 3000.0", "tune.params.alpha_I.low: must be >= 0"),
    ("[tune.params.alpha_I]\nlow = 0.0\nhigh = 3000.0\nscale = \"log\"", "tune.params.alpha_I.low: must be > 0"),
    ("[tune.params.alpha_I]\nlow = 1.0\nhigh = 3000.0\nsclae = \"log\"", "tune.params.alpha_I.sclae: unknown key"),
]


def _tune_spec(extra_tune: str = "", params: str = "[tune.params.alpha_I]\nlow = 10.0\nhigh = 1e4") -> str:
    steps = "" if extra_tune.startswith("steps") else "steps = 2"
    return f'base = "{BASE}"\n[tune]\n{steps}\n{extra_tune}\n{params}\n'


@pytest.mark.parametrize("params, message", BAD)
def test_bad_params_table_one_line_exit_2_nothing_written(tmp_path, params, message):
    p = _write(tmp_path, _tune_spec(params=params))
    out = tmp_path / "out"
    r = CliRunner().invoke(main, ["tune", str(p), "--out", str(out)])
    assert r.exit_code == 2, r.output
    err = r.stderr.strip() if hasattr(r, "stderr") else r.output.strip()
    assert len(err.splitlines()) == 1 and message in err, err
    assert not out.exists()


@pytest.mark.parametrize("extra, message", [
    ("steps = 0", "tune.steps: must be an integer in [1,"),
    ("steps = -3", "tune.steps: must be an integer in [1,"),
    ("stpes = 3", "tune.stpes: unknown key (did you mean 'steps'?)"),
    ("optimizer = \"adma\"", "tune.optimizer: must be one of"),
    ("learning_rate = 0.0", "tune.learning_rate: must be a number > 0"),
    ("train_base_seed = 0\nheldout_base_seed = 0", "tune.heldout_base_seed: must differ"),
    ("gradient = \"sideways\"", "tune.gradient: must be one of forward, reverse"),
    ("gradient_window = -1", "tune.gradient_window: must be an integer in [0, 200]"),
    ("gradient_window = 2.5", "tune.gradient_window: must be an integer in [0, 200]"),
    ("[tune.loss]\nfilter = \"kalman\"", "tune.loss.filter: must be one of"),
    ("[tune.smoothing]\ncom = 1.0", "tune.smoothing.com: unknown key"),  # the key's former name, still read
    ("[tune.relaxation]\ncom = 1.0", "tune.relaxation.com: unknown key"),
    ("[tune.relaxation]\ncomm = 1.0\n[tune.smoothing]\ncomm = 1.0", "tune.smoothing: the former name of tune.relaxation"),
])
def test_bad_tune_keys(tmp_path, extra, message):
    text = _tune_spec(extra_tune=extra if not extra.startswith("[") else "",
                      params="[tune.params.alpha_I]\nlow = 10.0\nhigh = 1e4\n" + (extra if extra.startswith("[") else ""))
    with pytest.raises(SpecError) as exc:
        tune.build_tune_spec(__import__("tomllib").loads(text), tmp_path)
    assert message in str(exc.value) and "\n" not in str(exc.value)


def test_spec_without_tune_table_or_with_grid(tmp_path):
    for text, message in [(f'base = "{BASE}"\n', "tune: missing"),
                          (_tune_spec() + "[grid]\nalpha_I = [1.0, 2.0]\n", "grid: unknown key")]:
        with pytest.raises(SpecError, match=message):
            tune.build_tune_spec(__import__("tomllib").loads(text), tmp_path)


def test_scenario_without_smoothing_switch_names_the_tunable_ones(tmp_path):
    """A scenario of one's own without a relaxation switch (Scenario.relaxation) cannot be tuned:
    one line naming it and the built-in scenarios that can."""
    (tmp_path / "plain.py").write_text("import dataclasses\nfrom mcjax.scenarios.ren2017 import SCENARIO as S\n"
                                       "SCENARIO = dataclasses.replace(S, name='plain', relaxation=None)\n")
    (tmp_path / "plain.toml").write_text('scenario = "plain.py:SCENARIO"\n')
    text = 'base = "plain.toml"\n[tune]\nsteps = 2\n[tune.params.sigma_r]\nlow = 1.0\nhigh = 9.0\n'
    with pytest.raises(SpecError) as exc:
        tune.build_tune_spec(__import__("tomllib").loads(text), tmp_path)
    message = str(exc.value)
    assert message.startswith("scenario: plain has no relaxation switch (Scenario.relaxation)") and "\n" not in message
    tunable = [n for n, s in scenarios.BUILTIN.items() if s.relaxation is not None]
    assert {"leader_follower", "urban_bearing"} <= set(tunable)
    assert message.endswith(f"tunable built-in scenarios: {', '.join(tunable)}")


def test_example_spec_reads():
    s = tune.load_tune_spec(ROOT / "sweeps" / "tune_sun2011.toml")
    assert s.names == ["alpha_I", "alpha_L", "alpha_C"]
    assert s.train_seeds == 128 and s.heldout_seeds == 1000 and s.heldout_base_seed != s.train_base_seed


# ------------------------------------------------------------------ gradients


def _assert_central_differences(spec, evaluator, z0, grad, h=1e-4):
    """``grad`` against central differences of ``evaluator``'s loss at ``z0`` (the same seeds,
    float64), each Param to a relative 1e-3 (of itself, or 1 % of the gradient's norm)."""
    fd = np.array([(evaluator(z0 + h * e).loss - evaluator(z0 - h * e).loss) / (2 * h) for e in np.eye(len(z0))])
    scale = np.linalg.norm(grad)
    assert scale > 0
    for name, g, f in zip(spec.names, grad, fd):
        assert abs(g - f) <= 1e-3 * max(abs(g), 1e-2 * scale), (name, g, f)
    assert np.all(np.abs(grad) > 1e-3 * scale)  # every Param carries gradient (none is checked as 0 = 0)


@pytest.mark.xdist_group("test_tune")  # one worker builds the module fixture once
def test_gradient_matches_central_differences(spec, evaluator):
    """d loss / d z of the forward-mode gradient vs central differences of the same loss (the
    same seeds, float64), for 4 Params, to a relative 1e-3."""
    z0 = tune.to_unconstrained(spec.bounds, spec.initial())
    ev = evaluator(z0)
    assert ev.dropped == 0 and np.all(np.isfinite(ev.grad))
    _assert_central_differences(spec, evaluator, z0, ev.grad)


@pytest.mark.xdist_group("test_tune")  # one worker builds the module fixture once
@pytest.mark.parametrize("case", ["uav_on_target", "coincident_uavs", "graph_breaks"])
def test_gradients_finite_for_degenerate_runs(spec, evaluator, case):
    pos = np.array(spec.study.base_params.initial_positions)
    values = {}
    if case == "uav_on_target":
        pos[1] = np.asarray(spec.study.base_params.target_x0)[[0, 2]]
        values["initial_positions"] = pos
    elif case == "coincident_uavs":
        pos[1] = pos[0]
        values["initial_positions"] = pos
    else:  # UAV 0 turns away from UAV 1 (60 km apart) at a 60.5 km comm radius: the link breaks
        values["initial_headings"] = np.array([np.pi, 0.0])
    s = _with_base(spec, **values)
    ev = tune.Evaluator(s)  # the same program (Params are its argument): no compilation
    assert ev.fn is evaluator.fn
    out = ev(tune.to_unconstrained(s.bounds, np.array([60.5e3, 120e3, 50.0, 800.0])))
    assert out.dropped == 0 and np.isfinite(out.loss) and np.all(np.isfinite(out.grad)), out


# ------------------------------------------------------------------ gradient truncation (toy scenario)


class _ToyState(NamedTuple):
    t: jax.Array
    x: jax.Array


class _ToyParams(NamedTuple):
    theta: jax.Array
    pinned: jax.Array  # (T,) a state to force at step t (NaN: none)


def _toy_scenario():
    """x ← 1.7·x + θ + noise per step (unstable, like the closed loop): errors x (1 filter, 1 agent)."""

    def init(cfg, params, key):
        return _ToyState(jnp.asarray(0, jnp.int32), jnp.asarray(30.0))

    def step(cfg, params, state, key, temperatures=None):
        x = jnp.where(jnp.isnan(params.pinned[state.t]), state.x, params.pinned[state.t])
        x = 1.7 * x + params.theta + 40.0 * jax.random.normal(key, ())
        return _ToyState(state.t + 1, x), jnp.reshape(x, (1, 1))

    class Scen(NamedTuple):
        init: object
        step: object
        relaxation: object

    return Scen(init, step, Relaxation(None, lambda cfg, params, record: record, lambda cfg, params: jnp.ones(1)))


class _ToyConfig(NamedTuple):
    n_steps: int = 6
    filters: tuple = ("f",)


def test_gradient_window_is_the_derivative_with_the_state_held_at_each_window_start():
    """With ``gradient_window = K`` the gradient equals the exact derivative of the same loss
    with the state forced, at steps K, 2K, …, to its value along the unperturbed run (checked
    by central differences of that run); the loss's value is unchanged."""
    scen, cfg = _toy_scenario(), _ToyConfig()
    loss = tune.Loss("f", 1000.0, 1.0, 200.0, 20.0, 150.0, 1)
    key, T, K = jax.random.PRNGKey(3), cfg.n_steps, 2
    free = jnp.full(T, jnp.nan)

    def loss_of(window):
        return lambda theta, pinned: tune.run_loss(scen, cfg, loss, None, 3, _ToyParams(theta, pinned), key,
                                                   window)[0]

    # two programs: the full gradient in reverse mode, the truncated one in forward mode (the
    # default of mcjax tune); each also gives the loss's value
    full_vg = jax.jit(jax.value_and_grad(loss_of(0)))
    cut_gv = jax.jit(jax.jacfwd(lambda th, p: (loss_of(K)(th, p),) * 2, has_aux=True))
    theta = jnp.asarray(5.0)

    @jax.jit
    def states(theta):  # the unperturbed state entering each step
        def body(st, t):
            return scen.step(cfg, _ToyParams(theta, free), st, jax.random.fold_in(key, t), None)[0], st.x
        return jax.lax.scan(body, scen.init(cfg, None, key), jnp.arange(T))[1]

    pinned = jnp.where((jnp.arange(T) % K == 0) & (jnp.arange(T) > 0), states(theta), jnp.nan)
    value = lambda th, p: full_vg(jnp.asarray(th), p)[0]  # noqa: E731
    v0, full = full_vg(theta, free)
    cut, v_cut = cut_gv(theta, free)
    assert float(v_cut) == pytest.approx(float(v0), rel=1e-14)
    assert float(value(theta, pinned)) == pytest.approx(float(v0), rel=1e-12)
    h = 1e-5
    fd_cut = (value(theta + h, pinned) - value(theta - h, pinned)) / (2 * h)
    fd_full = (value(theta + h, free) - value(theta - h, free)) / (2 * h)
    assert abs(cut - fd_cut) <= 1e-6 * abs(fd_cut), (cut, fd_cut)
    assert abs(full - fd_full) <= 1e-6 * abs(fd_full), (full, fd_full)
    assert abs(full - cut) > 1e-2 * abs(full)  # the truncation changes the gradient here


# ------------------------------------------------------------------ optimisation, resume after a kill, CLI


@pytest.mark.xdist_group("test_tune")  # one worker builds the module fixture once
def test_cli_resume_after_a_kill_gives_the_same_trace_end_to_end_and_report(spec_file, spec, evaluator, exact_warm,
                                                                           tmp_path):
    """One uninterrupted optimisation; one killed in its second step (the evaluator raises)
    and finished by ``mcjax tune --resume`` in process (optimisation, held-out evaluation,
    trace.png): the same trace; ``mcjax report`` reads the output."""
    thread, box = exact_warm
    thread.join()
    assert "error" not in box, box.get("error")
    assert len(box["rows"]) == 2 * 3 and np.isfinite(box["rows"]["rmse"]).all()
    cols = ["step", "loss", "soft_rmse", "soft_divergence", *spec.names, "grad_norm", "dropped_runs"]
    full_dir, out = tmp_path / "full", tmp_path / "out"
    tune.prepare_tune_output(spec, full_dir)
    full = tune.optimise(spec, full_dir, evaluator=evaluator)
    assert list(full["step"]) == [0, 1, 2] and full["loss"].notna().all()
    assert full[spec.names].diff().abs().iloc[1:].to_numpy().max() > 0  # the Params moved

    calls = []

    def killed(z):
        calls.append(1)
        if len(calls) == 2:
            raise KeyboardInterrupt  # killed while evaluating step 1
        return evaluator(z)

    tune.prepare_tune_output(spec, out, spec_file=spec_file)
    with pytest.raises(KeyboardInterrupt):
        tune.optimise(spec, out, evaluator=killed)
    assert list(pd.read_parquet(out / tune.TRACE_FILE)["step"]) == [0]  # step 0's state is on disk

    r = CliRunner().invoke(main, ["tune", str(spec_file), "--out", str(out), "--resume"])
    assert r.exit_code == 0, r.output
    trace = pd.read_parquet(out / tune.TRACE_FILE)
    pd.testing.assert_frame_equal(trace[cols], full[cols])
    assert "wall_s" in trace.columns and (out / "trace.png").stat().st_size > 0
    ident = json.loads((out / "sweep.json").read_text())
    assert ident["n_runs"] == 2 * 3
    held = pd.read_parquet(out / "runs")  # the dataset and the printed table say which row is which
    assert (held["role"].astype(str) == np.where(held["point_id"].astype(int) == 0, "initial", "tuned")).all()
    table = r.output.split("tuned - initial, paired", 1)[0]  # the summary table, before the paired comparison
    printed = [line.split()[0] for line in table.splitlines() if line.split()[:1] in (["initial"], ["tuned"])]
    assert printed == ["initial", "tuned"], r.output
    r2 = CliRunner().invoke(main, ["report", str(out), "--no-plots"])
    assert r2.exit_code == 0, r2.output
    assert "comm_radius" in r2.output
    # resuming a finished tune re-runs nothing; the same tune into its folder without --resume is told it is there
    r3 = CliRunner().invoke(main, ["tune", str(spec_file), "--out", str(out), "--resume"])
    assert r3.exit_code == 0, r3.output
    r4 = CliRunner().invoke(main, ["tune", str(spec_file), "--out", str(out)])
    assert r4.exit_code == 2 and "already holds this tune (the same spec): pass --resume" in r4.output


@pytest.mark.xdist_group("test_tune")  # one worker builds the module fixture once
def test_reverse_mode_gradient_matches_central_differences(spec, evaluator):
    """``gradient = "reverse"`` (one backward pass, ``jax.checkpoint`` over blocks of 2 of the 4
    steps): the same loss as the forward-mode program, and its gradient against central
    differences of that loss (the same seeds, float64) for the 4 Params, to a relative 1e-3."""
    import dataclasses

    reverse = tune.Evaluator(dataclasses.replace(spec, gradient="reverse", checkpoint_every=2))
    z0 = tune.to_unconstrained(spec.bounds, spec.initial())
    ev, fwd = reverse(z0), evaluator(z0)
    assert ev.dropped == 0 and np.all(np.isfinite(ev.grad))
    np.testing.assert_allclose(ev.loss, fwd.loss, rtol=1e-9)  # two programs: rounding differs
    _assert_central_differences(spec, evaluator, z0, ev.grad)


def test_two_devices_give_the_one_device_loss_and_gradient(tmp_path):
    """The training batch split over 2 CPU devices (a subprocess: the count is fixed when JAX
    starts; the gradient program compiled once and loaded on the second device) gives the same
    loss and gradient bits as one device."""
    import json
    import os
    import subprocess
    import sys

    p = _write(tmp_path, SPEC.replace("train_seeds = 2", f"train_seeds = {2 * tune.RUNS_PER_DEVICE}"))
    spec = tune.load_tune_spec(p)
    z0 = tune.to_unconstrained(spec.bounds, spec.initial())
    one = tune.Evaluator(spec)(z0)
    script = tmp_path / "two.py"
    script.write_text(
        "import json, sys\n"
        "from mcjax import tune\n"
        "spec = tune.load_tune_spec(sys.argv[1])\n"
        "ev = tune.Evaluator(spec)\n"
        "assert len(ev.devs) == 2, ev.devs\n"
        "r = ev(tune.to_unconstrained(spec.bounds, spec.initial()))\n"
        "print(json.dumps({'loss': float(r.loss).hex(), 'grad': [float(g).hex() for g in r.grad]}))\n")
    env = {**os.environ, "MCJAX_CPU_DEVICES": "2"}
    r = subprocess.run([sys.executable, str(script), str(p)], env=env, capture_output=True, text=True,
                       timeout=600, check=True)
    two = json.loads(r.stdout.strip().splitlines()[-1])
    assert two["loss"] == float(one.loss).hex()
    assert two["grad"] == [float(g).hex() for g in one.grad]


def test_paired_differences_are_the_paired_t_interval():
    """mcjax tune's held-out comparison against scipy: per filter and column, the mean of tuned −
    initial by seed and its 95 % Student-t interval (scipy.stats.t on the differences)."""
    from scipy import stats

    rng = np.random.default_rng(7)
    n = 40
    a, b = rng.normal(10.0, 2.0, n), rng.normal(9.0, 2.0, n)
    runs = pd.DataFrame({"point_id": np.repeat([0, 1], n), "seed_index": np.tile(np.arange(n), 2),
                         "filter": "f", "rmse": np.r_[a, b]})
    got = tune.paired_differences(runs, ["rmse"]).iloc[0]
    d = b - a
    low, high = stats.t.interval(0.95, n - 1, loc=d.mean(), scale=stats.sem(d))
    assert got["paired_difference"] == pytest.approx(d.mean(), rel=1e-12)
    assert (got["ci_low"], got["ci_high"]) == pytest.approx((low, high), rel=1e-9)
    assert got["initial"] == pytest.approx(a.mean()) and got["tuned"] == pytest.approx(b.mean()) and got["n"] == n
    assert tune.paired_differences(runs[runs["point_id"] == 0], ["rmse"]).empty  # one point: nothing to pair


def test_evaluation_rows_and_printed_table_say_initial_and_tuned(spec):
    """The held-out evaluation's rows carry ``role`` = "initial" (point 0) / "tuned" (point 1),
    and mcjax tune's printed table puts the initial row first even where the tuned value sorts
    first (here a smaller comm radius), with the same numbers as the rows' own means."""
    final = spec.initial().copy()
    final[spec.names.index("comm_radius")] *= 0.5  # tuned < initial: sorted by value, tuned would come first
    ev = tune.evaluation_spec(spec, final)
    assert list(ev.zipped) == ["comm_radius"]
    rng = np.random.default_rng(3)
    rows = []
    for point, radius in enumerate(ev.zipped["comm_radius"]):
        for seed in range(4):
            row = {"scenario": ev.scenario.name, "point_id": point, "seed_index": seed, "comm_radius": radius,
                   "filter": "modified_icf"}
            for name, o in ev.scenario.outputs(ev.config).items():
                row[name] = bool(rng.random() < 0.3) if o.role in ("divergence", "nonfinite") else rng.gamma(2.0, 5.0)
            rows.append(row)
    runs = tune.with_role(pd.DataFrame(rows))
    assert list(runs.columns[runs.columns.get_loc("role"):][:2]) == ["role", "filter"]
    assert (runs["role"] == np.where(runs["point_id"] == 0, "initial", "tuned")).all()
    text = tune.summary_text(runs, ev)
    table = [line.split() for line in text.splitlines() if line.split()[:1] in (["initial"], ["tuned"])]
    assert [r[0] for r in table] == ["initial", "tuned"], text
    header = next(line.split() for line in text.splitlines() if line.split()[:2] == ["role", "comm_radius"])
    means = runs.groupby("role")["rmse"].mean()
    for r in table:
        assert float(r[header.index("rmse_mean")]) == pytest.approx(means[r[0]], rel=1e-3)
    assert "role: initial = the Params the tune started from" in text
    # an evaluation written before the column: the table still says which row is which
    assert tune.summary_text(runs.drop(columns="role"), ev) == text
