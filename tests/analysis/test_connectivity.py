"""The default page's papercuts of issue 67, item 7: the trend sentence does not quote again the intervals
a headline quoted, and a per-run mean λ2 that is not monotone in the swept axis is explained with numbers
computed here from the runs (a mean over every step, a disconnected step counting 0)."""

from __future__ import annotations

import re

import numpy as np
import pytest

from mcjax.analysis import findings
from mcjax.analysis.statistics import mean_ci
from tests.analysis.test_tables import make_metadata, synthetic_runs

STEPS = 100
RADII = [50e3, 60e3, 80e3]


def _graph_runs(connected: dict, broken: dict, seeds: int = 30):
    """Runs over RADII whose per-run λ2 over the connected steps is ``connected[r]`` (plus a little noise)
    and which spend ``broken[r]`` of their STEPS steps disconnected (λ2 = 0 there)."""
    grid = {"comm_radius": RADII}
    runs = synthetic_runs(grid, seeds=seeds, divergence=False)
    rng = np.random.default_rng(3)
    per_run = {}
    for (p, s), g in runs.groupby(["comm_radius", "seed_index"]):
        per_run[(p, s)] = connected[p] * (1 + 0.02 * rng.standard_normal())
    lam = np.array([per_run[(p, s)] for p, s in zip(runs["comm_radius"], runs["seed_index"])])
    d = runs["comm_radius"].map(broken).to_numpy()
    runs["disconnected_steps"] = d
    runs["lambda2_mean"] = lam * (STEPS - d) / STEPS
    meta = make_metadata(grid, divergence=False)
    meta["config"] = {**meta["config"], "n_steps": STEPS}
    return runs, meta


def _sentence(runs, meta) -> str | None:
    said = [f.text for f in findings.findings(runs, meta) if "not monotone" in f.text]
    assert len(said) <= 1, said
    return said[0] if said else None


def test_a_non_monotone_mean_lambda2_made_by_the_disconnected_steps_says_so():
    """Over the connected steps λ2 rises with the radius (1.0, 1.2, 1.4); half the steps at 60 km are
    disconnected, so the mean over every step dips there (0.6)."""
    runs, meta = _graph_runs({50e3: 1.0, 60e3: 1.2, 80e3: 1.4}, {50e3: 0, 60e3: 50, 80e3: 0})
    text = _sentence(runs, meta)
    assert text is not None
    at60 = runs[runs["comm_radius"] == 60e3].drop_duplicates("seed_index")
    whole = mean_ci(at60["lambda2_mean"].to_numpy())
    connected = mean_ci(at60["lambda2_mean"].to_numpy() * STEPS / (STEPS - 50))
    assert f"{float(f'{whole.mean:.4g}'):g}" in text and f"{float(f'{connected.mean:.4g}'):g}" in text
    assert "a step with the graph disconnected counting 0" in text
    assert text.endswith("monotone: the steps the graph spent disconnected (disconnected_steps) make the difference.")


def test_a_non_monotone_mean_lambda2_with_connected_graphs_that_differ_says_so():
    """The default sweep's case: the mean over every step is higher at 50 km than at 60 km although the
    graph breaks for more steps at 50 km; over the connected steps it is not monotone either."""
    runs, meta = _graph_runs({50e3: 1.3, 60e3: 0.7, 80e3: 1.8}, {50e3: 40, 60e3: 17, 80e3: 0})
    text = _sentence(runs, meta)
    assert text is not None and "not monotone either: the steps spent disconnected do not explain it" in text
    assert "(the same at 80000 m, where it never disconnected)" in text


@pytest.mark.parametrize("connected", [{50e3: 1.0, 60e3: 1.2, 80e3: 1.4}, {50e3: 1.0, 60e3: 1.0, 80e3: 1.0}])
def test_a_monotone_mean_lambda2_gets_no_such_sentence(connected):
    runs, meta = _graph_runs(connected, {50e3: 0, 60e3: 0, 80e3: 0})
    assert _sentence(runs, meta) is None


def test_the_trend_does_not_quote_again_the_intervals_a_headline_quoted():
    """The default page quoted 'at 100 km: 17.48 m [16.61, 18.35] against 32.89 m [31.93, 33.85]' in its
    headline and both intervals again in the trend; the trend now gives those means alone, '(above)'."""
    grid = {"eps": [0.1, 1.0, 10.0]}  # the synthetic error rises with eps
    runs = synthetic_runs(grid, seeds=20, divergence=False)
    noise = 1 + 0.02 * np.random.default_rng(5).standard_normal(len(runs))
    runs["rmse"] = (1 + runs["eps"]) * runs["filter"].map({"kf": 1.0, "local": 2.0, "ekf": 3.0}) * noise
    meta = make_metadata(grid, divergence=False)
    meta["headlines"] = [["kf", "local"]]
    said = {f.kind: f.text for f in findings.findings(runs, meta)}
    intervals = re.findall(r"\d[\d.]* m \[[^\]]+\]", said["headline"])
    assert intervals, said["headline"]
    trend = said["trend"]
    assert not [i for i in intervals if i in trend], (intervals, trend)
    for i in intervals:  # each mean is still given, pointing to the sentence that quoted its interval
        assert f"{i.split(' [')[0]} (above)" in trend, (i, trend)
