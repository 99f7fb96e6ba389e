"""Consistency of a filter: the χ² bands of an averaged NEES / NIS (mcjax.analysis.statistics.chi2_band)
against scipy's quantiles, mcjax.tracking.metrics.nees / nis against numpy, and the bands doing their job on
a Kalman filter written here in numpy (Bar-Shalom, Li & Kirubarajan 2001, §5.4): correctly specified,
its per-step NEES averaged over 1,000 runs lies inside the 95 % band in at least 90 % of the steps;
with its process noise inflated 10x it lies below the band (under-confident) in most steps; with it
shrunk 10x, above (over-confident). These tests can fail: a wrong band or a wrong NEES breaks them."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

from mcjax.analysis.statistics import CONSISTENCY, Interval, chi2_band, consistency
from mcjax.tracking import metrics

RUNS, STEPS, DT, Q, R = 1000, 60, 1.0, 0.5, 2.0


@pytest.mark.parametrize("dof, runs, confidence", [(1, 1, 0.95), (2, 50, 0.95), (4, 1000, 0.99), (6, 7, 0.9)])
def test_band_is_scipys_chi2_quantiles_over_runs(dof, runs, confidence):
    band = chi2_band(dof, runs, confidence)
    low, high = stats.chi2.interval(confidence, dof * runs)
    assert band == pytest.approx(Interval(low / runs, high / runs), rel=1e-12)
    assert band.low < dof < band.high


def test_band_refuses_nonsense_and_consistency_reads_it():
    with pytest.raises(ValueError, match="dof >= 1 and runs >= 1"):
        chi2_band(0, 10)
    band = chi2_band(2, 100)
    assert [consistency(x, band) for x in (2.0, band.high + 1e-9, band.low - 1e-9)] == list(CONSISTENCY)
    with pytest.raises(ValueError, match="finite"):
        consistency(float("nan"), band)


def test_nees_and_nis_are_numpys():
    rng = np.random.default_rng(1)
    e = rng.normal(size=(5, 4))
    A = rng.normal(size=(5, 4, 4))
    P = A @ A.transpose(0, 2, 1) + 4 * np.eye(4)
    truth = rng.normal(size=(5, 4))
    ref = np.einsum("bi,bij,bj->b", e, np.linalg.inv(P), e)
    np.testing.assert_allclose(np.asarray(metrics.nees(truth + e, np.linalg.inv(P), truth)), ref, rtol=1e-12)
    np.testing.assert_allclose(np.asarray(metrics.nis(e[:, :2], np.linalg.inv(P[:, :2, :2]))),
                               np.einsum("bi,bij,bj->b", e[:, :2], np.linalg.inv(P[:, :2, :2]), e[:, :2]),
                               rtol=1e-12)


def _kalman_runs(q_model: float, seed: int = 0):
    """RUNS runs of a 1-D constant-velocity target (white-acceleration q = Q) observed in position
    (noise R), filtered by a Kalman filter that assumes process noise ``q_model``: per run and
    step, the NEES of the state (2 dof) and the NIS of the innovation (1 dof)."""
    rng = np.random.default_rng(seed)
    F = np.array([[1.0, DT], [0.0, 1.0]])
    G = np.array([[DT**3 / 3, DT**2 / 2], [DT**2 / 2, DT]])  # continuous white-acceleration Q per unit q
    H = np.array([[1.0, 0.0]])
    chol = np.linalg.cholesky(Q * G)
    x = rng.normal(0.0, 1.0, (RUNS, 2)) * [10.0, 1.0]
    xh, P = np.zeros((RUNS, 2)), np.diag([100.0, 1.0])
    nees, nis = np.empty((RUNS, STEPS)), np.empty((RUNS, STEPS))
    for t in range(STEPS):
        x = x @ F.T + rng.normal(size=(RUNS, 2)) @ chol.T
        z = x[:, :1] + np.sqrt(R) * rng.normal(size=(RUNS, 1))
        xh, P = xh @ F.T, F @ P @ F.T + q_model * G
        S = H @ P @ H.T + R
        K = P @ H.T / S
        nu = z - xh @ H.T
        nis[:, t] = nu[:, 0] ** 2 / S[0, 0]
        xh, P = xh + nu @ K.T, (np.eye(2) - K @ H) @ P
        e = x - xh
        nees[:, t] = np.einsum("bi,ij,bj->b", e, np.linalg.inv(P), e)
    return nees, nis


def test_a_correct_kalman_filter_is_consistent_and_mistuned_ones_are_not():
    band, band_nis = chi2_band(2, RUNS), chi2_band(1, RUNS)
    nees, nis = _kalman_runs(Q)
    inside = np.mean([consistency(v, band) == "consistent" for v in nees.mean(0)])
    inside_nis = np.mean([consistency(v, band_nis) == "consistent" for v in nis.mean(0)])
    assert inside >= 0.9 and inside_nis >= 0.9, (inside, inside_nis)
    wide, _ = _kalman_runs(10 * Q)
    assert np.mean([consistency(v, band) == "under-confident" for v in wide.mean(0)]) > 0.5
    narrow, _ = _kalman_runs(Q / 10)
    assert np.mean([consistency(v, band) == "over-confident" for v in narrow.mean(0)]) > 0.5
