"""The filter contract and its registry: every built-in filter is a record with its traits as data; a filter
of one's own — a file reference or an installed plugin — is found the same way and runs in a scenario exactly
as a built-in does; bad input is one line naming the filter."""

import importlib.metadata
import sys

import numpy as np
import pytest

from mcjax.contract.filter import Filter, Traits
from mcjax.tracking.filters import registry, steps

#: A filter written only through the public contract: the local EKF's step under another name.
MY_FILTER = '''
from mcjax.contract.filter import Filter, Traits
from mcjax.tracking.filters.consensus import local_step

MINE = Filter("my_local", "my local EKF", "ours",
              lambda m, post, meas: local_step(m.h, m.angle_mask, post, meas, m.F, m.Q),
              Traits(late_messages=True, messages=False))
NOT_A_FILTER = 3
CLASH = Filter("local", "another local", "ours", MINE.step)
'''


@pytest.fixture
def plugin_file(tmp_path):
    path = tmp_path / "my_filter.py"
    path.write_text(MY_FILTER)
    return path


def test_the_built_ins_are_records_with_their_traits_as_data():
    assert registry.FILTER_KINDS == ("cif", "icf", "modified_icf", "kcf", "local", "ci", "hcmci")
    for name, f in registry.BUILTIN.items():
        assert isinstance(f, Filter) and f.name == name and f.title and f.reference
    traits = {n: f.traits for n, f in registry.BUILTIN.items()}
    assert [n for n, t in traits.items() if t.centralised] == ["cif"]
    assert [n for n, t in traits.items() if t.late_messages] == ["cif", "kcf", "local"]
    assert [n for n, t in traits.items() if t.messages and t.late_messages] == ["kcf"]  # the one mailbox
    assert [n for n, t in traits.items() if t.weights == "doubly_stochastic"] == ["ci", "hcmci"]
    assert steps.delayed_sender(("cif", "kcf", "local")) == 1 and steps.delayed_sender(("cif", "icf")) is None


@pytest.mark.parametrize("fields, message", [
    (dict(name="My Filter"), "name must be lower-case"),
    (dict(title=""), "title must be a non-empty string"),
    (dict(step=3), "step must be a function"),
    (dict(traits=(True,)), "traits must be a mcjax.contract.filter.Traits"),
    (dict(traits=Traits(weights="row_stochastic")), "traits.weights must be one of any, doubly_stochastic"),
    (dict(traits=Traits(centralised=1)), "traits.centralised must be True or False"),
])
def test_a_bad_record_is_one_line_naming_the_field(fields, message):
    good = dict(name="mine", title="mine", reference="ours", step=lambda m, p, z: p)
    with pytest.raises(ValueError, match=message) as err:
        Filter(**{**good, **fields})
    assert "\n" not in str(err.value)


def test_a_file_reference_resolves_and_bad_ones_are_one_line(plugin_file):
    f = registry.get(f"{plugin_file}:MINE")
    assert f.name == "my_local" and registry.get(f"{plugin_file}:MINE") is f
    assert registry.origin(f"{plugin_file}:MINE") == str(plugin_file)
    for ref, message in [(f"{plugin_file}:NOT_A_FILTER", "is a int, not an mcjax.contract.filter.Filter"),
                         (f"{plugin_file}:CLASH", "named 'local', the name of a built-in filter"),
                         (f"{plugin_file}:NOPE", "has no attribute 'NOPE'"),
                         (f"{plugin_file.parent / 'absent.py'}:F", "filter file not found"),
                         ("modifed_icf", "did you mean 'modified_icf'")]:
        with pytest.raises(ValueError, match=message) as err:
            registry.get(ref)
        assert "\n" not in str(err.value)


def _entry_point(monkeypatch, tmp_path, value):
    point = importlib.metadata.EntryPoint(name="their_filter", value=value, group=registry.ENTRY_POINT_GROUP)
    real = importlib.metadata.entry_points

    def entry_points(**kw):
        return [point] if kw.get("group") == registry.ENTRY_POINT_GROUP else real(**kw)

    monkeypatch.setattr(registry, "entry_points", entry_points)
    monkeypatch.setattr(importlib.metadata, "entry_points", entry_points)
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.setattr(registry, "_FOUND", {})


