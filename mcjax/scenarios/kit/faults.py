"""Faults of a team's network, for every scenario with a comm graph: lost links (i.i.d. or in
bursts), lost agents, sensor dropouts — as ordinary Params (:data:`PARAMS`, all 0 by default).

* **Lost links.** A link's message is lost in a step with probability ``link_loss``,
  independently per link and step (``link_burst = 0``), or in bursts: each link is a two-state
  Gilbert–Elliott channel (Gilbert 1960, Elliott 1963) — *good* (delivered) or *bad* (lost) —
  a Markov chain whose stationary loss rate is ``link_loss`` and whose mean burst of losses
  lasts ``link_burst`` steps (:func:`channel_rates`). A link is symmetric: i's message to j is
  lost exactly when j's to i is. Only the messages are lost; the link's geometry (who is in
  range) is the scenario's.
* **Lost agents.** Each agent still alive is lost in a step with probability
  ``agent_loss_rate`` (a constant hazard, so its lifetime is geometric), for good: from that
  step on it senses nothing, sends and receives nothing, stops moving, and its estimate leaves
  the error statistics. Losses that would leave fewer than ``min_alive`` agents alive do not
  happen (of the agents drawn in one step, those with the smallest draws go first).
* **Sensor dropout.** Each agent's sensor returns nothing in a step with probability
  ``sensor_dropout`` (independently per agent and step).
* **Late messages.** With the Config field ``message_delay = k`` (:data:`DELAY_SETTINGS`, for
  a scenario whose filters take late messages) the consensus messages in flight are kept in a
  :class:`Mailbox` (:func:`mailbox`, :func:`late`, :func:`post`) and arrive k steps late.

The model is compiled in only with ``Config.faults = "on"`` (:data:`SETTINGS`): with
``"off"`` (the default) the program has no fault draws and is bit for bit the program without
faults, and :func:`check` rejects a non-zero fault Param. With ``"on"``, the draws come from
their own key stream, ``fold_in(step_key, FAULT_STREAM)`` (:func:`fault_key`), so they change
no other random number of a run; at rate 0 nothing is lost and every mask multiplies by 1 or
selects the unfaulted value, so the outputs equal the ``"off"`` program's up to rounding (the
compiled programs differ, and XLA may fuse and round their arithmetic differently).

A scenario uses the model through a few calls, each of which passes its input through
unchanged when the faults are off (``fault`` None): :func:`init` (the state before step 0),
:func:`advance` (the faults of one step: a :class:`Step`), :func:`measurements` and
:func:`messages` (what the sensors and links deliver), :func:`shield` / :func:`hold` (a lost
agent's filter state neither enters a neighbour's consensus nor changes), :func:`record` (a
:class:`Record` per step) and, to reduce the records, :func:`weights`,
:func:`summary_items` and :func:`series_items`. docs/library.md shows them in a user's
scenario.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from mcjax.contract import Output, Param, Setting, declare
from mcjax.tracking import graph
from mcjax.tracking.filters.consensus import Late
from mcjax.tracking.numerics import matvec

#: The constant folded into a step's key for the fault draws (``"FAUT"`` in ASCII).
FAULT_STREAM = 0x46415554

#: The Config field that compiles the fault model in (add to a scenario's ``config_type`` table).
SETTINGS = {
    "faults": Setting("off", "on: the fault Params (link_loss, link_burst, agent_loss_rate, min_alive, "
                      "sensor_dropout) draw faults; off: no fault draws in the program (the fault Params must "
                      "be at their defaults)", choices=("off", "on")),
}

#: The Config field of late consensus messages, for a scenario whose filters can take them
#: (a filter's traits say whether it takes late messages, :class:`mcjax.contract.filter.Traits`; a scenario whose
#: filters cannot does not declare it).
DELAY_SETTINGS = {
    "message_delay": Setting(0, "steps late the neighbours' consensus messages arrive (0: the same step); only "
                             "for the filters whose structure takes late messages (kcf; cif and local send none)",
                             "steps", low=0, integer=True),
}

#: The Params of lost links.
LINK_PARAMS = {
    "link_loss": Param(0.0, "", "probability that a link's message is lost in a step (the stationary rate with "
                                "link_burst)", low=0.0, high=1.0, label="link loss"),
    "link_burst": Param(0.0, "steps", "mean length of a burst of losses on a link (a Gilbert–Elliott channel); "
                                      "0: losses independent per step", low=0.0, label="mean burst"),
}

#: Every fault Param, as a scenario declares them (add to its ``params_type`` table).
PARAMS = {
    **LINK_PARAMS,
    "agent_loss_rate": Param(0.0, "1/step", "hazard of losing an agent for good, per agent and step (it stops "
                                            "sensing, sending and moving)", low=0.0, high=1.0, label="agent loss rate"),
    "min_alive": Param(1, "", "losses stop when this many agents are left alive (<= n_agents)", low=0,
                       integer=True, label="agents kept"),
    "sensor_dropout": Param(0.0, "", "probability that an agent's sensor returns nothing in a step",
                            low=0.0, high=1.0),
}


def check(cfg, values: dict, Params) -> list[tuple[str, str]]:
    """The checks across fault fields, ``[(field, what is allowed), …]``: every fault Param at
    its default unless ``cfg.faults = "on"``, ``link_burst`` fits ``link_loss``
    (:func:`burst_problem`), ``min_alive <= n_agents``. ``values`` as a scenario's
    ``check_params`` gets them; ``Params`` the scenario's (for the defaults)."""
    def value(name):
        return np.asarray(values.get(name, Params.TABLE[name].default_value(cfg)), np.float64)

    if cfg.faults == "off":
        return [(k, f"{p.default!r} unless config.faults = \"on\" (the fault model is compiled in only "
                    "when asked for)") for k, p in PARAMS.items() if np.any(value(k) != p.default)][:1]
    bad = []
    for loss, burst in np.broadcast(value("link_loss"), value("link_burst")):
        msg = burst_problem(float(loss), float(burst))
        if msg is not None:
            bad.append(("link_burst", msg))
            break
    if np.any(value("min_alive") > cfg.n_agents):
        bad.append(("min_alive", f"an integer in [0, n_agents = {cfg.n_agents}]"))
    return bad


