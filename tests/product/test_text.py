"""Text a user reads says what it means: no code identifiers in the scenarios' descriptions or
in a dataset's metadata, and a report's Spec block is the spec that ran.

A rename once leaked into user-facing strings ("mean full-state NEES over alive kit.agents",
"mean number of kit.agents that see the target", in `mcjax list` and in every Parquet file's
metadata); a sweep run with ``--seeds 50`` recorded ``seeds = 100`` in its spec."""

from __future__ import annotations

import dataclasses
import json
import re
from pathlib import Path

import pytest

from mcjax import scenarios
from mcjax.cli.listing import scenario_text
from mcjax.study import load_spec, part_metadata, read_config_file

ROOT = Path(__file__).resolve().parents[2]

#: ``name.attribute`` of the code's own names: the scenario kit, a Config or Params object, numpy, JAX.
CODE = re.compile(r"\b(kit|cfg|params|Params|config|Config|np|jnp|jax|lax|self|state|records?|sc|temperatures)\.[A-Za-z_]")


def test_the_pattern_finds_the_leak_it_is_for():
    assert CODE.search("mean full-state NEES over alive kit.agents and steps after warm-up")
    assert CODE.search("mean number of kit.agents that see the target") and CODE.search("cfg.n_agents UAVs")
    assert CODE.search("Params.horizon (t_r) <= this")
    assert not CODE.search("position error (m), e.g. 1.5 m; the param horizon (t_r) <= this; Sun et al. 2011")


def _configs(sc):
    """The scenario's default Config, every built-in config file's, and each with faults on."""
    out = [sc.Config()]
    for path in sorted((ROOT / "configs").glob("*.toml")):
        f = read_config_file(path)
        if f.scenario.name == sc.name:
            out.append(f.config)
    if "faults" in sc.settings:
        out += [dataclasses.replace(c, faults="on") for c in list(out)]
    return out


def _texts(sc, cfg) -> list[tuple[str, str]]:
    texts = [("title", sc.title)]
    texts += [(f"params.{k}", f"{p.unit} {p.description}") for k, p in sc.params_table.items()]
    texts += [(f"config.{k}", f"{s.unit} {s.description}") for k, s in sc.settings.items()]
    texts += [(f"output {k}", f"{o.unit} {o.description}") for k, o in sc.outputs(cfg).items()]
    if sc.timeseries_outputs is not None:
        texts += [(f"series {k}", f"{o.unit} {o.description}") for k, o in sc.timeseries_outputs(cfg).items()]
    texts.append(("Parquet metadata", json.dumps(sc.metadata(cfg), ensure_ascii=False)))
    texts.append(("mcjax list", scenario_text(sc)))
    return texts


@pytest.mark.parametrize("name", scenarios.known())
def test_user_facing_strings_hold_no_code_identifiers(name):
    sc = scenarios.get(name)
    bad = []
    for cfg in _configs(sc):
        for where, text in _texts(sc, cfg):
            for m in CODE.finditer(text):
                bad.append(f"{where}: ...{text[max(0, m.start() - 40):m.end() + 20]}...")
    assert not bad, "\n".join(sorted(set(bad)))


def test_the_spec_recorded_is_the_one_that_ran(tmp_path):
    """A dataset's spec (the report's Spec block) has --seeds and --chunk-size merged into it as
    --set values are, and the seeds a spec takes from its base config; what --resume compares
    (the spec as written, with seeds and chunk size beside it) does not change with them."""
    spec = ROOT / "sweeps" / "default.toml"
    written = load_spec(spec)
    ran = load_spec(spec, seeds=7, chunk_size=3, overrides={"params.sigma_range": 12.0})
    meta = part_metadata(ran, ran.chunk_runs)
    assert meta["spec"]["seeds"] == 7 == ran.seeds == meta["seeds"]
    assert meta["spec"]["chunk_size"] == 3 and meta["spec"]["params"]["sigma_range"] == 12.0
    assert part_metadata(written, written.chunk_runs)["spec"]["seeds"] == written.seeds == 100
    again = load_spec(spec, seeds=written.seeds, chunk_size=written.chunk_size)  # --resume passes the saved ones
    assert again.source == written.source and ran.source["params"] == {**written.source.get("params", {}),
                                                                       "sigma_range": 12.0}


def _readme_rows() -> dict:
    """{(comm radius in km, filter): (rmse_mean, div_rate)} of the README's printed summary."""
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    block = text.split("## What you should see", 1)[1].split("```text", 1)[1].split("```", 1)[0]
    lines = block.splitlines()
    header = next(line.split() for line in lines if line.split()[:2] == ["comm_radius", "filter"])
    rows = {}
    for line in lines:
        cells = line.split()
        if len(cells) == len(header) and cells[0].isdigit() and cells[2].isdigit():  # radius, filter, n, ...
            rows[(int(cells[0]) / 1000, cells[1])] = (float(cells[header.index("rmse_mean")]),
                                                       float(cells[header.index("div_rate")]))
    return rows


def test_papers_default_sweep_table_is_what_the_readme_prints():
    """docs/papers.md's "The default sweep" table and the README's printed summary are the same
    sweep's numbers wherever both give one (a re-run that updates one and not the other fails)."""
    text = (ROOT / "docs" / "papers.md").read_text(encoding="utf-8")
    section = text.split("### The default sweep", 1)[1].split("\n### ", 1)[0]
    table = [[c.strip() for c in line.strip("|").split("|")] for line in section.splitlines() if line.startswith("|")]
    radii = [float(c) for c in table[0][1:]]
    names = {"ICF": "icf", "modified ICF": "modified_icf", "CIF": "cif"}
    papers = {(r, names[row[0]]): tuple(float(x) for x in cell.split(" / "))
              for row in table[2:] for r, cell in zip(radii, row[1:])}
    readme = _readme_rows()
    assert len(readme) >= 4 and set(readme) <= set(papers), (sorted(readme), sorted(papers))
    for key, value in readme.items():
        assert papers[key] == value, (key, papers[key], value)


def test_the_suites_time_is_stated_in_one_place():
    """pyproject.toml once stated a test time the suite had long outgrown: the measured time lives
    in the README alone, so pyproject.toml's comments give no duration of their own."""
    pytest_part = (ROOT / "pyproject.toml").read_text(encoding="utf-8").split("[tool.pytest.ini_options]", 1)[1]
    comments = [line for line in pytest_part.split("\n[", 1)[0].splitlines() if line.lstrip().startswith("#")]
    assert comments  # the section explains its options
    durations = [c for c in comments if re.search(r"\d\s*(min|minutes|s)\b", c)]
    assert not durations, durations
    assert re.search(r"\(`python -m pytest`, [\d,]+ tests\) took \d+ min", (ROOT / "README.md").read_text())
