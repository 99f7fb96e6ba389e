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
        for e in league.scenarios.values():  # a note says why for every league filter a scenario does not run
            assert set(e.notes) == set(league.filters) - set(e.filters), e.key
        assert league.scenarios["leader_follower"].filters == league.filters  # Sun et al. 2011 runs them all
        assert league.scenarios["flocking"].notes and league.scenarios["wind_formation"].notes
    else:
        with pytest.raises(LeagueError, match=r"consensus.toml: filters\[\d+\]: filter 'diffusion_kf' is a plugin "
                                              r"that is not installed: pip install -e \S*plugins/diffusion_kf$"):
            load_league(path)


def _plugin_folder(root, name="my_plugin_kf"):
    folder = root / "plugins" / name
    folder.mkdir(parents=True)
    (folder / "pyproject.toml").write_text(f'[project]\nname = "{name}"\n', encoding="utf-8")
    return folder


def test_an_uninstalled_plugin_the_file_says_where_to_find_is_named_with_its_install_command(league_file, tmp_path,
                                                                                            monkeypatch):
    """The one line names the filter and the pip command, its folder as typed from the current folder
    (here: the league file's folder, and one above it)."""
    _plugin_folder(tmp_path)
    text = TINY.replace('"kcf", "local"]', '"kcf", "local", "my_plugin_kf"]\nplugins = { my_plugin_kf = '
                                           '"plugins/my_plugin_kf" }')
    path = league_file(text)
    monkeypatch.chdir(tmp_path)
    with pytest.raises(LeagueError) as info:
        load_league(path)
    assert str(info.value) == ("tiny.toml: filters[2]: filter 'my_plugin_kf' is a plugin that is not installed: "
                               "pip install -e plugins/my_plugin_kf")
    (tmp_path / "below").mkdir()
    monkeypatch.chdir(tmp_path / "below")
    out = tmp_path / "out"
    result = CliRunner().invoke(main, ["league", str(path), "--out", str(out)])
    assert result.exit_code == 2, result.output
    lines = [line for line in result.output.splitlines() if line.strip()]
    assert lines == ["error: tiny.toml: filters[2]: filter 'my_plugin_kf' is a plugin that is not installed: "
                     "pip install -e ../plugins/my_plugin_kf"]
    assert not out.exists()


@pytest.mark.parametrize("plugins, message", [
    ('plugins = "plugins/my_plugin_kf"', "tiny.toml: plugins: must be a table of filter name = the plugin's folder"),
    ('plugins = { kcf = "plugins/my_plugin_kf" }', "tiny.toml: plugins.kcf: 'kcf' is a built-in filter, not a plugin"),
    ('plugins = { other_kf = "plugins/my_plugin_kf" }', "tiny.toml: plugins.other_kf: names no filter of the league"),
    ('plugins = { my_plugin_kf = 3 }', "tiny.toml: plugins.my_plugin_kf: must be the plugin's folder"),
    ('plugins = { my_plugin_kf = "plugins/nowhere" }',
     "tiny.toml: plugins.my_plugin_kf: 'plugins/nowhere' is not a plugin's folder"),
])
def test_a_bad_plugins_table_is_one_line_naming_the_key(league_file, tmp_path, plugins, message):
    _plugin_folder(tmp_path)
    with pytest.raises(LeagueError) as info:
        load_league(league_file(TINY.replace('"kcf", "local"]', f'"kcf", "local", "my_plugin_kf"]\n{plugins}')))
    assert str(info.value).startswith(message) and "\n" not in str(info.value)


def test_the_project_league_says_where_its_plugin_comes_from():
    import tomllib

    path = ROOT / "benchmarks" / "league" / "consensus.toml"
    plugins = tomllib.loads(path.read_text(encoding="utf-8"))["plugins"]
    assert (path.parent / plugins["diffusion_kf"] / "pyproject.toml").is_file()


@pytest.mark.parametrize("name, folder", [("tiny.toml", "league_tiny"), ("league_tiny.toml", "league_tiny"),
                                          ("league.toml", "league"), ("my league.toml", "league_my_league")])
def test_the_default_folder_does_not_double_league(name, folder):
    from mcjax.league.runner import default_out_dir
    from mcjax.study.store import RESULTS_DIR

    assert default_out_dir(f"somewhere/{name}") == RESULTS_DIR / folder
