"""Independent peers of mcjax's filters, written from the papers' equations without JAX: the
references the tests compare mcjax with and the peers the speed benchmarks time it against.

* :mod:`benchmarks.peers.numpy_peer` -- plain numpy, one Monte-Carlo run at a time (every consensus
  filter of Sun et al. 2011 and the KCF).
* :mod:`benchmarks.peers.numba_peer` -- numba ``prange`` loops over runs (the local EKF and the modified
  ICF); needs numba (``pip install -e ".[bench]"``).

Neither is imported by the engine: they exist to be compared with it.
"""
