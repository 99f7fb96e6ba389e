"""The tests' probe scenario: one agent tracking a 1-D random walk with one Kalman filter, and a
host callback the tests steer through flag files in this file's folder (the tests copy it into a
temporary folder and name it as ``scenario = "probe.py:SCENARIO"``, so it also travels to Dask
workers by value):

* ``slow``: every chunk waits while the file exists;
* ``pace``: every chunk takes half a second more while the file exists;
* ``armed``: the next chunk claims it (renamed ``busy-<pid>``) and waits to be killed;
* the point r = 13.0 raises (a bad point).
"""
import os
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from mcjax.contract import Param, Scenario, config_type, declare, params_type
from mcjax.scenarios.kit import check_common, common_settings, error_items

FLAGS = Path(__file__).parent
BAD = 13.0

Config = config_type("Config", common_settings(filter_kinds=("kf",), n_agents=1, n_steps=10, warmup_steps=2,
                                               divergence_threshold=100.0), __name__, check_common)
Params = params_type("Params", dict(q=Param(1.0, "m", "walk std", low=0),
                                    r=Param(1.0, "m", "noise std", low=0, low_open=True)), __name__)


def _host(r):
    r = np.asarray(r)
    if (r == BAD).any():
        time.sleep(1.0)  # the good chunks finish first
        raise ValueError(f"bad point: r = {BAD}")
    try:
        os.rename(FLAGS / "armed", FLAGS / f"busy-{os.getpid()}")  # one chunk claims it
        time.sleep(60)  # ... and is killed here
    except FileNotFoundError:
        pass
    while (FLAGS / "slow").exists():
        time.sleep(0.05)
    if (FLAGS / "pace").exists():
        time.sleep(0.5)
    return r


def init(cfg, p, key):
    r = jax.pure_callback(_host, jax.ShapeDtypeStruct(jnp.shape(p.r), jnp.result_type(p.r)), p.r,
                          vmap_method="expand_dims")
    return (jnp.zeros(()), jnp.zeros(()), jnp.ones(()), r)


def step(cfg, p, s, key):
    t, x, P, r = s
    k1, k2 = jax.random.split(key)
    t = t + p.q * jax.random.normal(k1)
    z = t + r * jax.random.normal(k2)
    P = P + p.q**2
    K = P / (P + r**2)
    x, P = x + K * (z - x), (1 - K) * P
    return (t, x, P, r), jnp.abs(x - t).reshape(1, 1)


def summary(cfg, e, p):
    """The kit's error summary of the one agent's error, declared next to its values."""
    return declare(**error_items(lambda: e, lambda: jnp.ones(1), cfg, "m"))


SCENARIO = Scenario(name="probe", title="one agent, steerable by flag files", Config=Config, Params=Params,
                    init=init, step=step, summary=summary)