def test_an_installed_plugin_is_found_listed_and_a_broken_one_says_why(monkeypatch, tmp_path, plugin_file):
    from click.testing import CliRunner

    from mcjax.cli import main

    _entry_point(monkeypatch, tmp_path, "my_filter:MINE")
    assert registry.known()[-1] == "their_filter" and registry.get("their_filter").name == "my_local"
    r = CliRunner().invoke(main, ["list", "filters"])
    assert r.exit_code == 0, r.output
    assert "their_filter" in r.output and "my local EKF" in r.output and "[plugin: " in r.output
    assert "scenarios: leader_follower, flocking, wind_formation" in r.output.split("their_filter")[1]
    (tmp_path / "broken_filter.py").write_text("raise RuntimeError('no such library')\n")
    _entry_point(monkeypatch, tmp_path, "broken_filter:F")
    with pytest.raises(ValueError, match="the plugin broken_filter:F failed to import: RuntimeError: no such library"):
        registry.get("their_filter")
    r = CliRunner().invoke(main, ["list", "filters"])
    assert r.exit_code == 0 and "cannot be loaded" in r.output, r.output
    sys.modules.pop("my_filter", None)


def test_a_filter_of_ones_own_runs_in_a_scenario_as_the_built_in_it_copies(plugin_file):
    """Sun et al. 2011's open loop with the local EKF and the same step as a file plugin: the plugin's
    outputs are the built-in's (the scenarios call any filter through its record). To rounding, not bit
    for bit: two copies of one step in one program are fused differently by XLA (measured 1.8e-10)."""
    import jax

    from mcjax import configure, engine, scenarios

    configure()
    sc = scenarios.get("leader_follower")
    cfg = sc.Config(filters=("local", f"{plugin_file}:MINE"), n_steps=12, warmup_steps=2, planner="none")
    params = engine.stack_points([sc.default_params(cfg)])
    out = engine.simulate(sc, cfg, jax.tree.map(lambda a: np.repeat(a, 3, axis=0), params),
                          jax.random.split(jax.random.key(0), 3))
    rmse = np.asarray(out["rmse"])
    assert rmse.shape == (3, 2) and np.all(np.isfinite(rmse))
    np.testing.assert_allclose(rmse[:, 1], rmse[:, 0], rtol=1e-8)


def test_a_scenario_refuses_what_the_traits_forbid_in_one_line(plugin_file):
    from mcjax import scenarios

    sc = scenarios.get("leader_follower")
    with pytest.raises(ValueError, match="filters must be among cif, kcf, local when message_delay > 0"):
        sc.Config(filters=("icf",), planner="none", message_delay=1)
    with pytest.raises(ValueError, match="filters: filter 'nope.py:F'|unknown: 'nope'"):
        sc.Config(filters=("cif", "nope"), planner="none")
    with pytest.raises(ValueError, match=r"filters: filter '.*:CLASH' is named 'local'"):
        sc.Config(filters=("cif", f"{plugin_file}:CLASH"), planner="none")
    assert sc.Config(filters=("cif", f"{plugin_file}:MINE"), planner="none", message_delay=2).message_delay == 2


def _docs_filter(folder):
    """The filter file of docs/library.md's "Writing a filter", written to ``folder``; its reference."""
    import re
    from pathlib import Path

    text = (Path(__file__).resolve().parents[3] / "docs" / "library.md").read_text(encoding="utf-8")
    (folder / "my_ekf.py").write_text(re.search(r"`my_ekf\.py`:\s*```python\n(.*?)```", text, re.S).group(1))
    return f"{folder / 'my_ekf.py'}:MY_EKF"


