"""Sensitivity maps (a sweep's ``[sensitivity]``, mcjax.study.sensitivity): each column is the
derivative of an output of the smooth system with respect to a Param, checked against central
differences of that system (the same keys); the exact outputs are those of a sweep without
the table; bad input is one line, exit 2, nothing written."""

from __future__ import annotations

import functools
import textwrap
from pathlib import Path

import jax
import numpy as np
import pandas as pd
import pytest
from click.testing import CliRunner

from mcjax import engine
from mcjax.cli import main
from mcjax.contract.relaxation import column
from mcjax.study import load_spec, run_sweep

ROOT = Path(__file__).resolve().parents[2]

SUN = f"""
base = "{(ROOT / 'configs' / 'sun2011.toml').as_posix()}"
seeds = 2
[config]
n_steps = 8
warmup_steps = 2
planner = "none"
filters = ["modified_icf", "icf"]
[grid]
comm_radius = [60e3, 90e3]
"""
SENSITIVITY = """
[sensitivity]
params = ["comm_radius", "sigma_range"]
outputs = ["rmse", "anees"]
"""


def _spec(tmp_path, text, name="s.toml"):
    p = tmp_path / name
    p.write_text(textwrap.dedent(text))
    return p


@functools.cache
def _smooth_program(study):
    sm = study.sensitivity.temperatures
    # compiled with XLA's newer CPU emitters, named (the suite's flags pick the older ones, which
    # the engine's own program uses): the reference is a program of its own, as a user's jit is
    return jax.jit(lambda q, k: engine.simulate(study.scenario, study.config, q, k, temperatures=sm),
                   compiler_options={"xla_cpu_use_fusion_emitters": True})


def _central(study, name, outputs, h):
    """Fourth-order central differences of each of ``outputs`` of the smooth system (the same
    keys), every run of the study: (8 (f(x+h) - f(x-h)) - (f(x+2h) - f(x-2h))) / 12h; the four
    shifted runs serve every output."""
    params, keys = engine.chunk_inputs(study.params, study.seeds, study.base_seed, 0, study.n_runs, study.n_runs)
    run = _smooth_program(study)
    f = {s: run(params._replace(**{name: getattr(params, name) + s * h}), keys) for s in (1, -1, 2, -2)}
    return {o: (8 * (np.asarray(f[1][o]) - np.asarray(f[-1][o])) - (np.asarray(f[2][o]) - np.asarray(f[-2][o])))
            / (12 * h) for o in outputs}


def test_columns_match_central_differences_and_exact_outputs_are_unchanged(tmp_path):
    out = tmp_path / "out"
    r = CliRunner().invoke(main, ["sweep", str(_spec(tmp_path, SUN + SENSITIVITY)), "--out", str(out)])
    assert r.exit_code == 0, r.output
    study = load_spec(tmp_path / "s.toml")
    rows = pd.read_parquet(out / "runs").sort_values(["point_id", "seed_index", "filter"]).reset_index(drop=True)
    rows["point_id"] = rows["point_id"].astype(np.int64)
    filters = list(study.config.filters)
    # steps (a scan of h over two decades, fourth-order stencil): the quotient is flat to ~1e-5
    # there; the outputs carry ~1e-10 of round-off through the consensus iterations, which sets
    # the floor of the quotient: a derivative below 1 % of its column's largest is compared to
    # 1e-4 of that 1 % (the 90 km point, where the comm radius hardly acts); and the stencil's own
    # round-off, ~1e-10 of the output times (8 + 8 + 1 + 1) / 12h, whatever the CPU's vector code (on
    # an AVX2 machine d anees / d comm_radius moved by 4e-11 where it is 3e-8)
    for name, h in (("comm_radius", 20.0), ("sigma_range", 1e-2)):
        cds = _central(study, name, ("rmse", "anees"), h)
        for output in ("rmse", "anees"):
            cd = cds[output]  # (runs, F)
            for f, filt in enumerate(filters):
                mine = rows[rows["filter"] == filt].sort_values(["point_id", "seed_index"])
                got, want = mine[column(output, name)].to_numpy(), cd[:, f]
                scale = np.maximum(np.abs(want), 1e-2 * np.max(np.abs(want)))
                roundoff = 1e-10 * np.abs(mine[output].to_numpy()) * 18 / (12 * h)
                assert np.all(np.abs(got - want) <= 1e-4 * scale + roundoff), (name, output, filt, got, want)
    # the comm radius acts where links break (60 km) and hardly at 90 km: the columns are not constant
    d = rows.groupby("point_id")["d_rmse_d_comm_radius"].apply(lambda s: np.abs(s).mean())
    assert d[0] > 10 * d[1]
    plain = run_sweep(load_spec(_spec(tmp_path, SUN, "plain.toml")))
    def same(a, b):
        if a.dtype.kind in "fc":
            return np.array_equal(a.to_numpy(), b.to_numpy(), equal_nan=True)
        return list(a.astype(str)) == list(b.astype(str))

    bad = [c for c in plain.columns if not same(rows[c], plain[c])]
    assert not bad, (bad, rows[bad], plain[bad])
    # the report draws the derivatives under the error curve, the exact slope beside d rmse / d comm_radius
    r = CliRunner().invoke(main, ["report", str(out)])
    assert r.exit_code == 0, r.output
    assert (out / "report" / "sensitivity_rmse_vs_comm_radius.png").stat().st_size > 10_000
    page = (out / "report" / "index.html").read_text()
    assert "sensitivity_rmse_vs_comm_radius.png" in page


@pytest.mark.parametrize("table, message", [
    ('params = ["horizon"]', "sensitivity.params: horizon is not continuous"),
    ('params = ["n_agents"]', "sensitivity.params: n_agents is a Config field"),
    ('params = ["link_loss"]', "sensitivity.params: link_loss has no smooth path"),
    ('params = ["comm_radiuss"]', "sensitivity.params: unknown Param of leader_follower"),
    ('params = ["initial_positions"]', "sensitivity.params: initial_positions is an array here"),
    ('params = []', "sensitivity.params: must be a non-empty list"),
    ('outputs = ["rmse"]', "sensitivity.params: missing"),
    ('params = ["comm_radius"]\noutputs = ["rmsee"]', "sensitivity.outputs: 'rmsee' is not an output"),
    ('params = ["comm_radius"]\nfoo = 1', "sensitivity.foo: unknown key"),
    ('params = ["comm_radius"]\n[sensitivity.smoothing]\ncomm = -1.0', "sensitivity.smoothing.comm: must be a number > 0"),
    ('params = ["comm_radius"]\n[sensitivity.smoothing]\nhot = 1.0', "sensitivity.smoothing.hot: unknown key"),
    ('params = ["comm_radius"]\n[sensitivity.relaxation]\nhot = 1.0', "sensitivity.relaxation.hot: unknown key"),
    ('params = ["comm_radius"]\n[sensitivity.relaxation]\ncomm = 1.0\n[sensitivity.smoothing]\ncomm = 1.0',
     "sensitivity.smoothing: the former name of sensitivity.relaxation"),
])
def test_bad_sensitivity_table_is_one_line_exit_2_nothing_written(tmp_path, table, message):
    spec = _spec(tmp_path, SUN + "[sensitivity]\n" + table + "\n")
    out = tmp_path / "out"
    r = CliRunner().invoke(main, ["sweep", str(spec), "--out", str(out)])
    assert r.exit_code == 2, r.output
    err = r.stderr.strip() if hasattr(r, "stderr") else r.output.strip()
    assert len(err.splitlines()) == 1 and message in err, err
    assert not out.exists()
