"""Sun et al. 2011's relaxation switch, checked where ``sweeps/tune_sun2011.toml`` uses it: the
gradient of the tune loss with respect to the planner's weights (α_I, α_L, α_C), through the
closed loop (the leader's unrolled Adam on the smooth eq. 16 cost included), matches fourth-order
central differences of the same loss to 1e-4 relative at three random points inside the spec's
bounds; and the smooth system's error approaches the exact one's as the temperatures shrink."""

from __future__ import annotations

import textwrap
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from mcjax import engine, tune

ROOT = Path(__file__).resolve().parents[3]

#: The tune spec's Params and bounds on a small closed loop: 3 UAVs, 10 steps, horizon 2,
#: 3 Adam iterations per re-plan, one filter, 2 training runs. The UAVs start 60 km apart at a
#: 70 km comm radius, so the robustness term acts: with them 40 km apart and 6 steps the
#: weights moved the loss by ~1e-8 per unit z, under the closed loop's round-off (~1e-11).
SPEC = f"""
base = "{(ROOT / 'configs' / 'sun2011.toml').as_posix()}"
[config]
n_agents = 3
n_steps = 10
warmup_steps = 1
filters = ["modified_icf"]
max_horizon = 2
plan_period = 2
plan_iterations = 3
[params]
comm_radius = 70e3
horizon = 2
replan_every = 2
initial_positions = [[100e3, 150e3], [160e3, 150e3], [220e3, 150e3]]   # 60 km apart: links near R
alive = [1, 1, 1]
initial_headings = [0.0, 0.0, 0.0]
uav_speed = [800.0, 800.0, 800.0]
[tune]
steps = 1
train_seeds = 2
heldout_seeds = 2
gradient_window = 0
[tune.params.alpha_I]
low = 10.0
high = 1e5
scale = "log"
[tune.params.alpha_L]
low = 1e-6
high = 1e-2
scale = "log"
[tune.params.alpha_C]
low = 0.01
high = 100.0
scale = "log"
[tune.loss]
filter = "modified_icf"
[tune.smoothing]
sensing = 1000.0
comm = 1000.0
"""


@pytest.fixture(scope="module")
def spec(tmp_path_factory):
    p = tmp_path_factory.mktemp("lf") / "tune.toml"
    p.write_text(textwrap.dedent(SPEC))
    return tune.load_tune_spec(p)


def test_tune_loss_gradient_matches_central_differences_at_three_random_points(spec):
    keys = tune.train_keys(spec)
    base = spec.study.base_params
    # the tune's own program (tune.batch_function: forward mode, run_loss per training run):
    # the loss and its gradient from one trace of the closed loop, compiled once
    batch = tune.batch_function(spec)

    def value_grad(z):  # the mean over the training runs, as tune.Evaluator takes it
        losses, grads = batch(z, keys, base)[:2]
        return np.mean(np.asarray(losses)), np.mean(np.asarray(grads), axis=0)

    rng = np.random.default_rng(34)
    # h in z, fourth-order stencil: a scan over h = 0.1 … 0.001 at these points gave quotients
    # within 3e-5 of the gradient from h = 0.01 down (at 0.1 and 0.03 the loop's kinks show)
    h = 1e-3
    acting = 0
    for _ in range(3):
        z = rng.uniform(-2.0, 2.0, size=3)  # inside the bounds, away from their edges
        _, g = value_grad(jnp.asarray(z))
        for i in range(3):
            e = np.eye(3)[i] * h
            f = [float(value_grad(jnp.asarray(z + k * e))[0]) for k in (1, -1, 2, -2)]
            cd = (8 * (f[0] - f[1]) - (f[2] - f[3])) / (12 * h)
            assert abs(float(g[i]) - cd) <= 1e-4 * abs(cd) or float(g[i]) == cd == 0.0, (z, i, g, cd)
        acting += bool(np.all(np.abs(np.asarray(g)) > 0))
    # at the second point every re-plan's command sits at the turn-rate limit, so no weight acts
    # (gradient and differences exactly 0); at the other two all three weights act
    assert acting == 2


def test_smooth_error_approaches_the_exact_one_as_temperatures_shrink():
    """Open loop, 5 UAVs at a comm radius where links break: |RMSE smooth − exact| over the
    same runs shrinks as both temperatures go 1000 → 100 → 10 m (the sigmoids tend to the 0/1
    tests except within ~T of a threshold), down to round-off."""
    from mcjax.scenarios import sun2011 as lf

    cfg = lf.Config(n_steps=30, warmup_steps=5, planner="none", filters=("modified_icf", "icf"))
    p = lf.default_params(cfg, comm_radius=60e3, sensing_radius=80e3)
    n = 6
    P = jax.tree.map(lambda a: np.repeat(np.asarray(a)[None], n, 0), p)
    keys = engine.run_keys(0, np.arange(n))
    run = jax.jit(lambda s: engine.simulate(lf.SCENARIO, cfg, P, keys, temperatures=s)["rmse"])
    exact = np.asarray(jax.jit(lambda: engine.simulate(lf.SCENARIO, cfg, P, keys)["rmse"])())
    gaps = [np.abs(np.asarray(run(lf.Temperatures(t, t))) - exact).mean() for t in (1000.0, 100.0, 10.0)]
    # measured: 67 m, 1e-10, 3e-10: from 100 m on the links are the exact ones to round-off
    assert gaps[1] < 1e-3 * gaps[0] and gaps[2] < 1e-6 * gaps[0], gaps
