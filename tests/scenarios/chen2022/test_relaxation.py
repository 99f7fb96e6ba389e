"""``mcjax tune`` on Chen & Hao 2022 (urban_bearing): the planner weights c1, c2, c3 by gradient.

The exact closed loop is piecewise constant in the weights (the grid planner's argmax) with
jumps (the shadow hold, the measurement gate, reflections that appear and vanish), so
training runs the scenario's smooth system (``urban_bearing.step`` with ``temperatures``, docs/tune.md).
Every test shares ONE small gradient program: 8 steps, a 3-step planning horizon, the IMM
only, 2 training runs, on the first building layout (configs/chen2022_wide_prior.toml), the UAV
started 100 m south of the reflection region of the tall building's east wall, flying north into it, so that J_FIM, J_T and J_NLOS (eq. 20) all
differ between the candidate commands and each weight carries gradient. The degenerate runs
use the same program (the Params are its argument).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from mcjax import tune
from mcjax.scenarios import chen2022 as ub
from mcjax.scenarios.chen2022 import score as urban
from tests.tune.test_tune import _assert_central_differences

ROOT = Path(__file__).resolve().parents[3]
EMITTER = np.array([5000.0, 5000.0, 0.0])
#: Start: (5300, 5100) at 200 m heading north, 100 m south of the NLOS region (y 5200–5600 at
#: x = 5300) of the tall building's east wall, in line of sight.
START = [5300.0, 5100.0, 200.0, float(np.pi / 2)]


def _spec_data() -> dict:
    return {"base": str(ROOT / "configs" / "chen2022_wide_prior.toml"),   # the first layout: the placements below
            "config": {"n_steps": 8, "warmup_steps": 1, "horizon": 3, "filters": ["imm"]},
            "params": {"uav0": START},
            "tune": {"steps": 1, "train_seeds": 2, "train_base_seed": 1, "heldout_seeds": 2,
                     "heldout_base_seed": 0, "checkpoint_every": 8,
                     "params": {"c1": {"low": 0.01, "high": 2.0, "scale": "log"},
                                "c2": {"low": 0.01, "high": 5.0, "scale": "log"},
                                "c3": {"low": -1.5, "high": 1.5}},
                     "loss": {"filter": "imm"}}}


@pytest.fixture(scope="module")
def spec() -> tune.TuneSpec:
    return tune.build_tune_spec(_spec_data(), ROOT)


@pytest.fixture(scope="module")
def evaluator(spec) -> tune.Evaluator:
    return tune.Evaluator(spec)


def _with_base(spec, **values) -> tune.TuneSpec:
    """The same program with other (untuned) Params values."""
    sweep = dataclasses.replace(spec.study, base_params=spec.study.base_params._replace(
        **{k: np.asarray(v, np.float64) for k, v in values.items()}))
    return dataclasses.replace(spec, study=sweep)


@pytest.mark.xdist_group("tune_urban")  # one worker builds the module fixture once
def test_spec_takes_the_weights_and_the_smoothing_table():
    data = _spec_data()
    data["tune"]["smoothing"] = {"geometry": 30.0, "plan": 0.2, "command": 2e-3}
    s = tune.build_tune_spec(data, ROOT)
    assert s.names == ["c1", "c2", "c3"] and s.temperatures == ub.Temperatures(30.0, 0.2, 2e-3)
    assert s.study.config.planner == "grid"  # the paper's planner, whose argmax the surrogate smooths


@pytest.mark.xdist_group("tune_urban")  # one worker builds the module fixture once
def test_gradient_matches_central_differences_for_several_steps(spec, evaluator):
    """d loss / d z (forward mode, as mcjax tune) vs central differences of the same loss (the
    same seeds, float64) to a relative 1e-3 for c1, c2, c3, at steps h = 1e-3, 1e-4, 1e-5 in z:
    the agreement at every h shows the surrogate loss is smooth there, not one lucky h."""
    z0 = tune.to_unconstrained(spec.bounds, spec.initial())
    ev = evaluator(z0)
    assert ev.dropped == 0 and np.all(np.isfinite(ev.grad)), ev
    for h in (1e-3, 1e-4, 1e-5):
        _assert_central_differences(spec, evaluator, z0, ev.grad, h=h)


@pytest.mark.xdist_group("tune_urban")  # one worker builds the module fixture once
def test_loss_is_invariant_to_scaling_all_weights(spec, evaluator):
    """Like the grid's argmax, the surrogate's soft argmax over standardised scores does not
    change when (c1, c2, c3) are multiplied by a positive number (so the tune cannot lower
    the training loss by sharpening the surrogate)."""
    x = spec.initial()
    a = evaluator(tune.to_unconstrained(spec.bounds, x))
    b = evaluator(tune.to_unconstrained(spec.bounds, 2.0 * x))
    assert abs(a.loss - b.loss) <= 1e-9 * abs(a.loss)


@pytest.mark.xdist_group("tune_urban")  # one worker builds the module fixture once
@pytest.mark.parametrize("case", ["uav_over_emitter", "hidden_whole_run", "at_altitude_floor"])
def test_gradients_finite_for_degenerate_runs(spec, evaluator, case):
    """Same program, other Params: the UAV starting straight above the emitter; the UAV
    2 km WNW of the emitter, flying at it inside the tall building's shadow for the whole run
    (no measurement: the exact run holds its command every step); the UAV at h_min, where
    every descending candidate is inadmissible."""
    if case == "uav_over_emitter":
        values = {"uav0": [*EMITTER[:2], 200.0, 0.0]}
    elif case == "hidden_whole_run":
        bearing = np.deg2rad(152.0)  # the middle of the shadow wedge (135°–169°) behind the tall building
        values = {"uav0": [EMITTER[0] + 2000 * np.cos(bearing), EMITTER[1] + 2000 * np.sin(bearing), 200.0,
                           bearing - np.pi]}
    else:
        values = {"uav0": [0.0, 0.0, 100.0, 0.0]}
    s = _with_base(spec, **values)
    if case == "hidden_whole_run":  # the exact simulation sees nothing on this run
        from mcjax.scenarios.chen2022 import environment as env
        b = ub.buildings_np(s.study.base_params.buildings)
        # 8 steps of 50 m stay within 400 m of the start and 35 m of its altitude (|θ| ≤ 5°):
        # no point of that cylinder sees the emitter
        r, a, z = np.meshgrid(np.linspace(0, 400, 9), np.linspace(0, 2 * np.pi, 16), [165.0, 200.0, 235.0])
        pts = np.c_[values["uav0"][0] + (r * np.cos(a)).ravel(), values["uav0"][1] + (r * np.sin(a)).ravel(),
                    z.ravel()]
        assert not np.any(np.asarray(env.line_of_sight(b, EMITTER, pts)))
    ev = tune.Evaluator(s)
    assert ev.fn is evaluator.fn  # the same compiled program
    out = ev(tune.to_unconstrained(s.bounds, s.initial()))
    assert out.dropped == 0 and np.isfinite(out.loss) and np.all(np.isfinite(out.grad)), out


@pytest.mark.xdist_group("tune_urban")
def test_smooth_measurement_pieces_have_finite_derivatives_straight_above():
    """With the UAV exactly above the emitter and the estimate exactly under the UAV (a
    bearing undefined at both), the smooth bearing, the gated mode filter and the FIM
    increment have finite derivatives with respect to the UAV's position and the gate."""
    b = ub.buildings_np(ub.DEFAULT_BUILDINGS)
    T = ub.Temperatures().geometry

    def f(shift):
        uav = jnp.asarray([*EMITTER[:2], 200.0]) + shift
        bearing, los, refl = urban.soft_measured_bearing(b, jnp.asarray(EMITTER), uav, 0.5, 1.0, 1.0, T)
        gate = 1e-9 + (1 - 1e-9) * los
        x, P, ll = ub.gated_mode_filter(uav[:2], 1e4 * jnp.eye(2), (0.0, 0.0035), bearing, uav, 0.0, gate)
        info = urban.bearing_information(uav[:2], uav, 0.0035)
        return jnp.concatenate([jnp.stack([bearing, los, refl, ll]), x, P.ravel(), info.ravel()])

    def twice(shift):  # the values as the Jacobian's aux: one trace, one program for both
        v = f(shift)
        return v, v

    jac, values = jax.jit(jax.jacfwd(twice, has_aux=True))(jnp.zeros(3))
    assert np.all(np.isfinite(np.asarray(values))) and np.all(np.isfinite(np.asarray(jac)))


