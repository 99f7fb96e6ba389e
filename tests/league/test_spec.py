"""A league file checked whole before anything runs: one line naming the key path, exit 2."""

import pytest
from click.testing import CliRunner

from mcjax.cli import main
from mcjax.league.spec import LeagueError, load_league

from .conftest import ROOT, TINY


def test_a_league_file_reads_into_one_sweep_per_scenario_and_point(league_file):
    league = load_league(league_file())
    assert league.filters == ("kcf", "local") and league.seeds == 8 and league.timing_runs == 0
    assert list(league.studies) == [("wind", "none"), ("wind", "iid")]
    study = league.studies["wind", "iid"]
    assert study.config.filters == ("kcf", "local") and study.config.n_steps == 10
    assert float(study.base_params.link_loss) == 0.3 and study.seeds == 8
    assert league.points == {"none": "no faults", "iid": "i.i.d. link loss 0.3"}
    assert load_league(league_file(), seeds=3).studies["wind", "none"].seeds == 3


@pytest.mark.parametrize("edit, message", [
    (lambda t: t.replace('title =', 'colour = "red"\ntitle ='), "tiny.toml: colour: unknown key"),
    (lambda t: t.replace('"kcf", "local"]', '"kcf", "locl"]'), "tiny.toml: filters[1]: filter must be one of"),
    (lambda t: t.replace('"kcf", "local"]', '"kcf", "diffusion_kf_missing"]'), "diffusion_kf_missing"),
    (lambda t: t.replace('"kcf", "local"]', '"kcf", "kcf"]'), "tiny.toml: filters: must not name a filter twice"),
    (lambda t: t.replace("[points.iid]", "[points.iid]\nspeed = 3"), "tiny.toml: points.iid.speed: unknown key"),
    (lambda t: t.replace("params = { link_loss = 0.3 }", "params = { link_los = 0.3 }"),
     "tiny.toml: scenarios.wind at points.iid: params.link_los: unknown key"),
    (lambda t: t.replace("seeds = 8", "seeds = 0"), "tiny.toml: seeds: must be an integer"),
    (lambda t: t.replace("[scenarios.wind]\n", "[scenarios.wind]\nfilters = ['cif']\n"),
     "scenarios.wind.filters[0]: must be one of the league's filters"),
])
def test_bad_input_is_one_line_naming_the_key(league_file, edit, message):
    with pytest.raises(LeagueError) as info:
        load_league(league_file(edit(TINY)))
    assert message in str(info.value) and "\n" not in str(info.value)


FLOCK = f"""
[scenarios.flock]
base = "{ROOT / 'configs' / 'lou2013.toml'}"
config = {{ n_steps = 10, warmup_steps = 2, faults = "on" }}
"""


def test_a_filter_a_scenario_cannot_run_is_refused_when_asked_and_explained_when_not(league_file):
    text = TINY.replace('"kcf", "local"]', '"kcf", "local", "cif"]')
    with pytest.raises(LeagueError) as info:  # the flock cannot run the CIF, and the league asks it to
        load_league(league_file(text + FLOCK))
    assert "scenarios.flock at points.none: config.filters:" in str(info.value) and "'cif'" in str(info.value)
    league = load_league(league_file(text + FLOCK.replace("[scenarios.flock]\n",
                                                          "[scenarios.flock]\nfilters = ['kcf', 'local']\n")))
    assert league.scenarios["flock"].filters == ("kcf", "local")
    assert league.scenarios["flock"].notes["cif"] == ("cannot run here: flocking offers no 'cif' (its filters: kcf, "
                                                      "local, ci, hcmci; or a filter of one's own)")
    left = load_league(league_file(TINY.replace("[scenarios.wind]\n", "[scenarios.wind]\nfilters = ['kcf']\n")))
    assert left.scenarios["wind"].notes == {"local": "left out by the league file"}


def test_the_command_exits_2_with_one_line_before_anything_runs(league_file, tmp_path):
    out = tmp_path / "out"
    result = CliRunner().invoke(main, ["league", str(league_file(TINY.replace('"local"]', '"nope"]'))),
                                       "--out", str(out)])
    assert result.exit_code == 2, result.output
    lines = [line for line in result.output.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: tiny.toml: filters[1]:")
    assert not out.exists()


def test_the_project_league_names_the_missing_plugin_in_one_line_or_reads():
    from mcjax.tracking.filters import registry

    path = ROOT / "benchmarks" / "league" / "consensus.toml"
    if "diffusion_kf" in registry.known():
        league = load_league(path, seeds=1)
        assert league.seeds == 1 and len(league.points) == 4 and len(league.scenarios) == 3
        assert all(e.notes for e in league.scenarios.values())
    else:
        with pytest.raises(LeagueError, match=r"consensus.toml: filters\[\d+\]: .*'diffusion_kf'"):
            load_league(path)
