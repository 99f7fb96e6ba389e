"""Run keys: run r's key is ``fold_in(PRNGKey(base_seed), seed_index)`` — a seed index draws the
same noise at every sweep point (common random numbers) — computed in numpy without compiling
a JAX program (a copy of JAX's Threefry hash), and the key a run's ``init`` draws from."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np


def run_key(base_seed: int, seed_index) -> jax.Array:
    """The key of seed ``seed_index`` (the same at every sweep point)."""
    return jax.random.fold_in(jax.random.PRNGKey(base_seed), seed_index)


def _threefry2x32(k0, k1, x0, x1):
    """Threefry-2x32 with 20 rounds (Salmon, Moraes, Dror, Shaw 2011, "Parallel random numbers:
    as easy as 1, 2, 3", the Threefry-2x32 rotation constants and key schedule), on numpy
    uint32 arrays: the hash behind JAX's default PRNG."""
    rotations = ((13, 15, 26, 6), (17, 29, 16, 24))
    keys = (k0, k1, k0 ^ k1 ^ np.uint32(0x1BD11BDA))
    x0, x1 = x0 + keys[0], x1 + keys[1]
    for i in range(5):
        for r in rotations[i % 2]:
            x0 = x0 + x1
            x1 = ((x1 << np.uint32(r)) | (x1 >> np.uint32(32 - r))) ^ x0
        x0 = x0 + keys[(i + 1) % 3]
        x1 = x1 + keys[(i + 2) % 3] + np.uint32(i + 1)
    return x0, x1


def run_keys(base_seed: int, seed_index) -> np.ndarray:
    """:func:`run_key` of each seed index of the array ``seed_index``, as a numpy (n, 2) uint32
    array, computed in numpy: no JAX program is compiled for it (that took ~0.25 s of a
    sweep's start). JAX's default PRNG: ``PRNGKey(s)`` is the 32-bit words (high, low) of the
    64-bit ``s``, ``fold_in(key, d)`` is Threefry-2x32 keyed by ``key`` on the words (0, d).
    With another PRNG implementation configured in JAX, JAX computes them."""
    idx = np.asarray(seed_index)
    if jax.config.jax_default_prng_impl != "threefry2x32":
        return np.asarray(jax.vmap(lambda s: run_key(base_seed, s))(jnp.asarray(idx, jnp.uint32)))
    seed = int(np.int64(base_seed))  # JAX's range check: a 64-bit signed integer
    k0, k1 = np.uint32((seed >> 32) & 0xFFFFFFFF), np.uint32(seed & 0xFFFFFFFF)
    data = idx.astype(np.uint32).reshape(-1)
    with np.errstate(over="ignore"):
        y0, y1 = _threefry2x32(k0, k1, np.zeros_like(data), data)
    return np.stack([y0, y1], axis=-1).reshape(idx.shape + (2,))


#: Run ``key``'s draw for ``init``: ``fold_in(key, INIT_KEY)`` (step t draws ``fold_in(key, t)``).
INIT_KEY = 0x7FFFFFFF


def init_key(key) -> jax.Array:
    """The key a run's ``init`` draws from (:data:`INIT_KEY`)."""
    return jax.random.fold_in(key, INIT_KEY)
