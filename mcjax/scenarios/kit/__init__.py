"""The scenario kit: what every scenario shares, so a scenario folder holds only its own system.

* :mod:`~mcjax.scenarios.kit.settings` — the Config fields every tracking scenario has
  (:func:`common_settings`, :func:`check_common`), Params as arrays (:func:`cast`, :func:`typed`,
  :func:`agents`, :func:`param_value`), :func:`per_run`;
* :mod:`~mcjax.scenarios.kit.sensing` — every agent's range–bearing measurement
  (:func:`team_measurements`, :func:`soft_team_measurements`), measuring and linking with faults
  and relaxation in one call (:func:`sense_and_link`), the comm graph and the links that carried a
  message (:func:`link`), the fault-aware filter update
  (:func:`shield_filters`, :func:`hold_filters`, :func:`filter_update`), the KCF's late messages before step 0 (:func:`kcf_mailbox`);
* :mod:`~mcjax.scenarios.kit.outputs` — the per-filter error summary, graph statistics and error
  series declared next to their values (:func:`error_items`, :func:`graph_items`,
  :func:`error_series_items`; :func:`error_outputs`, :data:`GRAPH_OUTPUTS`, ...), the weights of
  the agents switched on and alive (:func:`team_weights`), the training loss's errors and
  weights (:func:`training_errors`, :func:`training_weights`);
* :mod:`~mcjax.scenarios.kit.bound` — the posterior Cramér–Rao bound carried step by step with
  ``bound = "on"`` (its Config setting, update, outputs);
* :mod:`~mcjax.scenarios.kit.consistency` — NEES and NIS outputs with ``consistency = "on"`` (its
  Config setting, each agent's NIS against its prediction, averages, outputs);
* :func:`aliases` — a scenario module's usual names for its record's functions.
"""

from mcjax.scenarios.kit.outputs import (GRAPH_OUTPUTS, declarations, error_items, error_outputs, error_series_items,
                                         error_series_outputs, error_summary, graph_items, team_weights,
                                         training_errors, training_weights)
from mcjax.scenarios.kit.sensing import (Sensed, filter_update, hold_filters, kcf_mailbox, link, sense_and_link, shield_filters, soft_team_measurements,
                                         team_measurements)
from mcjax.scenarios.kit.settings import (DTYPES, agents, cast, check_common, common_settings, param_value, per_run,
                                          shown_filter_names, typed)


def aliases(scenario) -> tuple:
    """``(default_params, reduce, outputs, timeseries, timeseries_outputs)`` of a Scenario record: the
    names a scenario module gives them (``default_params, reduce, outputs, timeseries,
    timeseries_outputs = kit.aliases(SCENARIO)``)."""
    return (scenario.default_params, scenario.reduce, scenario.outputs, scenario.timeseries,
            scenario.timeseries_outputs)


__all__ = ["GRAPH_OUTPUTS", "declarations", "error_items", "error_outputs", "error_series_items",
           "error_series_outputs", "error_summary", "graph_items", "team_weights", "training_errors",
           "training_weights", "Sensed", "filter_update", "hold_filters", "kcf_mailbox", "link", "sense_and_link", "shield_filters", "soft_team_measurements",
           "team_measurements", "DTYPES", "agents", "cast", "check_common", "common_settings", "param_value",
           "per_run", "shown_filter_names", "typed", "aliases"]
