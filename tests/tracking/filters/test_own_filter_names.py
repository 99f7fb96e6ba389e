"""A filter of one's own is shown by its record's name wherever a built-in's name appears (the datasets'
``filter`` column, the printed table, the report page), where it came from is kept once (the dataset's
``filter_sources``, the page's glossary); two filters of one name, a file that fails to import, a typo: one line,
exit 2, before anything is written; a scenario's refusal names the trait; ``mcjax list filters`` names only the
scenarios that take the filter (issue 67, items 3 and 4)."""

from __future__ import annotations

from pathlib import Path

import pandas as pd
import pytest
from click.testing import CliRunner

from mcjax.cli import main
from mcjax.tracking.filters import registry
from tests.tracking.filters import fake_plugins

ROOT = Path(__file__).resolve().parents[3]

#: Two records written only through the public contract: the local EKF's step under the name 'my_local', and
#: the same step under a trait the flock of Lou, Cui & Li 2013 cannot give with its defaults.
OWN = '''
from mcjax.contract.filter import Filter, Traits
from mcjax.tracking.filters.consensus import local_step

MINE = Filter("my_local", "my local EKF", "ours",
              lambda m, post, meas: local_step(m.h, m.angle_mask, post, meas, m.F, m.Q),
              Traits(late_messages=True, messages=False))
AVERAGING = Filter("my_average", "needs Metropolis weights", "ours", MINE.step,
                   Traits(weights="doubly_stochastic", late_messages=True, messages=False))
'''


@pytest.fixture
def own(tmp_path):
    (tmp_path / "own.py").write_text(OWN)
    (tmp_path / "twin.py").write_text(OWN.replace('"my local EKF"', '"another file, the same name"'))
    return tmp_path


def _cli(args, cwd):
    import contextlib

    with contextlib.chdir(cwd):
        return CliRunner().invoke(main, args)


def _errors(r) -> list[str]:
    return [line for line in r.output.splitlines() if line.startswith("error:")]


# ------------------------------------------------------------------------------ one line, exit 2


@pytest.mark.parametrize("body, expected", [
    ("from mcjax.contract.filter import Filter\nx = 1\ny = foo + 1\n",
     "importing {path} failed: NameError: name 'foo' is not defined (line 3)"),
    ("import a_module_nobody_installed_67\n",
     "importing {path} failed: ModuleNotFoundError: No module named 'a_module_nobody_installed_67' (line 1)"),
    ("F = 1\ndef f(:\n", "importing {path} failed: SyntaxError: "),
])
def test_a_filter_file_that_fails_to_import_is_one_line_and_exit_2(tmp_path, body, expected):
    path = tmp_path / "broken.py"
    path.write_text(body)
    with pytest.raises(ValueError) as err:
        registry.get(f"{path}:F")
    text = str(err.value)
    assert text.startswith(f"filter '{path}:F': ") and expected.format(path=path) in text and "\n" not in text
    if "SyntaxError" in expected:
        assert text.endswith("(line 2)"), text
    out = tmp_path / "out"
    r = _cli(["sweep", str(ROOT / "sweeps" / "default.toml"), "--seeds", "1", "--out", str(out),
              "--set", 'config.filters=["modified_icf", "broken.py:F"]'], tmp_path)
    assert r.exit_code == 2 and len(_errors(r)) == 1 and "Traceback" not in r.output, r.output
    assert expected.format(path=path) in _errors(r)[0] and not out.exists()


def test_a_module_that_is_missing_is_one_line_and_exit_2(tmp_path):
    with pytest.raises(ValueError, match=r"^filter 'no_such_pkg_67\.filters:F': importing module "
                                         r"no_such_pkg_67\.filters failed: ModuleNotFoundError: No module named "
                                         r"'no_such_pkg_67'$"):
        registry.get("no_such_pkg_67.filters:F")
    r = _cli(["run", str(ROOT / "configs" / "chen2013.toml"), "--seeds", "1",
              "--set", 'config.filters=["kcf", "no_such_pkg_67.filters:F"]'], tmp_path)
    assert r.exit_code == 2 and len(_errors(r)) == 1 and "No module named 'no_such_pkg_67'" in r.output, r.output


