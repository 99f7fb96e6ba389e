"""Sensing and linking, faults included: every agent's range–bearing measurement of the target
(exact range gate or soft gate), the comm graph (exact or soft) and the links that carried the
step's message; the fault-aware filter update (shield the inputs, hold a lost agent's state)."""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from mcjax.scenarios.kit import faults
from mcjax.scenarios.kit.settings import per_run
from mcjax.tracking import connectivity, graph
from mcjax.tracking.filters.steps import centralised, delayed_sender, filter_step
from mcjax.tracking.models.sensors import measure_range_bearing, range_bearing


def team_measurements(key, target, sensors, sigma_range, sigma_bearing, sensing_radius, alive):
    """Every agent's noisy range–bearing measurement of ``target`` (n, 2), NaN where the
    target is out of the agent's ``sensing_radius`` (n,) or the agent is not ``alive`` (n,)
    — :func:`mcjax.tracking.models.sensors.measure_range_bearing` with one key per agent."""
    keys = jax.random.split(key, sensors.shape[0])
    return jax.vmap(measure_range_bearing, in_axes=(0, None, 0, None, None, 0, 0))(
        keys, target, sensors, sigma_range, sigma_bearing, sensing_radius, alive)


def soft_team_measurements(key, target, sensors, sigma_range, sigma_bearing, sensing_radius, alive, temperature):
    """:func:`team_measurements` (the same noise draws) with the range gate ``r ≤ R_s`` replaced
    by a soft gate ``g_i = sigmoid((R_s − r_i)/T)``, for a scenario's relaxation switch: returns
    ``(z (n, 2), g (n,))``, every alive agent's measurement and its weight (the caller weighs
    agent i's measurement information by ``g_i``). Dead agents: NaN, ``g = 0``."""
    z = team_measurements(key, target, sensors, sigma_range, sigma_bearing,
                          jnp.full(sensors.shape[0], jnp.inf, sensors.dtype), alive)
    r = jax.vmap(range_bearing, in_axes=(None, 0))(target, sensors)[:, 0]
    return z, jnp.where(alive, jax.nn.sigmoid((sensing_radius - r) / temperature), 0.0)


class Sensed(NamedTuple):
    """One step's measurements and links (:func:`sense_and_link`)."""

    z: jax.Array                 # (n, 2) range–bearing measurements, NaN where there is none
    comm_graph: jax.Array        # (n, n) the comm graph among the agents switched on (0/1, or soft weights)
    carried: jax.Array           # (n, n) its links whose message was not lost (:func:`mcjax.scenarios.kit.faults.messages`)
    gates: jax.Array | None      # (n,) the soft sensing gates (smooth system), else None
    sizes: jax.Array | None      # (n,) the soft component sizes (smooth system), else None


def sense_and_link(key, target, sensors, params, sensing, comm, alive, fault, temperatures=None) -> Sensed:
    """Every agent's range–bearing measurement of ``target`` (noise ``params.sigma_range``,
    ``params.sigma_bearing``) within its ``sensing`` radius (n,), the comm graph of radius ``comm`` (n,)
    among the agents ``alive`` (n,) (switched on by the spec) and the links that carried the step's
    message, with the step's ``fault`` (:func:`mcjax.scenarios.kit.faults.advance`; None: off) applied:
    a lost agent senses nothing, a dropped-out sensor returns nothing, a lost link carries nothing.

    ``temperatures`` (a scenario's relaxation switch with ``sensing`` and ``comm`` temperatures; None:
    exact) swaps the range gate for soft gates (:func:`soft_team_measurements`) and the comm graph
    for soft links (:func:`mcjax.tracking.graph.soft_adjacency`), with the same random draws, and gives the
    soft component sizes (:func:`mcjax.tracking.connectivity.soft_component_sizes`), which see lost agents, not lost links."""
    if temperatures is None:
        z = faults.measurements(team_measurements(key, target, sensors, params.sigma_range, params.sigma_bearing,
                                                  sensing, alive), fault)
        gates = sizes = None
    else:
        z, gates = soft_team_measurements(key, target, sensors, params.sigma_range, params.sigma_bearing,
                                          sensing, alive, temperatures.sensing)
        z = faults.measurements(z, fault)
        sizes = connectivity.soft_component_sizes(sensors, comm, temperatures.comm, alive & faults.alive(fault, sensors.shape[0]))
    return Sensed(z, *link(sensors, comm, fault, temperatures, alive), gates, sizes)


