"""The robust consensus filters offered in Sun et al. 2011's scenario: opt-in names, refused with one line
where they cannot run (exit 2 through the CLI's own entry point)."""

import pytest
from click.testing import CliRunner

from mcjax.cli import main
from mcjax.scenarios import sun2011 as lf


def test_they_are_opt_in_names_and_the_papers_five_stay_the_default():
    assert lf.Config().filters == ("cif", "icf", "modified_icf", "kcf", "local")
    assert {"ci", "hcmci"} <= set(lf.SCENARIO.settings["filters"].choices)


@pytest.mark.parametrize("sets, words", [
    (["config.filters=[ci, hcmci]", "config.consensus_steps=0", "config.planner=none"],
     ["consensus_steps", ">= 1", "ci, hcmci"]),
    (["config.filters=[cii]"], ["filters", "cii", "hcmci"]),
])
def test_bad_input_exits_2_with_one_line_naming_it(sets, words):
    args = ["run", "configs/sun2011.toml", "--seeds", "1"] + [a for s in sets for a in ("--set", s)]
    done = CliRunner().invoke(main, args)
    assert done.exit_code == 2, done.output
    line = done.output.strip().splitlines()[-1]
    assert all(w in line for w in words), line


def test_a_scenario_that_cannot_run_them_refuses_them():
    done = CliRunner().invoke(main, ["run", "configs/ren2017.toml", "--seeds", "1", "--set", "config.filters=[ci]"])
    assert done.exit_code == 2 and "filters" in done.output and "imm" in done.output, done.output


def test_the_flock_offers_them_only_when_every_node_filters():
    from mcjax.scenarios import lou2013

    assert lou2013.Config().filters == ("kcf", "local")
    with pytest.raises(ValueError, match="filter_nodes must be 'all' with the filters ci"):
        lou2013.Config(filters=("kcf", "ci"))
    assert lou2013.Config(filters=("kcf", "ci", "hcmci"), filter_nodes="all").filters[-1] == "hcmci"
    with pytest.raises(ValueError, match="message_delay must be 0"):
        lou2013.Config(filters=("ci",), filter_nodes="all", message_delay=1)
