"""A tune's training loss and its gradient: one run's loss through the engine's time-loop
driver with the scenario's relaxation switch on (:func:`run_loss`), the jitted batch function
(:func:`batch_function`) and the :class:`Evaluator` that spreads the training batch over the
devices (see :mod:`mcjax.tune` for the loss)."""

from __future__ import annotations

import json
import math
from typing import Callable, NamedTuple

import numpy as np

from mcjax.tune.spec import Loss, NONFINITE_ERROR, TuneSpec, from_unconstrained

def params_at(bounds, base, x):
    """The Params ``base`` with the tuned fields (``bounds``) set to ``x`` (P,) (traceable)."""
    import jax.numpy as jnp

    values = {k: jnp.asarray(v) for k, v in base._asdict().items()}
    for i, b in enumerate(bounds):
        values[b.name] = x[i]
    return type(base)(**values)


def run_loss(scenario, cfg, loss: Loss, temperatures, block: int, params, key, window: int = 0, remat: bool = True):
    """The training loss of one run (module docstring) with its parts:
    ``(loss, (soft RMSE, soft divergence))``. The closed loop runs the scenario's step with its
    relaxation switch on (``step(..., temperatures)``, :class:`mcjax.contract.Relaxation`) through the engine's time-loop driver (:func:`mcjax.engine.time_loop`: the exact
    simulation's keys) over ``ceil(T / block)`` blocks of ``block`` steps, each block under
    ``jax.checkpoint`` when ``remat`` (reverse mode; forward mode stores no intermediates and
    skips it); the loss is computed from the stacked errors (T, n) of the loss's filter.

    ``window = K > 0`` truncates the gradient (not the value): at steps ``K, 2K, …`` the state
    enters the next step through ``stop_gradient``, so the derivative counts how the Params act
    on the errors within each window of K steps from the state the window starts in, and not
    how a change carries over from earlier windows (truncated differentiation through time).
    The loss's value is the same for every K."""
    import jax
    import jax.numpy as jnp

    from mcjax import engine

    sm = scenario.relaxation
    f = cfg.filters.index(loss.filter)
    weights = sm.weights(cfg, params)
    state = scenario.init(cfg, params, engine.init_key(key))
    T = cfg.n_steps
    c, tm = loss.error_scale, loss.max_temperature
    dtype = weights.dtype
    neg = jnp.asarray(-1e30, dtype)

    def advance(state, key_t, t):
        if window > 0:  # a new window: the state's derivative is dropped (the value is kept)
            cut = (t % window == 0) & (t > 0)
            state = jax.tree.map(lambda a: jnp.where(cut, jax.lax.stop_gradient(a), a), state)
        state, record = scenario.step(cfg, params, state, key_t, temperatures)
        return state, sm.errors(cfg, params, record)[f]

    _, e = engine.time_loop(advance, state, key, T, block=block, remat=remat)  # (T, n)
    e = jnp.where(jnp.isfinite(e), e, NONFINITE_ERROR * c)
    mask = (jnp.arange(T)[:, None] >= loss.warmup_steps) & (weights > 0)
    clipped = c * jnp.tanh(e / c)
    sq = jnp.sum(jnp.where(mask, clipped**2, 0.0))
    count = jnp.sum(mask.astype(dtype))
    lse = jax.nn.logsumexp(jnp.where(mask, e / tm, neg))
    rmse = jnp.sqrt(sq / jnp.maximum(count, 1.0))
    soft_div = jax.nn.sigmoid((tm * lse - loss.divergence_threshold) / loss.divergence_temperature)
    return rmse / c + loss.divergence_weight * soft_div, (rmse, soft_div)


def program_key(spec: TuneSpec) -> str:
    """What fixes a tune's compiled program: scenario and Config, the tuned Params and their
    bounds, the loss, the temperatures, the gradient mode and blocks (not the Params' values,
    which the program takes as an argument)."""
    s = spec.study
    return json.dumps([s.scenario.name, repr(s.config), [[b.name, b.low, b.high, b.scale] for b in spec.bounds],
                       list(spec.loss), list(spec.temperatures), spec.checkpoint_every, spec.gradient,
                       spec.gradient_window],
                      sort_keys=True, default=str)


def batch_function(spec: TuneSpec) -> Callable:
    """``f(z, keys, base) -> (losses (R,), grads (R, P), soft RMSE (R,), soft divergence (R,))``:
    every run's training loss at the base Params ``base`` with the tuned ones at ``z``, and its
    gradient with respect to ``z``, jitted (one program; the caller spreads batches over
    devices). One function per :func:`program_key`, kept in the engine's in-process cache
    (:func:`mcjax.engine.cached`)."""
    from mcjax import engine

    return engine.cached(("tune", program_key(spec)), lambda: _batch_function(spec))


