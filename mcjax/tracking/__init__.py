"""The science, in pure JAX: numerical kernels, the comm graph (λ2, consensus weights) and its
connectivity robustness, error and consistency metrics, motion / platform / sensor models, the
planning solvers and the filters. Nothing here knows a paper: the scenarios put these together."""
