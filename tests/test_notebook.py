"""mcjax from Python (mcjax.notebook): docs/library.md's "Sweeps from Python" runs as printed, from any
folder; the rows equal `mcjax sweep`'s dataset for the same spec and overrides, bit for bit, in the
dataset's column order, and the summary is the table the CLI prints; nothing is written unless asked;
a bad spec raises the CLI's line, naming the keyword arguments as written."""

import contextlib
import io
import re
from pathlib import Path

import pandas as pd
import pytest
from click.testing import CliRunner

from mcjax.base import parquet
from mcjax.cli import main
import mcjax.notebook as mc
from mcjax.study import SpecError

pytestmark = pytest.mark.xdist_group("notebook")  # one worker builds the module's fixtures once

ROOT = Path(__file__).resolve().parents[1]
SPEC = {"base": str(ROOT / "configs" / "ren2017.toml"), "seeds": 6, "config": {"filters": ["cv"]},
        "grid": {"comm_radius": [150.0, 450.0]}}
SET = {"config.n_steps": 12}
KEYS = ["point_id", "seed_index", "filter"]


def _toml(spec: dict) -> str:
    lines = [f'base = "{spec["base"]}"', f'seeds = {spec["seeds"]}', "[config]", 'filters = ["cv"]', "[grid]",
             "comm_radius = [150.0, 450.0]"]
    return "\n".join(lines) + "\n"


def _sorted(df: pd.DataFrame) -> pd.DataFrame:
    return df.sort_values(KEYS).reset_index(drop=True)[sorted(df.columns)]


@pytest.fixture(scope="module")
def both(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("notebook")
    spec = tmp / "spec.toml"
    spec.write_text(_toml(SPEC), encoding="utf-8")
    printed = CliRunner().invoke(main, ["sweep", str(spec), "--out", str(tmp / "cli"), "--set", "config.n_steps=12"])
    assert printed.exit_code == 0, printed.output
    with contextlib.chdir(tmp):
        api = mc.sweep(SPEC, set=SET)
        written = sorted(p.name for p in tmp.iterdir())
    return api, parquet.read_table(tmp / "cli"), printed.output, written, tmp


def test_the_rows_are_the_clis_bit_for_bit_and_nothing_is_written(both):
    api, cli, _, written, _ = both
    pd.testing.assert_frame_equal(_sorted(api.rows), _sorted(cli), check_dtype=False, check_categorical=False,
                                  check_exact=True)
    assert written == ["cli", "spec.toml"]  # the API call wrote nothing
    assert api.out_dir is None and api.axes == ("comm_radius",)


def test_the_rows_have_the_datasets_column_order(both):
    """As pandas (and DuckDB, polars) read the dataset: the part files' columns, point_id (the folder) last;
    in memory it was second, read back from a written dataset first."""
    api, _, _, _, tmp = both
    dataset = list(pd.read_parquet(tmp / "cli" / "runs").columns)
    assert dataset[0] == "scenario" and dataset[-1] == "point_id"
    assert list(api.rows.columns) == dataset
    assert list(mc.sweep(SPEC, set=SET, out=tmp / "ordered").rows.columns) == dataset


def test_the_summary_is_the_table_the_cli_prints(both):
    api, _, output, _, _ = both
    body = api.table().split("\n", 1)[1]  # the legend's first line names the scenario the same way
    assert body.strip() in output
    assert list(api.summary["filter"]) == ["cv", "cv"] and (api.summary["n"] == 6).all()


def test_out_writes_the_dataset_mcjax_report_reads(both):
    api, _, _, _, tmp = both
    again = mc.sweep(SPEC, set=SET, out=tmp / "api")
    assert (tmp / "api" / "sweep.json").is_file()
    pd.testing.assert_frame_equal(_sorted(again.rows), _sorted(api.rows), check_dtype=False, check_exact=True)
    assert CliRunner().invoke(main, ["report", str(tmp / "api"), "--no-plots"]).exit_code == 0


def test_a_bad_spec_raises_the_clis_line():
    with pytest.raises(SpecError, match=r"params\.no_such_param"):
        mc.sweep(SPEC, set={"params.no_such_param": 1.0})


@pytest.mark.parametrize("given, named", [(dict(seeds=0), "seeds: must be an integer in [1, 10000000]; got 0"),
                                          (dict(chunk_size=0), "chunk_size: must be an integer in [1, 1000000]; got 0"),
                                          (dict(set={"params.": 1.0}), "set['params.']: must be a key path")])
def test_from_python_a_message_names_the_keyword_argument(given, named):
    """``seeds=0`` is named ``seeds``, not the command line's ``--seeds`` (which `mcjax sweep` still says)."""
    with pytest.raises(mc.SpecError) as caught:
        mc.sweep(SPEC, **given)
    assert str(caught.value).startswith(named) and "--" not in str(caught.value), str(caught.value)
    if "seeds" in given:
        with pytest.raises(mc.SpecError, match=r"^seeds: "):
            mc.run(ROOT / "configs" / "ren2017.toml", seeds=0)


def test_library_md_sweeps_from_python_runs_as_printed(tmp_path):
    """From a folder that is not the checkout (a notebook's own), as printed; its bad spec's line is the one
    its comment shows, and the docs name SpecError where it is defined and where it is imported from."""
    text = (ROOT / "docs" / "library.md").read_text(encoding="utf-8")
    section = text.split("## Sweeps from Python", 1)[1].split("\n## ", 1)[0]
    code = re.search(r"```python\n(.*?)```", section, flags=re.S).group(1)
    out = io.StringIO()
    with contextlib.chdir(tmp_path), contextlib.redirect_stdout(out):
        namespace = {}
        exec(compile(code, "docs/library.md", "exec"), namespace)
    assert "rmse" in out.getvalue() and out.getvalue().count("\n- ") >= 1
    assert type(namespace["figure"]).__name__ == "Figure"
    shown = re.search(r"print\(mistake\)\s+# (.*)", code).group(1)
    assert out.getvalue().rstrip().endswith(shown), out.getvalue()[-300:]
    assert list(tmp_path.iterdir()) == []  # nothing written
    prose = " ".join(section.split())
    for name in re.findall(r"`((?:mc|mcjax(?:\.\w+)*)\.SpecError)`", prose):  # each name it gives is the class
        module, _, _ = name.rpartition(".")
        assert getattr(mc if module == "mc" else __import__(module, fromlist=["x"]), "SpecError") is SpecError, name
    assert f"`{SpecError.__module__}`" in prose  # where a traceback says it lives