def _batch_function(spec: TuneSpec) -> Callable:
    import jax

    s = spec.study
    scenario, cfg, loss, temperatures, block, bounds = (s.scenario, s.config, spec.loss, spec.temperatures,
                                                     spec.checkpoint_every, spec.bounds)
    window = spec.gradient_window

    def one(z, key, base):
        def of_z(z):
            params = params_at(bounds, base, from_unconstrained(bounds, z))
            return run_loss(scenario, cfg, loss, temperatures, block, params, key, window, spec.gradient == "reverse")

        if spec.gradient == "reverse":
            (value, (rmse, div)), g = jax.value_and_grad(of_z, has_aux=True)(z)
            return value, g, rmse, div

        def pushed(z):  # forward mode: one tangent per tuned Param
            value, aux = of_z(z)
            return value, (value, aux)

        g, (value, (rmse, div)) = jax.jacfwd(pushed, has_aux=True)(z)
        return value, g, rmse, div

    from mcjax.engine import compiler_options

    return jax.jit(jax.vmap(one, in_axes=(None, 0, None)), compiler_options=compiler_options(scenario, cfg))


def train_keys(spec: TuneSpec):
    """The training runs' keys: the engine's keys of seeds ``0 … train_seeds−1`` of
    ``train_base_seed`` (the same at every optimisation step: common random numbers)."""
    import jax
    import jax.numpy as jnp

    from mcjax.engine import run_key

    return jax.vmap(lambda i: run_key(spec.train_base_seed, i))(jnp.arange(spec.train_seeds, dtype=jnp.uint32))


class Evaluation(NamedTuple):
    """The batch loss at one ``z`` and its gradient (means over the runs with a finite one)."""

    loss: float
    grad: np.ndarray          # (P,) d loss / d z
    soft_rmse: float
    soft_divergence: float
    dropped: int              # runs whose loss or gradient was not finite


#: Fewest training runs per device before a second device is used.
RUNS_PER_DEVICE = 16


class Evaluator:
    """The training batch's loss and gradient at any ``z``: the batch is cut into one slice
    per device, one program compiled once and loaded on each device, run side by side."""

    def __init__(self, spec: TuneSpec):
        import jax

        from mcjax import engine, runtime

        runtime.configure()  # JAX's process settings, before the training keys are computed
        self.spec = spec
        self.fn = batch_function(spec)
        keys = train_keys(spec)
        n = spec.train_seeds
        # one device per RUNS_PER_DEVICE runs at least (a small batch compiles once)
        self.devs = engine.devices(spec.study.scenario)[:max(1, n // RUNS_PER_DEVICE)]  # one_device: one
        size = -(-n // len(self.devs))
        self.slices = [(i * size, min(n, (i + 1) * size)) for i in range(len(self.devs)) if i * size < n]
        self.devs = self.devs[:len(self.slices)]
        # every slice padded to one size (repeating its last key), so one program serves all
        self.keys = []
        for a, b in self.slices:
            k = keys[a:b]
            if b - a < size:
                k = jax.numpy.concatenate([k, jax.numpy.repeat(k[-1:], size - (b - a), axis=0)])
            self.keys.append(k)
        self.programs = None

    def __call__(self, z) -> Evaluation:
        import jax

        from mcjax import engine

        z = np.asarray(z, np.float64)
        base = self.spec.study.base_params
        if self.programs is None:
            self.programs = engine.programs(self.fn, (z, self.keys[0], base), self.devs)
        outs = [prog(jax.device_put(z, d), jax.device_put(k, d), jax.device_put(base, d))
                for prog, d, k in zip(self.programs, self.devs, self.keys)]
        parts = [[np.asarray(x)[:b - a] for x in o] for o, (a, b) in zip(outs, self.slices)]
        loss, grad, rmse, div = (np.concatenate([p[i] for p in parts]) for i in range(4))
        ok = np.isfinite(loss) & np.all(np.isfinite(grad), axis=1)
        if not ok.any():
            return Evaluation(math.nan, np.full(len(z), np.nan), math.nan, math.nan, int(len(loss)))
        return Evaluation(float(loss[ok].mean()), grad[ok].mean(0), float(rmse[ok].mean()), float(div[ok].mean()),
                          int((~ok).sum()))