def on(cfg) -> bool:
    """Whether ``cfg`` compiles the fault model in (``Config.faults = "on"``)."""
    return cfg.faults == "on"


def fault_key(step_key: jax.Array) -> jax.Array:
    """The key of a step's fault draws: ``fold_in(step_key, FAULT_STREAM)``."""
    return jax.random.fold_in(step_key, FAULT_STREAM)


def channel_rates(loss, burst):
    """``(p_gb, p_bb)``: the probabilities that a link is lost in the next step given it is
    delivered (good) or lost (bad) now. A Gilbert–Elliott chain with stationary loss rate
    ``π = loss`` and mean burst length ``L = burst`` leaves the bad state with ``p_bg = 1/L``
    (bursts are geometric), and balance ``π p_bg = (1 − π) p_gb`` gives ``p_gb = π / (L (1 − π))``;
    ``burst = 0`` is independent loss, ``p_gb = p_bb = π``. Valid for ``L ≥ max(1, π / (1 − π))``
    (:func:`burst_problem`)."""
    loss, burst = jnp.asarray(loss), jnp.asarray(burst)
    bursty = burst > 0
    safe_burst = jnp.where(bursty, burst, 1.0)
    p_gb = jnp.where(bursty, loss / (safe_burst * jnp.maximum(1.0 - loss, jnp.finfo(loss.dtype).tiny)), loss)
    p_bb = jnp.where(bursty, 1.0 - 1.0 / safe_burst, loss)
    return jnp.minimum(p_gb, 1.0), p_bb


def burst_problem(loss: float, burst: float) -> str | None:
    """None if ``(link_loss, link_burst)`` make a Gilbert–Elliott chain, else what is allowed."""
    if burst == 0:
        return None
    least = max(1.0, loss / (1.0 - loss)) if loss < 1 else float("inf")
    if burst < least * (1 - 1e-12):  # (0.8 / 0.2 is 4.000000000000001 in floating point)
        return f"0 or >= {least:g} steps for link_loss = {loss:g} (a burst lasts at least one step, and " \
               f"bursts must fit the loss rate)"
    return None


