"""Lost links (mcjax.scenarios.kit.faults): the measured loss rate and burst length of the channel
against the Params, checked with the binomial (i.i.d.) and the Markov chain's own statistics."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.stats import binomtest

from mcjax.scenarios.kit import faults

N, STEPS = 6, 40_000


def _simulate(loss, burst, seed=0):
    """(STEPS, N, N) link states of one run."""
    key = jax.random.PRNGKey(seed)
    lost = faults.channel_init(faults.fault_key(jax.random.fold_in(key, STEPS)), N, loss)

    def step(lost, t):
        lost = faults.channel_step(faults.fault_key(jax.random.fold_in(key, t)), lost, loss, burst)
        return lost, lost

    return np.asarray(jax.jit(lambda: jax.lax.scan(step, lost, jnp.arange(STEPS))[1])())


def _links(states):
    i, j = np.triu_indices(N, 1)
    return states[:, i, j]  # (STEPS, links)


def _bursts(series):
    """Lengths of the runs of 1s of each column (bursts cut by the window's ends are dropped)."""
    lengths = []
    for col in series.T:
        edges = np.flatnonzero(np.diff(np.concatenate([[0], col, [0]])))
        starts, stops = edges[::2], edges[1::2]
        keep = (starts > 0) & (stops < len(col))
        lengths += list((stops - starts)[keep])
    return np.asarray(lengths)


def test_links_are_symmetric_and_a_zero_rate_loses_nothing():
    states = _simulate(0.3, 4.0)
    assert np.array_equal(states, np.swapaxes(states, 1, 2))
    assert not _simulate(0.0, 0.0).any() and not _simulate(0.0, 5.0).any()
    A = np.ones((N, N)) - np.eye(N)
    assert np.array_equal(np.asarray(faults.delivered(jnp.asarray(A), jnp.zeros((N, N)))), A)


@pytest.mark.parametrize("loss", [0.1, 0.5])
def test_independent_loss_rate_is_the_param(loss):
    links = _links(_simulate(loss, 0.0))
    k, n = int(links.sum()), links.size
    ci = binomtest(k, n).proportion_ci(confidence_level=0.999)
    assert ci.low <= loss <= ci.high, (k / n, ci)
    # independent in time: a loss tells nothing about the next step
    now, nxt = links[:-1].ravel(), links[1:].ravel()
    after_loss = binomtest(int(nxt[now == 1].sum()), int((now == 1).sum())).proportion_ci(confidence_level=0.999)
    assert after_loss.low <= loss <= after_loss.high


@pytest.mark.parametrize("loss, burst", [(0.2, 5.0), (0.3, 2.0)])
def test_gilbert_elliott_rate_and_mean_burst_are_the_params(loss, burst):
    links = _links(_simulate(loss, burst, seed=3))
    # the chain's autocorrelation ρ = p_bb − p_gb inflates the variance of the mean by (1 + ρ)/(1 − ρ)
    p_gb, p_bb = (float(x) for x in faults.channel_rates(loss, burst))
    rho = p_bb - p_gb
    se = np.sqrt(loss * (1 - loss) * (1 + rho) / (1 - rho) / links.size)
    assert abs(links.mean() - loss) < 5 * se, (links.mean(), loss, se)
    bursts = _bursts(links)
    # bursts are geometric with mean L: variance L (L − 1)
    se = np.sqrt(burst * (burst - 1) / len(bursts))
    assert abs(bursts.mean() - burst) < 5 * se + 1e-12, (bursts.mean(), burst, se, len(bursts))


def test_fault_draws_use_their_own_key_stream():
    key = jax.random.PRNGKey(7)
    assert not np.array_equal(np.asarray(faults.fault_key(key)), np.asarray(key))
    # the draws a scenario makes from its step key are the same whether or not faults are drawn
    a = jax.random.normal(key, (3,))
    faults.channel_step(faults.fault_key(key), jnp.zeros((N, N)), 0.3, 0.0)
    assert np.array_equal(np.asarray(a), np.asarray(jax.random.normal(key, (3,))))


def test_burst_lengths_that_do_not_fit_the_rate_are_named():
    assert faults.burst_problem(0.2, 0.0) is None and faults.burst_problem(0.2, 1.0) is None
    assert faults.burst_problem(0.8, 4.0) is None
    assert "0 or >= 4 steps" in faults.burst_problem(0.8, 2.0)
    assert "0 or >= 1 steps" in faults.burst_problem(0.1, 0.5)