@pytest.mark.parametrize("typo, meant", [("modifed_icf", "modified_icf"), ("kfc", "kcf"), ("loacl", "local"),
                                         ("hcmic", "hcmci")])
def test_a_typo_of_a_filter_name_is_told_the_name(typo, meant):
    with pytest.raises(ValueError, match=f"got '{typo}'; did you mean '{meant}'\\?$"):
        registry.get(typo)


@pytest.mark.parametrize("typo, meant", [("modifed_icf", "modified_icf"), ("kfc", "kcf")])
def test_a_typo_in_a_configs_filters_is_told_the_name_exit_2(tmp_path, typo, meant):
    out = tmp_path / "out"
    r = _cli(["sweep", str(ROOT / "sweeps" / "default.toml"), "--seeds", "1", "--out", str(out),
              "--set", f'config.filters=["cif", "{typo}"]'], tmp_path)
    assert r.exit_code == 2 and len(_errors(r)) == 1, r.output
    assert _errors(r)[0].endswith(f"(unknown: '{typo}'; did you mean '{meant}'?)") and not out.exists(), r.output


def test_a_name_far_from_every_filter_gets_no_guess():
    with pytest.raises(ValueError) as err:
        registry.get("particle")
    assert "did you mean" not in str(err.value)


def test_two_filters_of_one_name_are_refused_in_one_line_before_anything_is_written(own):
    from mcjax import scenarios

    sc = scenarios.get("wind_formation")
    a, b = f"{own / 'own.py'}:MINE", f"{own / 'twin.py'}:MINE"
    with pytest.raises(ValueError) as err:
        sc.Config(filters=("kcf", a, b))
    assert str(err.value) == (f"filters: {a!r} and {b!r} are both named 'my_local' (the name the datasets show); "
                              f"rename one of the two records")
    out = own / "out"
    r = _cli(["sweep", str(ROOT / "sweeps" / "default.toml"), "--seeds", "1", "--out", str(out),
              "--set", 'config.filters=["modified_icf", "own.py:MINE", "twin.py:MINE"]'], own)
    assert r.exit_code == 2 and len(_errors(r)) == 1 and "both named 'my_local'" in r.output, r.output
    assert not out.exists()
    assert sc.Config(filters=("kcf", a)).filters == ("kcf", a)  # one of them alone runs; the config keeps the reference


def test_a_league_of_two_filters_of_one_name_is_refused_in_one_line(own):
    (own / "twins.toml").write_text(f'seeds = 2\nfilters = ["kcf", "own.py:MINE", "twin.py:MINE"]\n'
                                    f'[scenarios.wind_formation]\nbase = "{ROOT / "configs" / "chen2013.toml"}"\n'
                                    f'[points.none]\ndescription = "no faults"\n')
    r = _cli(["league", "twins.toml", "--out", str(own / "league")], own)
    assert r.exit_code == 2 and len(_errors(r)) == 1 and "both named 'my_local'" in r.output, r.output
    assert not (own / "league").exists()


def test_a_league_table_shows_a_filter_of_ones_own_by_its_records_name(own):
    """The league file names the file (``own.py:MINE``); its table, as every dataset, shows ``my_local``
    (Chen & Lu 2013, 8 steps, 3 runs, no timing pass)."""
    (own / "mine.toml").write_text(f'seeds = 3\ntiming_runs = 0\nfilters = ["kcf", "own.py:MINE"]\n'
                                   f'[scenarios.wind]\nbase = "{ROOT / "configs" / "chen2013.toml"}"\n'
                                   f'config = {{ n_steps = 8 }}\n[points.none]\ndescription = "no faults"\n')
    r = _cli(["league", "mine.toml", "--out", str(own / "league")], own)
    assert r.exit_code == 0, r.output
    table = pd.read_parquet(own / "league" / "league.parquet")
    assert sorted(table["filter"]) == ["kcf", "my_local"]
    assert "my_local" in r.output and "own.py" not in r.output