def _symmetric_uniform(key, n: int, dtype) -> jax.Array:
    """(n, n) uniform numbers with ``u[i, j] = u[j, i]`` (the upper triangle mirrored; the
    diagonal is that of the draw and unused)."""
    u = jax.random.uniform(key, (n, n), dtype)
    upper = jnp.triu(u, 1)
    return upper + upper.T + jnp.diag(jnp.diag(u))


def channel_init(key, n: int, loss, dtype=jnp.float64) -> jax.Array:
    """The links' states before step 0, drawn from the chain's stationary distribution (loss
    rate ``loss`` whatever the bursts): (n, n), 1.0 where the link is lost, symmetric."""
    return (_symmetric_uniform(key, n, dtype) < loss).astype(dtype)


def channel_step(key, lost: jax.Array, loss, burst) -> jax.Array:
    """The links' states one step on: each link lost with probability ``p_bb`` if it is lost
    now, ``p_gb`` if not (:func:`channel_rates`); symmetric like ``lost``."""
    p_gb, p_bb = channel_rates(loss, burst)
    u = _symmetric_uniform(key, lost.shape[-1], lost.dtype)
    return (u < jnp.where(lost > 0, p_bb, p_gb)).astype(lost.dtype)


def delivered(adjacency: jax.Array, lost: jax.Array) -> jax.Array:
    """The links whose messages arrive this step: ``adjacency · (1 − lost)`` (bit for bit the
    adjacency where nothing is lost)."""
    return adjacency * (1.0 - lost)


class State(NamedTuple):
    """The faults a run carries from step to step."""

    links: jax.Array    # (n, n) 1.0 where the link's channel is bad (messages lost), symmetric
    alive: jax.Array    # (n,) bool: not lost to faults (an agent the spec switched off stays True)


class Step(NamedTuple):
    """The faults of one step."""

    links: jax.Array    # (n, n) 1.0 where a link's message is lost this step
    alive: jax.Array    # (n,) bool: not lost to faults by this step
    sensing: jax.Array  # (n,) bool: the sensor works this step (no dropout)


def init(cfg, key, params) -> State | None:
    """The faults before step 0: the links' channels in their stationary state
    (:func:`channel_init`, from ``fault_key(key)``), every agent alive; None if off."""
    if not on(cfg):
        return None
    n, dtype = cfg.n_agents, jnp.dtype(cfg.dtype)
    lost = channel_init(fault_key(key), n, jnp.asarray(params.link_loss, dtype), dtype)
    return State(lost, jnp.ones(n, bool))


def _losses(key, alive, hazard, min_alive):
    """Which of the ``alive`` agents (n,) bool are lost this step: each with probability
    ``hazard``, at most ``Σ alive − min_alive`` of them (the smallest draws first)."""
    u = jax.random.uniform(key, alive.shape, hazard.dtype)
    drawn = alive & (u < hazard)
    room = jnp.maximum(jnp.sum(alive) - jnp.asarray(min_alive).astype(jnp.int32), 0)
    rank = jnp.argsort(jnp.argsort(jnp.where(drawn, u, jnp.inf)))
    return drawn & (rank < room)


def advance(key, state: State | None, params, static_alive) -> tuple[State | None, Step | None]:
    """The faults of the step whose key is ``key``: the links' channels move one step
    (:func:`channel_step`), agents are lost (``agent_loss_rate``, never below ``min_alive``
    agents alive, counted over ``static_alive`` (n,) bool, the agents the spec switched on),
    sensors drop out (``sensor_dropout``). Returns the new state and the step's faults
    (``(None, None)`` if off: ``state`` None)."""
    if state is None:
        return None, None
    k_links, k_agents, k_sensors = jax.random.split(fault_key(key), 3)
    dtype = state.links.dtype
    links = channel_step(k_links, state.links, jnp.asarray(params.link_loss, dtype),
                         jnp.asarray(params.link_burst, dtype))
    lost = _losses(k_agents, state.alive & static_alive, jnp.asarray(params.agent_loss_rate, dtype), params.min_alive)
    alive = state.alive & ~lost
    sensing = jax.random.uniform(k_sensors, alive.shape, dtype) >= jnp.asarray(params.sensor_dropout, dtype)
    return State(links, alive), Step(links, alive, sensing)


