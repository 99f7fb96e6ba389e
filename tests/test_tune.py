"""``mcjax tune``: gradients through the closed loop, the [tune] table, resume, the CLI.

Compilation is what costs here, so every test of the loop shares one small program (an
open-loop leader_follower run of a few steps: its gradient still goes through the dynamics,
the smooth sensing gate, the smooth comm graph, the consensus filters and the loss), and the
planner's own derivative (the weights α_I, α_L, α_C through its unrolled Adam) is checked on one
planning problem. The full closed loop's gradient check is in docs/tune.md (measured, too slow
to compile here).
"""

from __future__ import annotations

import json
import textwrap
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pandas as pd
import pytest
from click.testing import CliRunner

from mcjax import tune
from mcjax.cli import main
from mcjax.sweep import SpecError

ROOT = Path(__file__).resolve().parents[1]
BASE = (ROOT / "configs" / "sun2011.toml").as_posix()

#: The shared small program: 8 steps, open loop, modified ICF only, 2 training runs.
SPEC = f"""
base = "{BASE}"
[config]
n_steps = 8
warmup_steps = 2
filters = ["modified_icf"]
planner = "none"
[params]
comm_radius = 70e3
initial_headings = [0.0, 0.0, 0.0, 0.0, 0.0]   # one per UAV, so a test may turn one away (same program)
[tune]
steps = 3
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
[tune.params.heading_cmd]
low = -3.0
high = 0.0
[tune.loss]
filter = "modified_icf"
divergence_temperature = 200.0
[tune.smoothing]
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
def evaluator(spec) -> tune.Evaluator:
    return tune.Evaluator(spec)


def _with_base(spec, **values) -> tune.TuneSpec:
    """The same program with other (untuned) Params values."""
    import dataclasses

    sweep = dataclasses.replace(spec.sweep, base_params=spec.sweep.base_params._replace(
        **{k: np.asarray(v, np.float64) for k, v in values.items()}))
    return dataclasses.replace(spec, sweep=sweep)


# ------------------------------------------------------------------ transforms and spec


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
    ("[tune.loss]\nfilter = \"kalman\"", "tune.loss.filter: must be one of"),
    ("[tune.smoothing]\ncom = 1.0", "tune.smoothing.com: unknown key"),
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


def test_example_spec_reads():
    s = tune.load_tune_spec(ROOT / "sweeps" / "tune_sun2011.toml")
    assert s.names == ["alpha_I", "alpha_L", "alpha_C"]
    assert s.train_seeds == 128 and s.heldout_seeds == 1000 and s.heldout_base_seed != s.train_base_seed


# ------------------------------------------------------------------ gradients


def test_gradient_matches_central_differences(spec, evaluator):
    """d loss / d z of the forward-mode gradient vs central differences of the same loss (the
    same seeds, float64), for 4 Params, to a relative 1e-3."""
    z0 = tune.to_unconstrained(spec.bounds, spec.initial())
    ev = evaluator(z0)
    assert ev.dropped == 0 and np.all(np.isfinite(ev.grad))
    h = 1e-4
    fd = np.array([(evaluator(z0 + h * e).loss - evaluator(z0 - h * e).loss) / (2 * h) for e in np.eye(len(z0))])
    scale = np.linalg.norm(ev.grad)
    assert scale > 0
    for name, g, f in zip(spec.names, ev.grad, fd):
        assert abs(g - f) <= 1e-3 * max(abs(g), 1e-2 * scale), (name, g, f)
    assert np.count_nonzero(np.abs(ev.grad) > 1e-3 * scale) >= 3  # at least 3 Params carry gradient


@pytest.mark.parametrize("case", ["uav_on_target", "coincident_uavs", "graph_breaks"])
def test_gradients_finite_for_degenerate_runs(spec, evaluator, case):
    pos = np.array(spec.sweep.base_params.initial_positions)
    values = {}
    if case == "uav_on_target":
        pos[1] = np.asarray(spec.sweep.base_params.target_x0)[[0, 2]]
        values["initial_positions"] = pos
    elif case == "coincident_uavs":
        pos[3] = pos[2]
        values["initial_positions"] = pos
    else:  # UAV 0 turns away from UAV 1 (60 km apart) at a 60.5 km comm radius: the link breaks
        values["initial_headings"] = np.array([np.pi, 0.0, 0.0, 0.0, 0.0])
    s = _with_base(spec, **values)
    ev = tune.Evaluator(s)(tune.to_unconstrained(s.bounds, np.array([60.5e3, 120e3, 50.0, -1.37])))
    assert ev.dropped == 0 and np.isfinite(ev.loss) and np.all(np.isfinite(ev.grad)), ev


def test_planner_weights_gradient_matches_central_differences():
    """The tuned weights act on the closed loop through the planner: the derivative of its
    plan (unrolled Adam on the smooth eq. 16 cost) with respect to α_I, α_L, α_C matches central
    differences (one compiled program gives both: the primal and the tangent of ``jax.jvp``)."""
    from mcjax.planning import CostParams, Dynamics, PlannerOptions, Problem, horizon_plan_cost, solve

    uavs = jnp.array([[20e3, 150e3, 800.0, 0.3], [80e3, 150e3, 800.0, 0.0], [130e3, 200e3, 800.0, -0.2]])
    problem = Problem(uavs, jnp.array([200e3, 200.0, 180e3, -1000.0]), jnp.diag(jnp.array([1e-4, 1e-2, 1e-4, 1e-2])))
    dyn = Dynamics(1.0, 1.0, np.deg2rad(10.0), 2.0, 50.0)
    ones = jnp.ones(3)
    c = jnp.asarray(np.random.default_rng(0).normal(size=(2, 3)))

    def summary(w):  # a fixed weighted sum of the smooth cost's unrolled-Adam plan
        cost = CostParams(w[0], w[2], w[1], 1e4, 1e3, 20e3, 5e3, 1e3, 120e3 * ones, 70e3 * ones, 10.0, 0.017, ones)
        pc = horizon_plan_cost(problem, dyn, cost, penalty="barrier")
        u = solve(pc._replace(exact=pc.smooth), jnp.zeros((2, 3)), jax.random.PRNGKey(0),
                  PlannerOptions("gradient", 4, 2, 0.3)).u
        return jnp.sum(c * u)

    both = jax.jit(lambda w, v: jax.jvp(summary, (w,), (v,)))
    w0 = jnp.array([1000.0, 1e-4, 1.0])
    for i in range(3):
        e = jnp.zeros(3).at[i].set(1.0)
        _, g = both(w0, e * w0[i])  # d summary / d log w_i
        h = 1e-4
        fd = (both(w0 * (1 + h * e), e)[0] - both(w0 * (1 - h * e), e)[0]) / (2 * h)
        assert abs(g - fd) <= 1e-3 * abs(g) + 1e-12, (i, g, fd)
        assert abs(g) > 0


# ------------------------------------------------------------------ optimisation, resume, CLI


def test_resume_after_kill_gives_the_same_trace(spec, evaluator, tmp_path):
    cols = ["step", "loss", *spec.names, "grad_norm"]
    full_dir, cut_dir = tmp_path / "full", tmp_path / "cut"
    for d in (full_dir, cut_dir):
        tune.prepare_tune_output(spec, d)
    full = tune.optimise(spec, full_dir, evaluator=evaluator)
    assert list(full["step"]) == [0, 1, 2, 3]
    calls = []
    part = tune.optimise(spec, cut_dir, evaluator=evaluator, should_stop=lambda: calls.append(1) or len(calls) >= 2)
    assert list(part["step"]) == [0, 1]  # "killed" after two completed steps (the state is on disk)
    tune.prepare_tune_output(spec, cut_dir, resume=True)
    resumed = tune.optimise(spec, cut_dir, evaluator=evaluator)
    pd.testing.assert_frame_equal(resumed[cols], full[cols])
    on_disk = pd.read_parquet(cut_dir / tune.TRACE_FILE)
    pd.testing.assert_frame_equal(on_disk[cols], full[cols])


def test_cli_end_to_end_and_report(spec_file, evaluator, tmp_path):
    out = tmp_path / "out"
    r = CliRunner().invoke(main, ["tune", str(spec_file), "--out", str(out)])
    assert r.exit_code == 0, r.output
    trace = pd.read_parquet(out / "trace.parquet")
    assert {"step", "loss", "comm_radius", "grad_norm", "wall_s"} <= set(trace.columns) and len(trace) == 4
    assert (out / "trace.png").stat().st_size > 0
    ident = json.loads((out / "sweep.json").read_text())
    assert ident["n_runs"] == 2 * 3
    r2 = CliRunner().invoke(main, ["report", str(out), "--no-plots"])
    assert r2.exit_code == 0, r2.output
    assert "comm_radius" in r2.output
    # resuming a finished tune re-runs nothing; a non-empty folder without --resume is refused
    r3 = CliRunner().invoke(main, ["tune", str(spec_file), "--out", str(out), "--resume"])
    assert r3.exit_code == 0, r3.output
    r4 = CliRunner().invoke(main, ["tune", str(spec_file), "--out", str(out)])
    assert r4.exit_code == 2 and "not empty" in r4.output