def test_a_claim_names_a_filter_of_ones_own_by_its_reference_or_its_name(own):
    """A claims file's ``filter`` may be the reference its sweep's config wrote or the record's name; either
    selects the rows the dataset shows by the name (Chen & Lu 2013, 12 steps, 4 runs)."""
    import math

    from mcjax.claims.spec import load_claims

    (own / "claims.toml").write_text(f"""
paper = "a test"
seeds = 4
[sweeps.s]
base = "{(ROOT / 'configs' / 'chen2013.toml').as_posix()}"
config = {{ n_steps = 12, filters = ["kcf", "own.py:MINE"] }}

[[claim]]
id = "kcf-below-mine"
claim = "consensus beats each UAV's own filter"
where = "nowhere"
paper = "-"
output = "rmse"
filter = "kcf"
minus = {{ filter = "{(own / 'own.py').as_posix()}:MINE" }}
relation = "below"
value = 0.0

[[claim]]
id = "mine-by-name"
claim = "each UAV's own filter stays below 20 m/s"
where = "nowhere"
paper = "-"
output = "rmse"
filter = "my_local"
relation = "below"
value = 20.0
""")
    claims = load_claims(own / "claims.toml")
    assert [c.side.minus.filter if c.side.minus else c.side.filter for c in claims.claims] == ["my_local", "my_local"]
    r = _cli(["check", "claims.toml", "--out", str(own / "checked")], own)
    assert r.exit_code in (0, 1) and "Traceback" not in r.output, r.output
    verdicts = pd.read_parquet(own / "checked" / "claims.parquet")
    assert list(verdicts["runs"]) == [4, 4] and all(math.isfinite(v) for v in verdicts["value"]), verdicts.T
    assert "(my_local)" in verdicts["statistic"][1] and "own.py" not in " ".join(verdicts["statistic"])


def test_a_file_record_named_like_an_installed_plugin_is_refused(own, monkeypatch):
    monkeypatch.syspath_prepend(str(own))
    fake_plugins.install(monkeypatch, "my_local", "twin:MINE")  # an installed plugin of that name, another record
    with pytest.raises(ValueError, match="is named 'my_local', the name of the installed plugin twin:MINE"):
        registry.get(f"{own / 'own.py'}:MINE")
    assert registry.get("my_local").title == "another file, the same name"  # the plugin itself resolves
    assert registry.get("twin:MINE") is registry.get("my_local")  # and the very record, by its module, too


# ------------------------------------------------------------------------------ shown by its name


def _fake_run_chunks():
    """engine.run_chunks with outputs of the declared shapes, no simulation (tests/product/test_docs.py's)."""
    from tests.product.test_docs import _fake_run_chunks as fake

    return fake


def test_a_sweep_shows_it_by_its_name_and_keeps_where_it_came_from_once(own, monkeypatch):
    from mcjax import engine
    from mcjax.base.parquet import read_metadata

    monkeypatch.setattr(engine, "run_chunks", _fake_run_chunks())
    out = own / "out"
    r = _cli(["sweep", str(ROOT / "sweeps" / "default.toml"), "--seeds", "3", "--out", str(out),
              "--set", 'config.filters=["modified_icf", "own.py:MINE"]'], own)
    assert r.exit_code == 0, r.output
    assert r.output.splitlines()[0].endswith("filters modified_icf, my_local"), r.output  # the headline
    table = r.output.strip().split("\n\n")[-1]
    assert "my_local" in table and "own.py" not in table, table  # the printed summary
    rows = pd.read_parquet(out / "runs")
    assert list(dict.fromkeys(rows["filter"])) == ["modified_icf", "my_local"]
    assert len(rows) == 4 * 3 * 2  # default.toml: 4 comm radii x 3 seeds x 2 filters
    meta = read_metadata(out)
    assert meta["filters"] == ["modified_icf", "my_local"]
    assert meta["filter_sources"] == {"my_local": str(own / "own.py")}
    assert meta["config"]["filters"] == ["modified_icf", f"{own / 'own.py'}:MINE"]  # what was written: the reference
    r = _cli(["report", str(out)], own)
    assert r.exit_code == 0, r.output
    page = (out / "report" / "index.html").read_text(encoding="utf-8")
    where = str(own / "own.py")
    # where it came from once (the glossary), and the reference as written twice: the spec and the Config's table
    assert f"<dt>my_local</dt><dd>my local EKF (ours; from {where})</dd>" in page
    assert page.count(where) == 3 and page.count(f"{where}:MINE") == 2, page.count(where)
    assert page.count("my_local") >= 3  # the findings, the tables, the glossary


