"""An installed plugin whose entry point takes a built-in filter's name is never resolved (the name stays the
built-in's) and never silent: every command that runs filters refuses to start in one line, exit 2, and
``mcjax list filters`` names it."""

import pytest
from click.testing import CliRunner

from mcjax.tracking.filters import registry
from tests.tracking.filters import fake_plugins


@pytest.fixture
def clashing_plugin(monkeypatch):
    fake_plugins.install(monkeypatch, "local", "their_pkg:THEIR_LOCAL")


def test_a_plugin_named_like_a_built_in_is_never_resolved_and_is_named_in_one_line(clashing_plugin):
    assert registry.get("local") is registry.BUILTIN["local"]  # a built-in name is always the built-in
    assert registry.known().count("local") == 1
    (clash,) = registry.clashes()
    assert clash == ("filter 'local': the installed plugin their_pkg:THEIR_LOCAL declares the name of a built-in "
                     "filter (entry-point group mcjax.filters); rename its entry point or uninstall it")


def test_a_run_naming_the_clashing_filter_ends_in_one_line_and_exit_2_and_the_list_says_why(clashing_plugin):
    from mcjax.cli import main

    r = CliRunner().invoke(main, ["run", "configs/chen2013.toml", "--seeds", "2", "--set", "config.n_steps=5",
                                  "--set", 'config.filters=["kcf", "local"]'])
    assert r.exit_code == 2, r.output
    assert r.output.strip().splitlines() == [f"error: {registry.clashes()[0]}"]
    r = CliRunner().invoke(main, ["list", "filters"])
    assert r.exit_code == 0, r.output
    assert f"local\n    cannot be loaded: {registry.clashes()[0]}" in r.output
    assert "\nkcf " in r.output  # the built-ins are still listed


@pytest.mark.parametrize("command", [["sweep", "sweeps/default.toml", "--dry-run"], ["tune", "x.toml"],
                                     ["check", "x.toml"], ["league", "x.toml"]])
def test_every_command_that_runs_filters_refuses_to_start(clashing_plugin, command):
    from mcjax.cli import main

    r = CliRunner().invoke(main, command)
    assert r.exit_code == 2 and r.output.startswith("error: filter 'local': the installed plugin"), r.output
