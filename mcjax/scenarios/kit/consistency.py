"""Is a filter honest about its own error: NEES and NIS outputs (Bar-Shalom, Li & Kirubarajan 2001,
§5.4) that a scenario with ``consistency = "on"`` records for every filter.

* NEES ``eᵀ P⁻¹ e`` of each agent's estimate of the state it tracks (the scenario computes it with
  :func:`mcjax.tracking.metrics.nees`; an IMM's from its combined mean and covariance): χ² with the state's
  dimension when the filter is consistent.
* NIS ``νᵀ S⁻¹ ν`` of each agent's own measurement against its own prediction from its last
  estimate (:func:`predicted_nis`): ``ν = z − h(x̄)``, ``S = H P̄ Hᵀ + R`` with ``x̄ = F x``,
  ``P̄ = F P Fᵀ + Q`` the filter's model; χ² with the measurement's dimension. A consensus filter
  fuses more than its own measurement, but its own measurement is still independent of its
  prediction, so the same χ² holds when the filter is consistent.

The outputs carry their degrees of freedom (:class:`mcjax.contract.Output` ``dof``), from which
the report draws the χ² bands (:func:`mcjax.analysis.statistics.chi2_band`)."""

from __future__ import annotations

from functools import cache

import jax
import jax.numpy as jnp

from mcjax.contract import Output, Setting
from mcjax.tracking import metrics
from mcjax.tracking.filters.gaussian import Gaussian
from mcjax.tracking.filters.imm import IMMState, combine, mix
from mcjax.tracking.numerics import spd_inverse, symmetrize, wrap_angle

#: The Config switch (off: the program without the NIS and the per-step series, bit for bit).
SETTING = Setting("off", "consistency outputs (Bar-Shalom et al. 2001): on adds each filter's average NIS (anis) "
                  "and the per-step NEES and NIS series (nees, nis) the report draws against their chi-square "
                  "bands; off is the program without them", choices=("off", "on"))


def predicted_nis(prior, F, Q, h, sensors, z, R_inv, angle_mask):
    """The NIS (n,) of each agent's measurement ``z`` (n, m) against its prediction from ``prior``
    (a Gaussian with an agent axis first: x (n, d), P (n, d, d)) through the filter's model ``F``,
    ``Q`` (``(I, 0)`` at the first measurement time) and ``h(x, sensor)``; ``R_inv`` (n, m, m) or
    (m, m); the angle components (``angle_mask``) of the innovation wrapped. NaN where no
    measurement was taken (module docstring; Bar-Shalom et al. 2001 eq. 5.4.2-3)."""
    n = z.shape[0]
    R = spd_inverse(jnp.broadcast_to(R_inv, (n,) + R_inv.shape[-2:]))

    def one(x, P, sensor, zi, Ri):
        xb, Pb = F @ x, symmetrize(F @ P @ F.T + Q)
        H = jax.jacfwd(lambda s: h(s, sensor))(xb)
        nu = zi - h(xb, sensor)
        nu = jnp.where(angle_mask, wrap_angle(nu), nu)
        return metrics.nis(nu, spd_inverse(symmetrize(H @ Pb @ H.T + Ri)))

    taken = jnp.all(jnp.isfinite(z), axis=-1)
    value = jax.vmap(one)(prior.x, prior.P, sensors, jnp.where(taken[:, None], z, 0.0), R)
    return jnp.where(taken, value, jnp.nan)


def imm_prediction(state, transition, F_modes, Q_modes):
    """The combined prediction of an IMM (a Gaussian with an agent axis first: x (n, d), P (n, d, d)):
    mixed (:func:`mcjax.tracking.filters.imm.mix`), each mode predicted by its linear model, then
    moment-matched over the predicted mode probabilities c̄ (:func:`mcjax.tracking.filters.imm.combine`) —
    the prediction whose NIS :func:`predicted_nis` takes with ``(I, 0)``. ``state`` an IMMState with
    the agent axis first; ``F_modes``, ``Q_modes`` (M, d, d)."""
    def one(s):
        cbar, x0, P0 = mix(s, transition)
        xb = jnp.einsum("mab,mb->ma", F_modes, x0)
        Pb = jnp.einsum("mab,mbc,mdc->mad", F_modes, P0, F_modes) + Q_modes
        return combine(IMMState(cbar, xb, Pb))

    x, P = jax.vmap(one)(state)
    return Gaussian(x, P, None)


def _weights(values, alive):
    """0/1 weights (T, F, n) of finite values of alive agents (``alive`` (n,) or (T, n))."""
    a = alive if alive.ndim == 2 else jnp.broadcast_to(alive, (values.shape[0], alive.shape[-1]))
    return jnp.isfinite(values) & (a[:, None, :] > 0)


def run_average(values, alive, warmup: int):
    """Per filter (F,): the mean of ``values`` (T, F, n) over the alive agents and steps after
    ``warmup`` where it is finite (NaN where none is)."""
    w = _weights(values, alive) & (jnp.arange(values.shape[0]) >= warmup)[:, None, None]
    total = jnp.sum(jnp.where(w, values, 0.0), axis=(0, 2))
    count = jnp.sum(w, axis=(0, 2))
    return jnp.where(count > 0, total / jnp.maximum(count, 1), jnp.nan)


def step_average(values, alive):
    """Per step and filter (T, F): the mean of ``values`` (T, F, n) over the alive agents where it is
    finite (NaN where none is)."""
    w = _weights(values, alive)
    count = jnp.sum(w, axis=-1)
    return jnp.where(count > 0, jnp.sum(jnp.where(w, values, 0.0), axis=-1) / jnp.maximum(count, 1), jnp.nan)


def anees_output(dof: int, what: str = "full-state") -> Output:
    """The declaration of a run's average NEES (role ``"nees"``, ``dof`` the state's dimension)."""
    return Output("", f"mean {what} NEES over alive agents and steps after warm-up ({dof} dof; consistent "
                      f"filters average {dof})", True, "nees", dof)


def summary_items(cfg, nees, nis, alive, warmup: int, state_dof: int, meas_dof: int, *, anees: bool = True):
    """The consistency summary, when ``cfg.consistency`` is on: ``anees`` (unless the scenario
    declares it itself: ``anees=False``) and ``anis``, from functions of no arguments giving the
    NEES and NIS (T, F, n) (NIS NaN where no measurement) and the alive weights."""
    if cfg.consistency != "on":
        return {}
    out = {}
    if anees:
        out["anees"] = (anees_output(state_dof), lambda: run_average(nees(), alive(), warmup))
    out["anis"] = (Output("", f"mean NIS of each agent's own measurement over alive agents and steps after warm-up "
                              f"({meas_dof} dof; consistent filters average {meas_dof})", True, "nis", meas_dof),
                   lambda: run_average(nis(), alive(), warmup))
    return out


def series_items(cfg, nees, nis, alive, state_dof: int, meas_dof: int):
    """The per-step ``nees`` and ``nis`` (T, F), averaged over the alive agents (NIS: those with a
    measurement), when ``cfg.consistency`` is on."""
    if cfg.consistency != "on":
        return {}
    a = cache(lambda: alive())
    return {"nees": (Output("", f"NEES averaged over alive agents ({state_dof} dof)", True, "nees", state_dof),
                     lambda: step_average(nees(), a())),
            "nis": (Output("", f"NIS averaged over the alive agents with a measurement ({meas_dof} dof)", True, "nis",
                           meas_dof), lambda: step_average(nis(), a()))}
