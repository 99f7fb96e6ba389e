"""The one time-loop driver (exact and smooth system alike), a run's records, its derivatives,
and :func:`simulate`: ``vmap`` over the runs of a batch of ``lax.scan`` over time. Step t's key
is ``fold_in(run_key, t)`` (noise drawn per step, never pre-drawn)."""

from __future__ import annotations

from typing import Callable

import jax
import jax.numpy as jnp

from mcjax import runtime
from mcjax.contract import Scenario
from mcjax.contract.relaxation import column
from mcjax.engine.keys import init_key


def time_loop(step: Callable, state, key, n_steps: int, *, block: int | None = None, remat: bool = False):
    """The one time-loop driver: ``step(state, key_t, t) -> (state, out)`` for ``t = 0 … n_steps−1``
    with ``key_t = fold_in(key, t)``; returns ``(final state, outs stacked over time)``.

    Serves the exact simulation (:func:`simulate`, ``block=None``: one ``lax.scan`` over the
    steps) and the smooth one of ``mcjax tune`` (``block = K``: a scan over blocks of K steps,
    each block under ``jax.checkpoint`` when ``remat``, so reverse mode keeps one state per
    block; steps past ``n_steps`` in the last block leave the state as it is and output zeros,
    trimmed from the result)."""

    def body(state, t):
        return step(state, jax.random.fold_in(key, t), t)

    if block is None:
        return jax.lax.scan(body, state, jnp.arange(n_steps))
    n_blocks = -(-n_steps // block)
    if n_steps % block:
        shapes = jax.eval_shape(body, state, jnp.asarray(0))[1]

        def idle(state, t):
            return state, jax.tree.map(lambda a: jnp.zeros(a.shape, a.dtype), shapes)

        def padded(state, t):
            return jax.lax.cond(t < n_steps, body, idle, state, t)
    else:
        padded = body

    def run_block(state, ts):
        return jax.lax.scan(padded, state, ts)

    if remat:
        run_block = jax.checkpoint(run_block)
    state, outs = jax.lax.scan(run_block, state, jnp.arange(n_blocks * block).reshape(n_blocks, block))
    return state, jax.tree.map(lambda a: a.reshape((n_blocks * block,) + a.shape[2:])[:n_steps], outs)


def run_records(scenario, cfg, params, key, temperatures=None):
    """One run's records stacked over time: the exact simulation (``temperatures`` None) or the
    smooth one at those temperatures (:class:`mcjax.contract.relaxation.Relaxation`), with the same keys."""
    state = scenario.init(cfg, params, init_key(key))
    smooth = () if temperatures is None else (temperatures,)
    return time_loop(lambda s, k, t: scenario.step(cfg, params, s, k, *smooth), state, key, cfg.n_steps)[1]


def derivatives(scenario, cfg, params, key, sensitivity) -> dict:
    """One run's d output / d Param of the smooth system (a sweep's ``[sensitivity]``), forward
    mode (a per-agent Param moves every agent's value together), by :func:`mcjax.contract.relaxation.column`."""
    names, outputs, temperatures = sensitivity

    def outputs_at(shift):
        q = params._replace(**{n: getattr(params, n) + shift[i] for i, n in enumerate(names)})
        reduced = scenario.reduce(cfg, run_records(scenario, cfg, q, key, temperatures), q)
        return {o: jnp.asarray(reduced[o]).astype(jnp.result_type(float)) for o in outputs}  # a flag's: 0

    jac = jax.jacfwd(outputs_at)(jnp.zeros(len(names), jnp.result_type(float)))
    return {column(o, n): jac[o][..., i] for o in outputs for i, n in enumerate(names)}


def simulate(scenario: Scenario, cfg, params, keys, *, records: bool = False, timeseries: bool = False,
             temperatures=None, sensitivity=None):
    """Run a batch: ``params`` and ``keys`` carry a leading run axis. Returns each run's reduced
    outputs (``scenario.reduce``: a dict of (runs, …) arrays) or, with ``records=True``, the
    records stacked over time (run, time, …): the caller chooses what is kept. ``timeseries``:
    ``(outputs, scenario.timeseries(...))`` from one simulation. ``temperatures``: the smooth
    system (:func:`run_records`); ``sensitivity`` (a sweep's ``[sensitivity]``): each run's
    :func:`derivatives` instead (a program of their own beside the exact one, whose outputs
    so stay bit for bit those of a sweep without them). Not jitted: see :func:`compiled`."""
    runtime.configure()

    def one(p, k):
        if sensitivity is not None:
            return derivatives(scenario, cfg, p, k, sensitivity)
        recs = run_records(scenario, cfg, p, k, temperatures)
        if records:
            return recs
        if timeseries:
            return scenario.reduce(cfg, recs, p), scenario.timeseries(cfg, recs, p)
        return scenario.reduce(cfg, recs, p)

    return jax.vmap(one)(params, keys)