#: Three parameter points drawn once inside the bounds (numpy seed 34): the fraction of each
#: Param's (log-)range uniform in [0.1, 0.9], so no point sits on a bound.
_POINTS = np.random.default_rng(34).uniform(0.1, 0.9, size=(3, 3))


@pytest.mark.xdist_group("tune_urban")  # one worker builds the module fixture once
@pytest.mark.parametrize("point", range(len(_POINTS)))
def test_gradient_matches_central_differences_at_random_points(spec, evaluator, point):
    """d loss / d z (forward mode, as mcjax tune) vs central differences of the same loss (the
    same seeds, float64) to a relative 1e-4 of each derivative, at three random points
    ((c1, c2, c3) = (0.017, 1.42, −0.62), (0.27, 0.21, 0.69), (0.71, 1.63, 0.05)).

    h = 1e-4 in z, from a scan of h = 1e-2 … 1e-6 at these points: the largest relative
    difference was 4.5e-3, 4.4e-5, 1.9e-5, 1.6e-4, 1.3e-3. Above 1e-4 the quotient's O(h²)
    error shows (it falls 100-fold per 10-fold h), below it rounding (the loss ≈ 1.3 is known
    to ~1e-16, so the quotient's rounding error ~1e-16/h grows 10-fold per 10-fold h, and the
    smallest derivative is ~1e-6)."""
    z = np.log(_POINTS[point]) - np.log1p(-_POINTS[point])
    ev = evaluator(z)
    assert ev.dropped == 0 and np.all(np.isfinite(ev.grad)), ev
    h = 1e-4
    fd = np.array([(evaluator(z + h * e).loss - evaluator(z - h * e).loss) / (2 * h) for e in np.eye(len(z))])
    assert np.all(np.abs(ev.grad) > 1e-3 * np.linalg.norm(ev.grad))  # every Param carries gradient
    for name, g, f in zip(spec.names, ev.grad, fd):
        assert abs(g - f) <= 1e-4 * abs(g), (name, g, f)


