"""The relaxation switch of Ren & Lv 2017's scenario: smooth versions of the sonar's range gate,
the comm links, the component sizes the consensus weighs the measurement information by, and
the IMM's "likelier mode" indicator. The scenario's ``step`` uses them when given a
:class:`Temperatures` (training by gradient, ``mcjax tune``; sensitivities of a sweep).

What stays rough (no smooth path): the target's mode jumps — the fixed schedule's switch at
``ct_start`` / ``ct_stop`` (step counts) and the Markov chain's draws (thresholds of uniform
numbers) — and the fault model's draws (:data:`mcjax.scenarios.kit.faults.ROUGH`)."""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp


class Temperatures(NamedTuple):
    """Temperatures of the relaxation switch (the scenario's ``step`` with ``temperatures``); ours,
    fixed before any tune was run. The UUVs of the paper's layout are 400 m from their ring
    neighbours and the default comm radius is 450 m, so the smallest link margin is 50 m: at
    10 m a ring link weighs sigmoid(5) = 0.993 and a second neighbour (693 m) 3e-11."""

    sensing: float = 10.0   # m, the sonar's range gate sigmoid((R_s − r)/T)
    comm: float = 10.0      # m, the comm links sigmoid((min(R_i, R_j) − l_ij)/T) and the component sizes
    mode: float = 0.05      # probability, the IMM's "CT is likelier" indicator sigmoid((μ_CT − 0.5)/T)








def mode_hits(mu_ct, turns, temperature=None):
    """Per UUV (n,), whether the IMM's likelier mode is the target's true one: ``μ_CT > 0.5``
    equals ``turns`` (the target is in CT) → 1.0, else 0.0 — what the output ``mode_accuracy``
    averages. With a ``temperature`` T the indicator of ``μ_CT > 0.5`` becomes
    ``sigmoid((μ_CT − 0.5)/T)`` (the true mode is the truth's, not smoothed). NaN ``μ_CT``
    (no IMM) gives 0/1 in the exact simulation and NaN when smoothed; ``mode_accuracy`` is
    NaN then either way."""
    if temperature is None:
        return ((mu_ct > 0.5) == turns).astype(mu_ct.dtype)
    p = jax.nn.sigmoid((mu_ct - 0.5) / temperature)
    return jnp.where(turns, p, 1.0 - p)
