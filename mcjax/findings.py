"""The report's "What this shows": sentences about a sweep generated from its data, each
backed by the intervals it quotes; a glossary from the dataset's declarations; the base
Params table. This module imports neither JAX nor matplotlib."""