#: Starts for the exact-vs-smooth checks: open (line of sight, 2.8 km SW of the emitter, flying
#: east into the reflection region) and hidden (the shadow run of the degenerate case above).
_HIDDEN_BEARING = np.deg2rad(152.0)
_STARTS = {"open": [3000.0, 3000.0, 200.0, 0.0],
           "hidden": [EMITTER[0] + 2000 * np.cos(_HIDDEN_BEARING), EMITTER[1] + 2000 * np.sin(_HIDDEN_BEARING),
                      200.0, _HIDDEN_BEARING - np.pi]}
#: Temperatures 1000 times below the defaults (m; τ; rad, rad/s).
_SHARP = ub.Temperatures(0.02, 1e-4, 1e-6)


@pytest.fixture(scope="module")
def paths(spec):
    """Records (start, level) of the small program (8 steps, horizon 3, 2 runs): the exact
    simulation (level None) and the smooth one at the default and at the sharp temperatures,
    the temperatures passed as arguments (one compiled smooth program)."""
    from mcjax import engine

    cfg, base = spec.study.config, spec.study.base_params
    keys = jax.vmap(lambda i: engine.run_key(0, i))(jnp.arange(2, dtype=jnp.uint32))
    exact = jax.jit(jax.vmap(lambda p, k: engine.run_records(ub.SCENARIO, cfg, p, k), in_axes=(None, 0)))
    smooth = jax.jit(jax.vmap(lambda p, k, s: engine.run_records(ub.SCENARIO, cfg, p, k, s), in_axes=(None, 0, None)))
    out = {}
    for name, start in _STARTS.items():
        p = base._replace(uav0=np.asarray(start))
        out[name, None] = exact(p, keys)
        for level in (ub.Temperatures(), _SHARP):
            out[name, level] = smooth(p, keys, ub.Temperatures(*(jnp.asarray(v, jnp.float64) for v in level)))
    return cfg, base, out


