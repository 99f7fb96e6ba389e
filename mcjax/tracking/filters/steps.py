"""One step of any of the consensus filters by its kind: the consensus filters of Sun et al. 2011 and
Chen & Lu 2013 (:mod:`.consensus`) and the robust ones of Battistelli & Chisci (:mod:`.robust_consensus`),
side by side, so neither module imports the other."""

from __future__ import annotations

from mcjax.tracking.filters.consensus import (FILTER_KINDS, FilterOptions, Measurements, cif_step, icf_step,
                                              kcf_step, local_step, modified_icf_step, prior_consensus_kcf_step)
from mcjax.tracking.filters.robust_consensus import ci_step, hcmci_step


def filter_step(kinds, opts: FilterOptions, h, angle_mask, states, meas: Measurements, F, Q, kcf_epsilon,
                formation=None):
    """Advance every filter in ``kinds`` by one step. Returns the new states (same
    structure as ``states``). ``formation``: eq. 12's formation term of Chen & Lu 2013's
    consensus Kalman filter (:func:`prior_consensus_kcf_step`), if any."""
    out = []
    for kind, post in zip(kinds, states):
        if kind == "cif":
            out.append(cif_step(h, angle_mask, post, meas, F, Q))
        elif kind == "local":
            out.append(local_step(h, angle_mask, post, meas, F, Q))
        elif kind == "modified_icf":
            out.append(modified_icf_step(h, angle_mask, opts, post, meas, F, Q))
        elif kind == "icf":
            out.append(icf_step(h, angle_mask, opts, post, meas, F, Q))
        elif kind == "kcf" and opts.kcf_gain == "prior_consensus":
            out.append(prior_consensus_kcf_step(h, angle_mask, opts, post, meas, F, Q, formation))
        elif kind == "kcf":
            out.append(kcf_step(h, angle_mask, opts, kcf_epsilon, post, meas, F, Q))
        elif kind == "ci":  # Battistelli & Chisci 2014
            out.append(ci_step(h, angle_mask, opts, post, meas, F, Q))
        elif kind == "hcmci":  # Battistelli et al. 2015
            out.append(hcmci_step(h, angle_mask, opts, post, meas, F, Q))
        else:
            raise ValueError(f"kind must be one of {', '.join(map(repr, FILTER_KINDS))}; got {kind!r}")
    return tuple(out)