def test_built_in_rows_and_metadata_are_as_before():
    """With built-in filters only, the shown names are the names written and the metadata has no new key."""
    from mcjax import scenarios
    from mcjax.study import rows

    sc = scenarios.get("leader_follower")
    cfg = sc.Config(filters=("cif", "icf", "modified_icf"))
    assert rows.shown_filters(sc, cfg) == ["cif", "icf", "modified_icf"]
    assert rows.filter_sources(sc, cfg) == {}
    meta = sc.metadata(cfg)
    assert rows._shown(sc, cfg, meta) is meta


def test_a_league_reads_a_filter_of_its_own_by_the_name_the_file_wrote(own):
    """League.filter_name takes a dataset's filter value — a record's name, or the absolute reference a
    dataset written before 2026-12-07 holds — to the name the league file wrote."""
    from mcjax.league.spec import League

    ref = f"{own / 'own.py'}:MINE"
    registry.get(ref)
    league = League(own / "l.toml", "t", ("kcf", "own.py:MINE"), {"kcf": "kcf", "own.py:MINE": ref}, {}, {}, {},
                    1, 0, {})
    assert league.filter_name("my_local") == "own.py:MINE"
    assert league.filter_name(ref) == "own.py:MINE"
    assert league.filter_name("kcf") == "kcf"


# ------------------------------------------------------------------------------ refusals in the trait's words


def test_the_flock_refuses_a_filter_needing_doubly_stochastic_weights_in_the_traits_words(own):
    r = _cli(["run", str(ROOT / "configs" / "lou2013.toml"), "--seeds", "1",
              "--set", 'config.filters=["kcf", "own.py:AVERAGING"]'], own)
    assert r.exit_code == 2 and len(_errors(r)) == 1, r.output
    line = _errors(r)[0]
    assert "filter_nodes: must be 'all' with the filters my_average" in line
    assert "traits.weights = 'doubly_stochastic'" in line and "omega" not in line and "HCMCI" not in line, line


def test_list_filters_names_only_the_scenarios_that_take_it(own, monkeypatch):
    monkeypatch.syspath_prepend(str(own))
    fake_plugins.install(monkeypatch, "my_average", "own:AVERAGING")
    r = CliRunner().invoke(main, ["list", "filters"])
    assert r.exit_code == 0, r.output
    block = r.output.split("\nmy_average ")[1].split("\n")
    assert block[3].strip() == "scenarios: leader_follower, wind_formation", block
    assert block[4].strip().startswith("not with flocking's defaults: filter_nodes must be 'all'"), block
    hcmci = r.output.split("\nhcmci ")[1].split("\n")  # a built-in of the same trait: the same rule
    assert hcmci[3].strip() == "scenarios: leader_follower, wind_formation", hcmci


def test_a_step_returning_an_array_is_told_so_with_its_shape(own):
    import jax.numpy as jnp

    from mcjax import configure
    from mcjax.tracking.filters import steps
    from mcjax.tracking.filters.consensus import FilterOptions, Measurements

    configure()
    (own / "bad.py").write_text("from mcjax.contract.filter import Filter\n"
                                "BAD = Filter('bad', 'bad', 'ours', lambda m, post, meas: (post.x, post.P))\n")
    ref = f"{own / 'bad.py'}:BAD"
    n = 3
    states = steps.init_states((ref,), jnp.zeros(4), jnp.eye(4), n)
    meas = Measurements(jnp.full((n, 2), jnp.nan), jnp.zeros((n, 2)), jnp.zeros((n, n)),
                        jnp.broadcast_to(jnp.eye(2), (n, 2, 2)))
    with pytest.raises(ValueError, match=r"returned a tuple of 2 \(an array \(shape \(3, 4\)\), an array \(shape "
                                         r"\(3, 4, 4\)\)\), not a Gaussian"):
        steps.filter_step((ref,), FilterOptions(), lambda x, s: x[:2], jnp.zeros(2), states, meas, jnp.eye(4),
                          jnp.zeros((4, 4)), 0.1)
