"""Tune and sensitivity with a filter of one's own (the filter contract): a file's record that runs the built-in
KCF's step under another name is tuned and differentiated exactly as the built-in is — its sensitivity columns
and its gradient of the tuning loss are the built-in's — on Chen & Lu 2013's wind formation (a small program)."""

from __future__ import annotations

import textwrap
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from mcjax import tune
from mcjax.study import load_spec, run_sweep

ROOT = Path(__file__).resolve().parents[2]

COPY = """
from mcjax.contract.filter import Filter
from mcjax.tracking.filters.consensus import KCF

MY_KCF = Filter("my_kcf", "the KCF's step under another name", "ours", KCF.step, KCF.traits)
"""


@pytest.fixture(scope="module")
def folder(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("plugin_filter")
    (out / "my_kcf.py").write_text(COPY)
    return out


def _base(folder: Path, head: str = "") -> str:
    return head + textwrap.dedent(f"""
        base = "{(ROOT / 'configs' / 'chen2013.toml').as_posix()}"
        [config]
        n_steps = 6
        filters = ["kcf", "{(folder / 'my_kcf.py').as_posix()}:MY_KCF"]
        [params]
        comm_radius = 3500.0
        """)


def test_its_sensitivity_columns_are_the_built_ins(folder):
    spec = folder / "sens.toml"
    spec.write_text(_base(folder, "seeds = 2\n") + '[sensitivity]\nparams = ["noise_scale", "comm_radius"]\noutputs = ["rmse"]\n')
    rows = run_sweep(load_spec(spec))
    # the datasets show the file's record by its name (issue 67, item 3)
    kcf, mine = (rows[rows["filter"].astype(str) == f].sort_values("seed_index") for f in ("kcf", "my_kcf"))
    assert len(kcf) == len(mine) == 2
    for column in ("rmse", "d_rmse_d_noise_scale", "d_rmse_d_comm_radius"):
        a, b = kcf[column].to_numpy(), mine[column].to_numpy()
        assert np.all(np.isfinite(a)) and np.any(a != 0), column
        # two copies of one step in one program: fused alike or not by XLA (rounding, not bits)
        np.testing.assert_allclose(b, a, rtol=1e-9, atol=1e-12 * np.abs(a).max(), err_msg=column)


def test_its_tuning_gradient_is_the_built_ins(folder):
    grads = []
    for loss_filter in ("kcf", f"{(folder / 'my_kcf.py').as_posix()}:MY_KCF"):
        spec = folder / "tune.toml"
        spec.write_text(_base(folder) + textwrap.dedent(f"""
            [tune]
            steps = 1
            train_seeds = 2
            heldout_seeds = 2
            [tune.params.sigma_wind_process]
            low = 0.05
            high = 5.0
            scale = "log"
            [tune.params.eta]
            low = 0.0
            high = 0.05
            [tune.loss]
            filter = "{loss_filter}"
            """))
        ts = tune.load_tune_spec(spec)
        ev = tune.Evaluator(ts)(tune.to_unconstrained(ts.bounds, ts.initial()))
        assert ev.dropped == 0 and np.all(np.isfinite(ev.grad)) and np.all(ev.grad != 0)
        grads.append((ev.loss, ev.grad))
    (loss_kcf, grad_kcf), (loss_mine, grad_mine) = grads
    np.testing.assert_allclose(loss_mine, loss_kcf, rtol=1e-9)
    np.testing.assert_allclose(grad_mine, grad_kcf, rtol=1e-7)