def link(positions, comm, fault, temperatures=None, alive=None) -> tuple:
    """``(comm_graph, carried)``: the comm graph of radius ``comm`` (scalar or (n,)) among the agents
    ``alive`` (all if None) — Sun et al. 2011 eq. 13, or its soft links at ``temperatures.comm``
    (:func:`mcjax.tracking.graph.soft_adjacency`) — and its links whose message the step's ``fault`` did not lose."""
    if temperatures is None:
        comm_graph = graph.adjacency(positions, comm, alive)
    else:
        comm_graph = graph.soft_adjacency(positions, comm, temperatures.comm, alive)
    return comm_graph, faults.messages(comm_graph, fault)


def shield_filters(fault, kinds, states) -> tuple:
    """The filters' states (one per kind of ``kinds``) as they enter a step under faults: each lost
    agent's entries replaced by a finite stand-in (:func:`mcjax.scenarios.kit.faults.shield`), but for
    a centralised filter (its traits: one estimate, which no link carries)."""
    return tuple(s if centralised(k) else faults.shield(fault, s) for k, s in zip(kinds, states))


def hold_filters(fault, kinds, new, old) -> tuple:
    """The filters' states after a step under faults: a lost agent's stay as they were
    (:func:`mcjax.scenarios.kit.faults.hold`), but for a centralised filter's."""
    return tuple(s if centralised(k) else faults.hold(fault, s, o) for k, s, o in zip(kinds, new, old))


def kcf_mailbox(cfg, params, x0):
    """The consensus messages in flight before step 0 of the filter that sends them late (the KCF among the
    built-ins; :func:`mcjax.tracking.filters.steps.delayed_sender`; :func:`mcjax.scenarios.kit.faults.mailbox`;
    None without a message delay or without such a filter), per-run from the start (:func:`per_run`)."""
    box = faults.mailbox(cfg, x0) if delayed_sender(cfg.filters) is not None else None
    return None if box is None else faults.Mailbox(*per_run(params.dt, *box))


def filter_update(kinds, opts, h, angle_mask, states, meas, F, Q, kcf_epsilon, fault, mailbox=None) -> tuple:
    """``(filters, mailbox)``: every filter of ``kinds`` one step on (:func:`mcjax.tracking.filters.steps.filter_step`)
    under faults — the states shielded before (:func:`shield_filters`), a lost agent's held after
    (:func:`hold_filters`) — and, with a ``mailbox`` (:func:`kcf_mailbox`), the KCF's consensus messages
    arriving late (:func:`mcjax.scenarios.kit.faults.late`), this step's posted over the links that carried
    one (``meas.adjacency``)."""
    shielded = shield_filters(fault, kinds, states)
    if mailbox is None:
        filters = filter_step(kinds, opts, h, angle_mask, shielded, meas, F, Q, kcf_epsilon)
    else:  # the sender's consensus messages arrive message_delay steps late
        sender = delayed_sender(kinds)
        late = meas._replace(late=faults.late(mailbox, F))
        filters = tuple(filter_step((k,), opts, h, angle_mask, (f,), late if i == sender else meas, F, Q,
                                    kcf_epsilon)[0] for i, (k, f) in enumerate(zip(kinds, shielded)))
        mailbox = faults.post(mailbox, shielded[sender].x, meas.adjacency)
    return hold_filters(fault, kinds, filters, states), mailbox