def alive(faults: Step | None, n: int):
    """(n,) bool: the agents not lost to faults (all of them if off)."""
    return jnp.ones(n, bool) if faults is None else faults.alive


def messages(adjacency, faults: Step | None):
    """The links that carry a message this step: ``adjacency`` without the lost links
    (:func:`delivered`) and without any link of a lost agent."""
    if faults is None:
        return adjacency
    a = faults.alive.astype(adjacency.dtype)
    return delivered(adjacency, faults.links) * a[:, None] * a[None, :]


def measurements(z, faults: Step | None):
    """``z`` (n, m) with NaN for the agents whose sensor dropped out or who are lost."""
    if faults is None:
        return z
    return jnp.where((faults.sensing & faults.alive)[:, None], z, jnp.nan)


def _agent_where(alive, a, b):
    """``where(alive, a, b)`` over an agent-leading leaf (``alive`` broadcast to its shape)."""
    return jnp.where(alive.reshape(alive.shape + (1,) * (a.ndim - 1)), a, b)


def shield(faults: Step | None, states):
    """Filter states (pytree, agents on the leading axis of every leaf) with each lost agent's
    entries replaced by those of the lowest-numbered agent still ``alive``: a lost agent has no
    link, so its entries enter a neighbour's consensus with weight 0, and a finite stand-in
    keeps ``0 × NaN`` (say of a diverged lost agent) out of the sums. Unchanged while every
    agent is alive."""
    if faults is None:
        return states
    first = jnp.argmax(faults.alive)
    return jax.tree.map(lambda a: _agent_where(faults.alive, a, a[first][None]), states)


def hold(faults: Step | None, new, old):
    """The new filter states for the agents alive; a lost agent's stay as they were."""
    if faults is None:
        return new
    return jax.tree.map(lambda a, b: _agent_where(faults.alive, a, b), new, old)


class Record(NamedTuple):
    """One step's faults, as a scenario's record carries them (stacked over time by the engine)."""

    alive: jax.Array        # (n,) bool: not lost to faults
    links: jax.Array        # () links in comm range between agents the spec switched on
    links_lost: jax.Array   # () of them, links whose message was lost (a lost agent's links included)
    dropouts: jax.Array     # () alive agents whose sensor dropped out
    cut: jax.Array          # () bool: the graph of messages is disconnected, the comm graph is not


def record(adjacency, carried, faults: Step | None, static_alive) -> Record | None:
    """The :class:`Record` of a step: ``adjacency`` the comm graph of the agents the spec
    switched on (``static_alive``), ``carried`` the links that carried a message
    (:func:`messages`); None if off."""
    if faults is None:
        return None

    def connected(a):
        n_on = jnp.sum(static_alive)
        return jnp.all(jnp.where(static_alive, graph.component_sizes(a) == n_on, True))

    upper = jnp.triu(jnp.ones_like(adjacency), 1)
    links, links_lost = jnp.sum(upper * adjacency), jnp.sum(upper * (adjacency - carried))
    dropouts = jnp.sum(faults.alive & static_alive & ~faults.sensing)
    return Record(faults.alive, links, links_lost, dropouts, connected(adjacency) & ~connected(carried))


def weights(static_alive, r: Record | None):
    """The error statistics' weights per step and agent (T, n): the agents the spec switched
    on (``static_alive`` (n,) 0/1 weights) and not yet lost to faults (``static_alive``
    itself if off: ``r`` None)."""
    if r is None:
        return static_alive
    return static_alive * r.alive.astype(static_alive.dtype)


def masked(values, weights):
    """``values`` (T, …, n) with 0 wherever ``weights`` (T, n) is 0, so that a lost agent's
    values (which may be anything, NaN included) leave a weighted statistic instead of entering
    it as ``0 × value``; unchanged for (n,) weights (faults off: the statistic as it was)."""
    if weights.ndim < 2:
        return values
    w = weights.reshape(weights.shape[:1] + (1,) * (values.ndim - 2) + weights.shape[-1:])
    return jnp.where(w > 0, values, jnp.zeros_like(values))


