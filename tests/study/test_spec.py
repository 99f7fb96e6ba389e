"""Stage 1, the spec (mcjax.study.spec): a sweep spec file or table read into a validated Study —
its base config relative to the spec's folder, the command line's overrides, the axes as
written — and a bad key stopped with a SpecError naming its path."""

from __future__ import annotations

import tomllib
from pathlib import Path

import pytest

from mcjax.study import SpecError, build_spec, is_config_file, is_sweep_spec, load_spec

ROOT = Path(__file__).resolve().parents[2]


def test_a_spec_file_reads_its_base_relative_to_its_folder(tmp_path):
    (tmp_path / "cfg").mkdir()
    (tmp_path / "cfg" / "base.toml").write_bytes((ROOT / "configs" / "chen2013.toml").read_bytes())
    spec = tmp_path / "spec.toml"
    spec.write_text('base = "cfg/base.toml"\nseeds = 4\n[config]\nn_steps = 3\n[grid]\neta = [0.0, 0.01]\n'
                    '[zip]\nnoise_scale = [1.0, 2.0]\n')
    s = load_spec(spec, out_dir=tmp_path / "out")
    assert s.scenario.name == "wind_formation" and s.config.n_steps == 3 and s.out_dir == tmp_path / "out"
    assert s.axes == ["eta", "noise_scale"] and s.n_points == 4 and s.seeds == 4 and s.n_runs == 16
    assert s.source["base"] == "cfg/base.toml"  # the spec as written
    assert load_spec(spec, seeds=7, overrides={"config.n_steps": 5}).seeds == 7


def test_overrides_change_the_spec_and_are_kept_for_resume():
    s = build_spec({"base": str(ROOT / "configs" / "sun2011.toml")}, ROOT, seeds=2,
                   overrides={"params.comm_radius": 90e3, "grid.horizon": [4, 5]})
    assert float(s.base_params.comm_radius) == 90e3 and s.axes == ["horizon"] and s.n_points == 2
    assert s.overrides == {"params.comm_radius": 90e3, "grid.horizon": [4, 5]}


@pytest.mark.parametrize("table, where", [
    ({"config": {"n_stepz": 3}}, "n_stepz"),
    ({"grid": {"comm_radius": []}}, "grid.comm_radius"),
    ({"seeds": 0}, "seeds"),
])
def test_a_bad_key_is_one_spec_error_naming_its_path(table, where):
    with pytest.raises(SpecError) as caught:
        build_spec({"base": str(ROOT / "configs" / "sun2011.toml"), **table}, ROOT)
    message = str(caught.value)
    assert where in message and "\n" not in message


def test_a_spec_is_told_from_a_config_file():
    spec = tomllib.loads((ROOT / "sweeps" / "default.toml").read_text())
    config = tomllib.loads((ROOT / "configs" / "sun2011.toml").read_text())
    assert is_sweep_spec(spec) and not is_config_file(spec)
    assert is_config_file(config) and not is_sweep_spec(config)


def test_a_filter_file_is_read_beside_the_file_that_names_it_and_the_command_lines_here(tmp_path, monkeypatch):
    """A relative ``"file.py:ATTRIBUTE"`` in a config's or a spec's ``filters`` is the file beside that config or
    spec (as a scenario file is), whatever the current folder; on the command line (``--set``), the current
    folder's. Each becomes an absolute reference, so a worker in another folder finds the same file."""
    from mcjax.tracking.filters import registry

    record = ("from mcjax.contract.filter import Filter, Traits\nfrom mcjax.tracking.filters.consensus import KCF\n"
              "MINE = Filter('{name}', 'a copy', 'ours', KCF.step, KCF.traits)\n")
    base = ROOT / "configs" / "chen2013.toml"
    for folder in ("configs", "specs", "here"):
        (tmp_path / folder).mkdir()
        (tmp_path / folder / "mine.py").write_text(record.format(name=f"mine_{folder}"))
    (tmp_path / "configs" / "c.toml").write_text(
        base.read_text(encoding="utf-8").replace('filters = ["kcf", "local", "cif"]', 'filters = ["kcf", "mine.py:MINE"]'))
    (tmp_path / "specs" / "s.toml").write_text('base = "../configs/c.toml"\nseeds = 2\n')
    (tmp_path / "specs" / "t.toml").write_text('base = "../configs/c.toml"\nseeds = 2\n[config]\nfilters = ["mine.py:MINE"]\n')
    monkeypatch.chdir(tmp_path / "here")
    in_config = load_spec(tmp_path / "specs" / "s.toml").config.filters
    in_spec = load_spec(tmp_path / "specs" / "t.toml").config.filters
    on_line = load_spec(tmp_path / "specs" / "t.toml", overrides={"config.filters": ["kcf", "mine.py:MINE"]}).config.filters
    for filters, folder in ((in_config, "configs"), (in_spec, "specs"), (on_line, "here")):
        ref = filters[-1]
        assert ref == f"{(tmp_path / folder / 'mine.py').resolve()}:MINE", filters
        assert registry.get(ref).name == f"mine_{folder}"
    assert in_config[0] == on_line[0] == "kcf"  # a name stays a name