@pytest.mark.parametrize("scenario, config", [
    ("leader_follower", dict(planner="none", faults="on")),
    ("flocking", dict(n_agents=6, faults="on")),
    ("wind_formation", dict(faults="on")),
])
def test_the_docs_filter_runs_in_the_three_scenarios_as_the_local_filter(tmp_path, scenario, config):
    """docs/library.md's filter, written from the docs alone (the public contract), in each scenario that
    takes any filter, under faults where the scenario has them: every output the built-ins' rows carry, and
    the local EKF's numbers (it is the same filter, written again)."""
    import jax

    from mcjax import configure, engine, scenarios

    configure()
    sc = scenarios.get(scenario)
    ref = _docs_filter(tmp_path)
    cfg = sc.Config(filters=("local", ref), n_steps=10, warmup_steps=2, **config)
    params = engine.stack_points([sc.default_params(cfg, link_loss=0.2, sensor_dropout=0.1)])
    out = engine.simulate(sc, cfg, jax.tree.map(lambda a: np.repeat(a, 2, axis=0), params),
                          jax.random.split(jax.random.key(1), 2))
    assert np.asarray(out["links_lost"]).sum() > 0  # the faults were drawn
    declared = sc.outputs(cfg)
    assert set(out) == set(declared)
    for name, o in declared.items():
        if o.per_filter:
            a = np.asarray(out[name], np.float64)
            np.testing.assert_allclose(a[:, 1], a[:, 0], rtol=1e-7, atol=1e-9, err_msg=name)


@pytest.mark.parametrize("scenario, why", [("uuv_imm", "Ren & Lv 2017's filters are UKFs of its motion models"),
                                           ("urban_bearing", "Chen & Hao 2022 fly one UAV with no comm graph")])
def test_the_two_scenarios_that_take_no_filter_of_ones_own_say_why_in_one_line(plugin_file, scenario, why):
    from mcjax import scenarios

    with pytest.raises(ValueError, match="must be among its own") as err:
        scenarios.get(scenario).Config(filters=(f"{plugin_file}:MINE",))
    assert why in str(err.value) and "\n" not in str(err.value)


@pytest.mark.parametrize("returns, message", [
    ("post.x", r"its step returned an array \(shape \(3, 4\)\), not a Gaussian"),
    ("post._replace(x=post.x[:, :2])", r"returned x of shape \(3, 2\) and dtype float64; the posterior's x is \(3, 4\)"),
    ("post._replace(P=post.P.astype('float32'))", "returned P of shape .* and dtype float32"),
])
def test_a_step_returning_the_wrong_structure_is_refused_in_one_line_naming_the_field(tmp_path, returns, message):
    import jax.numpy as jnp

    from mcjax import configure
    from mcjax.tracking.filters.consensus import FilterOptions, Measurements

    configure()
    (tmp_path / "bad_filter.py").write_text(
        "from mcjax.contract.filter import Filter\n"
        f"BAD = Filter('bad', 'bad', 'ours', lambda m, post, meas: {returns})\n")
    ref = f"{tmp_path / 'bad_filter.py'}:BAD"
    n = 3
    states = steps.init_states((ref,), jnp.zeros(4), jnp.eye(4), n)
    meas = Measurements(jnp.full((n, 2), jnp.nan), jnp.zeros((n, 2)), jnp.zeros((n, n)),
                        jnp.broadcast_to(jnp.eye(2), (n, 2, 2)))
    with pytest.raises(ValueError, match=message) as err:
        steps.filter_step((ref,), FilterOptions(), lambda x, s: x[:2], jnp.zeros(2), states, meas, jnp.eye(4),
                          jnp.zeros((4, 4)), 0.1)
    assert f"filter {ref!r}" in str(err.value) and "\n" not in str(err.value)


def test_through_the_command_line_a_broken_step_is_one_line_and_exit_2(tmp_path):
    from pathlib import Path

    from click.testing import CliRunner

    from mcjax.cli import main

    (tmp_path / "bad_filter.py").write_text("from mcjax.contract.filter import Filter\n"
                                            "BAD = Filter('bad', 'bad', 'ours', lambda m, post, meas: post.x)\n")
    config = Path(__file__).resolve().parents[3] / "configs" / "sun2011.toml"
    r = CliRunner().invoke(main, ["run", str(config), "--seeds", "2", "--set",
                                  f'config.filters=["local", "{tmp_path / "bad_filter.py"}:BAD"]',
                                  "--set", "config.planner=none", "--set", "config.n_steps=12"])
    assert r.exit_code == 2, r.output
    errors = [line for line in r.output.splitlines() if line.startswith("error:")]
    assert len(errors) == 1 and "its step returned" in errors[0] and "not a Gaussian" in errors[0], r.output
    assert "Traceback" not in r.output