def summary_items(cfg, r: Record | None, static_alive):
    """The per-run fault outputs of the stacked records ``r``, each declared next to its value
    (``static_alive``: a function of no arguments giving the (n,) 0/1 weights of the agents the
    spec switched on); none if off."""
    if cfg is not None and not on(cfg):
        return {}

    def lost_steps():
        gone = (~r.alive) & (static_alive()[None] > 0)         # (T, n)
        ever = jnp.any(gone, 0)
        return jnp.where(ever, jnp.argmax(gone, 0), -1), ever

    def first_loss():
        at, ever = lost_steps()
        return jnp.where(jnp.any(ever), jnp.min(jnp.where(ever, at, jnp.iinfo(at.dtype).max)), -1)

    return declare(
        links_lost=(Output("", "fraction of the link-steps in comm range whose message was lost (link loss and "
                           "lost agents)", False), lambda: jnp.sum(r.links_lost) / jnp.maximum(jnp.sum(r.links), 1)),
        agents_lost=(Output("", "agents lost to faults (agent_loss_rate) by the last step", False),
                     lambda: jnp.sum(lost_steps()[1])),
        first_loss_step=(Output("steps", "step at which the first agent was lost (-1: none)", False), first_loss),
        dropout_steps=(Output("", "agent-steps in which an alive agent's sensor dropped out", False),
                       lambda: jnp.sum(r.dropouts)),
        fault_disconnected_steps=(Output("steps", "steps in which the comm graph was connected but its messages "
                                         "were not, because of faults", False), lambda: jnp.sum(r.cut)),
    )


def series_items(cfg, r: Record | None, static_alive):
    """Per-step fault series of the stacked records ``r`` (see :func:`summary_items`)."""
    if cfg is not None and not on(cfg):
        return {}
    return declare(
        agents_alive=(Output("", "agents switched on and not lost to faults", False),
                      lambda: jnp.sum(weights(static_alive(), r), -1)),
        links_lost=(Output("", "links in comm range whose message was lost", False), lambda: r.links_lost),
    )


#: The names of the fault outputs (summary and series), e.g. to leave them out of a comparison.
#: The fault Params, for a scenario's relaxation switch (:class:`mcjax.contract.Relaxation`): rates of
#: random draws have no smooth path (the draws are thresholds of uniform numbers).
ROUGH = tuple(PARAMS)
SUMMARY_OUTPUTS = tuple(summary_items(None, None, None))
SERIES_OUTPUTS = tuple(series_items(None, None, None))


class Mailbox(NamedTuple):
    """The consensus messages in flight when they arrive ``k = message_delay`` steps late: the
    estimates x̂ of steps t−k−1 … t−2 (the predictions sent at t−k … t−1 are ``F x̂``) and the
    links that carried the messages of steps t−k … t−1. (k, n, d) and (k, n, n)."""

    estimates: jax.Array
    links: jax.Array


def mailbox(cfg, x0) -> Mailbox | None:
    """The messages in flight before step 0: none carried (no link), every estimate the prior
    ``x0`` (d,) — None when ``message_delay = 0``."""
    k, n = cfg.message_delay, cfg.n_agents
    if k == 0:
        return None
    return Mailbox(jnp.broadcast_to(x0, (k, n) + x0.shape), jnp.zeros((k, n, n), x0.dtype))


def late(box: Mailbox, F) -> Late:
    """The messages that arrive at this step, sent ``k`` steps ago: the predictions
    ``F x̂(t−k−1) = x̄(t−k)`` (``F`` this step's transition; the model is time-invariant after
    step 0) and the links that carried them."""
    return Late(matvec(F, box.estimates[0]), box.links[0])


def post(box: Mailbox, estimates, carried) -> Mailbox:
    """The mailbox one step on: this step's sent estimates (the posteriors x̂(t−1) (n, d) the
    agents predicted from) and ``carried`` (n, n), the links that carry this step's messages."""
    return Mailbox(jnp.concatenate([box.estimates[1:], estimates[None]]),
                   jnp.concatenate([box.links[1:], carried[None]]))