@pytest.mark.xdist_group("tune_urban")
def test_one_step_exact_and_smooth_paths(paths):
    """One ``step``, no near-twin: the Scenario's step is ``urban_bearing.step`` with its temperatures
    switch declared (temperatures, Params with no smooth path). Its exact path (temperatures None)
    keeps 0/1 indicators and a NaN score exactly when the command was held (the golden rows
    check it bit for bit). Its smooth path returns a Record of the same structure, its soft
    indicators floats in [0, 1]; and it is the smooth version of the exact step: with every
    temperature 1000 times below the defaults it flies the exact step's horizontal track and
    reports the exact indicators and errors, to within the residue of the soft gate's floor
    (a shadowed measurement keeps weight 1e-9), while at the defaults it differs by far more."""
    import mcjax.contract.relaxation as relaxation

    assert ub.SCENARIO.step is ub.step and not hasattr(ub, "smooth_step")
    assert ub.SCENARIO.relaxation.Temperatures is ub.Temperatures
    assert {"max_hold_steps", "plan_temperature"} <= set(ub.SCENARIO.relaxation.rough)
    assert {"c1", "c2", "c3"} <= set(relaxation.smooth_params(ub.SCENARIO, paths[0]))
    _, _, out = paths
    for name in _STARTS:
        ex, sm, sharp = out[name, None], out[name, ub.Temperatures()], out[name, _SHARP]
        assert jax.tree.structure(ex) == jax.tree.structure(sm)
        for f in ("held", "shadow", "nlos", "in_building", "violation"):
            assert getattr(ex, f).dtype == jnp.bool_ and getattr(sm, f).dtype == jnp.float64, f
            v = np.asarray(getattr(sm, f))
            assert np.all((v >= 0) & (v <= 1)), (name, f)
            assert jnp.shape(getattr(ex, f)) == jnp.shape(getattr(sm, f))
        assert np.array_equal(np.isnan(np.asarray(ex.score)), np.asarray(ex.held))
        for f in ("held", "shadow", "nlos", "in_building"):
            assert np.max(np.abs(np.asarray(getattr(sharp, f)) - np.asarray(getattr(ex, f)))) < 1e-2, (name, f)
        assert np.max(np.abs(np.asarray(sharp.uav[..., :2] - ex.uav[..., :2]))) < 1.0, name
        gap_sharp = np.max(np.abs(np.asarray(sharp.error - ex.error)))
        gap_default = np.max(np.abs(np.asarray(sm.error - ex.error)))
        assert gap_sharp < 0.5 and gap_sharp < 1e-2 * gap_default, (name, gap_sharp, gap_default)
    assert np.all(np.asarray(out["hidden", None].shadow)) and not np.any(np.asarray(out["open", None].shadow))


@pytest.mark.xdist_group("tune_urban")
def test_summary_reduces_the_smooth_record(paths):
    """``summary`` reduces the smooth Record: every output the exact run has finite is finite on
    the smooth run (default temperatures), the step counts are sums of soft indicators within
    [0, n_steps], and the shadow count of the hidden run is near its exact 8."""
    cfg, base, out = paths
    reduce = jax.jit(jax.vmap(lambda r: ub.reduce(cfg, r, base)))  # compiled (op by op costs more CPU)
    for name in _STARTS:
        exact = reduce(out[name, None])
        smooth = reduce(out[name, ub.Temperatures()])
        assert set(exact) == set(smooth)
        for k in exact:
            e, s = np.asarray(exact[k], float), np.asarray(smooth[k], float)
            assert e.shape == s.shape and np.all(np.isfinite(s[np.isfinite(e)])), (name, k)
        for k in ("shadow_steps", "nlos_steps", "held_steps", "building_steps", "limit_violations"):
            assert np.all((np.asarray(smooth[k]) >= 0) & (np.asarray(smooth[k]) <= cfg.n_steps)), (name, k)
    hidden = reduce(out["hidden", ub.Temperatures()])
    assert np.all(np.abs(np.asarray(hidden["shadow_steps"]) - 8) < 0.5)
