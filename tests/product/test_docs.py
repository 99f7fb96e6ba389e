"""The README and docs/*.md stay true: every command they show runs, every link stays inside
the repository, the option lists of docs/cli.md are the commands' own --help, and the README
is what a newcomer needs first.

Every ``mcjax`` command in a ```bash block runs in-process through the CLI's entry point
(``mcjax.cli.main``, click's runner), in order, in a scratch folder that sees the
repository's configs/, sweeps/ and benchmarks/: specs and configs are read and validated,
``--set`` values applied, Parquet datasets written, summaries printed, reports made. Only
the simulation itself is replaced by random numbers of the declared shapes (compiling every
paper's program would take many minutes), so what is checked is everything a reader types.
A ``python benchmarks/X.py --opt`` line is checked for the script and each option; ``pip
install`` lines for the extras and packages the project declares. The README's Python
blocks (and docs/cli.md's) run against the datasets the commands wrote. docs/library.md's
code is run by tests/product/test_readme.py and tests/contract/test_contract.py, its "Writing a filter" whole
(every block, as written, from a folder outside the repository, the simulations real) by
tests/tracking/filters/test_writing_a_filter.py. A block preceded by
``<!-- not run by tests/product/test_docs.py: REASON -->`` is left out (the reason names what runs
it instead).
"""

from __future__ import annotations

import ast
import contextlib
import io
import os
import re
import shlex
import tomllib
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import click
from click.testing import CliRunner

from mcjax import engine
from mcjax.cli import doc
from mcjax.cli import main

ROOT = Path(__file__).resolve().parents[2]
README = ROOT / "README.md"
DOCS = [README, *sorted((ROOT / "docs").glob("*.md"))]
PYPROJECT = tomllib.loads((ROOT / "pyproject.toml").read_text())
SKIP = re.compile(r"<!-- not run by tests/product/test_docs.py: (.+?) -->\s*$")
FENCE = re.compile(r"^```(\w*)\s*$")


def fenced(path: Path) -> list[tuple[str, str, str | None]]:
    """``(language, text, skip reason)`` of every fenced block of a Markdown file."""
    out, lines = [], path.read_text(encoding="utf-8").splitlines()
    i = 0
    while i < len(lines):
        m = FENCE.match(lines[i])
        if m and m.group(1):
            j = next(k for k in range(i + 1, len(lines)) if lines[k].startswith("```"))
            prev = next((lines[k] for k in range(i - 1, -1, -1) if lines[k].strip()), "")
            skip = SKIP.match(prev)
            out.append((m.group(1), "\n".join(lines[i + 1:j]) + "\n", skip.group(1) if skip else None))
            i = j + 1
        else:
            i += 1
    return out


def shell_commands(text: str) -> list[list[str]]:
    """The commands of a shell block: comments dropped, ``&&`` chains split, leading
    ``NAME=value`` environment settings dropped."""
    joined = text.replace("\\\n", " ")
    out = []
    for line in joined.splitlines():
        words = shlex.split(line, comments=True)
        if not words:
            continue
        assert not {";", "|", "||", "&"} & set(words), f"unsupported shell syntax in {line!r}"
        cmd: list[str] = []
        for w in [*words, "&&"]:
            if w == "&&":
                while cmd and re.fullmatch(r"[A-Z_][A-Z0-9_]*=.*", cmd[0]):
                    cmd.pop(0)
                if cmd:
                    out.append(cmd)
                cmd = []
            else:
                cmd.append(w)
    return out


def doc_commands(path: Path) -> list[list[str]]:
    return [c for lang, text, skip in fenced(path) if lang in ("bash", "sh", "shell") and skip is None
            for c in shell_commands(text)]


# ------------------------------------------------------------------------------ the README


def test_readme_opens_with_the_two_commands_ci_runs():
    lang, text, _ = fenced(README)[0]
    lines = [line for line in text.splitlines() if line.strip()]
    assert lang == "bash" and len(lines) == 2, text
    # any Python, an externally managed one too: a virtual environment first, made and activated in the line
    assert lines[0].startswith("python3 -m venv .venv && . .venv/bin/activate && pip install -e . && "
                               "mcjax sweep sweeps/default.toml")
    assert "mcjax report" not in lines[0]  # the sweep prints the summary; the report would print it again
    assert lines[1] == 'pip install -e ".[test]" && python -m pytest'
    ci = [line for line in (ROOT / ".ci" / "run").read_text().splitlines() if line.startswith("pip install")]
    assert ci == [lines[1]]  # what CI runs is what a newcomer types
    before = README.read_text(encoding="utf-8").split("```bash", 1)[0]
    assert len(before.splitlines()) <= 20  # they come first, after a few lines saying what mcjax is


def test_readme_is_short_and_names_papers_not_seeds():
    text = README.read_text(encoding="utf-8")
    assert len(text.splitlines()) <= 200
    for doc in DOCS:
        body = doc.read_text(encoding="utf-8")
        assert not re.search(r"seed 0\d\d", body), doc.name
        assert "../shared" not in body and "shared/" not in body, doc.name
    for paper in ("Sun", "Ren & Lv 2017", "Chen & Hao 2022", "Lou", "Chen & Lu 2013"):
        assert paper in text
    for heading in ("## Past one machine", "## Tuning by gradient, and sensitivities", "## Dependencies and why"):
        assert heading in text
    section = text.split("## Dependencies and why", 1)[1].split("\n## ", 1)[0]
    for dep in ("click", "tqdm", "matplotlib", "scipy"):
        assert f"**{dep}**" in section


LINK = re.compile(r"(?<!\!)\[[^\]]*\]\(([^)\s]+)\)")


def test_links_stay_inside_the_repository():
    for doc in DOCS:
        for target in LINK.findall(doc.read_text(encoding="utf-8")):
            assert not re.match(r"[a-z][a-z0-9+.-]*:", target), f"{doc.name}: {target} leaves the repository"
            path = target.split("#", 1)[0]
            if not path:
                continue
            resolved = (doc.parent / path).resolve()
            assert resolved.is_relative_to(ROOT), f"{doc.name}: {target} points outside the repository"
            assert resolved.exists(), f"{doc.name}: {target} does not exist"


def test_benchmarks_are_dated_newest_first():
    text = (ROOT / "docs" / "benchmarks.md").read_text(encoding="utf-8")
    dates = re.findall(r"^## (\d{4}-\d{2}-\d{2})\s*$", text, flags=re.M)
    assert len(dates) >= 3 and dates == sorted(dates, reverse=True)
    sections = re.split(r"^## \d{4}-\d{2}-\d{2}\s*$", text, flags=re.M)[1:]
    for date, body in zip(dates, sections):
        for entry in re.split(r"^### ", body, flags=re.M)[1:]:
            assert "`" in entry, f"{date}: {entry.splitlines()[0]} names no command"


# ------------------------------------------------------------------------------ the CLI's own help


def test_cli_md_holds_every_commands_current_help():
    text = (ROOT / "docs" / "cli.md").read_text(encoding="utf-8")
    stale = doc.stale(text)
    if stale:  # say how each block differs from the command's help now
        import difflib

        found = {m.group(1): m.group(0) for m in doc._BLOCK.finditer(text)}
        diffs = ["\n".join(difflib.unified_diff(found.get(c, "").splitlines(), doc._block(c).splitlines(), c, "now",
                                                 lineterm="")) for c in stale]
        raise AssertionError("docs/cli.md is out of date: run `python -m mcjax.cli.doc`\n" + "\n".join(diffs))
    for name, cmd in main.commands.items():
        for param in cmd.params:
            for opt in param.opts:
                if opt.startswith("-"):
                    assert opt in text, (name, opt)


def test_help_lists_every_command_on_one_line():
    r = CliRunner().invoke(main, ["--help"], terminal_width=80)  # a common terminal's width
    assert r.exit_code == 0
    lines = r.output.split("Commands:\n", 1)[1].splitlines()
    listed = [line.split()[0] for line in lines if line.strip()]
    assert listed == sorted(main.commands)  # each command once, one line each
    for line in lines:
        if line.strip():
            assert not line.rstrip().endswith("..."), line  # not cut short
            assert len(line.split(None, 1)[1]) > 20, line


# ------------------------------------------------------------------------------ every command runs


def _fake_run_chunks(scenario, cfg, point_params, n_seeds, *, base_seed=0, chunk_size=1000, chunks=None,
                     timeseries=False, sensitivity=None):
    """engine.run_chunks with random outputs of the declared shapes instead of a simulation."""
    n_points = np.asarray(getattr(point_params, point_params._fields[0])).shape[0]
    plan = engine.chunk_plan(n_points * n_seeds, chunk_size)
    filters = len(cfg.filters)
    for idx in (range(len(plan)) if chunks is None else chunks):
        start, stop = plan[idx]
        n = stop - start
        rng = np.random.default_rng(idx)
        out = {}
        for name, o in scenario.outputs(cfg).items():
            shape = (n, filters) if o.per_filter else (n,)
            if o.role == "divergence":
                out[name] = rng.random(shape) < 0.1
            elif o.role == "nonfinite":
                out[name] = np.zeros(shape, bool)
            else:
                out[name] = rng.gamma(2.0, 10.0, shape)
        if timeseries:
            series = {name: np.zeros((n, cfg.n_steps, filters) if o.per_filter else (n, cfg.n_steps))
                      for name, o in scenario.timeseries_outputs(cfg).items()}  # zeros: quick to compress
            yield idx, start, stop, (out, series)
        else:
            yield idx, start, stop, out


def _argparse_options(script: Path) -> set[str]:
    found = set()
    for node in ast.walk(ast.parse(script.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Call) and getattr(node.func, "attr", "") == "add_argument":
            found |= {a.value for a in node.args if isinstance(a, ast.Constant) and str(a.value).startswith("-")}
    return found


def _declared_packages() -> set[str]:
    project = PYPROJECT["project"]
    specs = [*project["dependencies"], *(d for ds in project["optional-dependencies"].values() for d in ds)]
    return {re.split(r"[<>=!~\[ ;]", s, maxsplit=1)[0].lower() for s in specs}


class Runner:
    """Runs one document's commands in order in a scratch folder."""

    def __init__(self, folder: Path, plots_for: set[str]):
        self.folder, self.plots_for, self.outputs, self.venvs = folder, plots_for, {}, []

    def __call__(self, cmd: list[str]) -> str | None:
        """None if the command ran as documented, else what went wrong."""
        prog, args = cmd[0], cmd[1:]
        if prog == "pip":
            return self.pip(args)
        if prog in ("python", "python3"):
            return self.python(args)
        if prog in (".", "source"):  # activating the virtual environment a `python3 -m venv DIR` made
            return None if args in ([f"{d}/bin/activate"] for d in self.venvs) else f"no venv made for {args}"
        if prog == "mcjax":
            return self.mcjax(args)
        return f"no check for the program {prog!r} (add one to tests/product/test_docs.py or mark the block)"

    def pip(self, args):
        if args[:1] != ["install"]:
            return "only `pip install` is checked"
        extras = set(PYPROJECT["project"]["optional-dependencies"])
        for a in args[1:]:
            if a in ("-e", "-q", "-U", "--upgrade", "."):
                continue
            m = re.fullmatch(r"\.\[([\w,-]+)\]", a)
            if m:
                missing = set(m.group(1).split(",")) - extras
                if missing:
                    return f"pyproject.toml declares no extra {sorted(missing)}"
            elif a.lower() not in _declared_packages():
                return f"{a} is not a dependency the project declares (pyproject.toml)"
        return None

    def python(self, args):
        if args[:2] == ["-m", "pytest"]:
            return None
        if args[:2] == ["-m", "venv"] and len(args) == 3:
            self.venvs.append(args[2])  # not made: the tests already run in an environment
            return None
        if args[:2] == ["-m", "mcjax.cli.doc"]:
            return None
        if args and args[0].endswith(".py"):
            script = ROOT / args[0]
            if not script.is_file():
                return f"no script {args[0]}"
            known = _argparse_options(script)
            unknown = [a.split("=")[0] for a in args[1:] if a.startswith("--") and a.split("=")[0] not in known]
            return f"{args[0]} has no option(s) {unknown}" if unknown else None
        return f"no check for python {' '.join(args)}"

    def mcjax(self, args):
        sub = args[0] if args else ""
        if sub == "report" and not {"--help", "-h"} & set(args):
            out = next(a for a in args[1:] if not a.startswith("-"))
            if out not in self.plots_for and "--no-plots" not in args:
                args = [*args, "--no-plots"]  # plots are drawn for the README's report only (time)
        if sub not in main.commands and not sub.startswith("-"):
            return f"no command `mcjax {sub}`"
        if sub and sub not in ("sweep", "run", "check", "report", "list") and not sub.startswith("-"):
            try:  # another engineer's command: its options are parsed, not run
                # under the group's context, as the command line does: a context of its own would give the
                # command the default help option (click keeps it), and docs/cli.md's -h would go stale
                root = click.Context(main, info_name="mcjax", **main.context_settings)
                main.commands[sub].make_context(sub, list(args[1:]), parent=root)
            except Exception as exc:  # noqa: BLE001 - report what click says
                return f"mcjax {' '.join(args)}: {exc}"
            return None
        r = CliRunner().invoke(main, args, catch_exceptions=True)
        self.outputs[" ".join(["mcjax", *args])] = r.output
        if r.exit_code != 0:
            return f"mcjax {' '.join(args)} exited {r.exit_code}: {r.output[-600:]}{r.exception!r}"
        return None


@pytest.fixture(scope="module")
def ran(tmp_path_factory):
    """Every document's commands, each document in its own scratch folder: {doc: (folder, runner)}."""
    mp = pytest.MonkeyPatch()
    mp.setattr(engine, "run_chunks", _fake_run_chunks)
    mp.setattr(os, "fsync", lambda fd: None)  # scratch files: durability is tests/base/test_parquet.py's business
    done = {}
    try:
        for doc in DOCS:
            cmds = doc_commands(doc)
            if not cmds:
                continue
            folder = tmp_path_factory.mktemp(doc.stem.lower())
            for name in ("configs", "sweeps", "benchmarks"):
                (folder / name).symlink_to(ROOT / name, target_is_directory=True)
            runner = Runner(folder, plots_for={"results/default"} if doc == README else set())
            problems = []
            with contextlib.chdir(folder):
                for cmd in cmds:
                    problem = runner(cmd)
                    if problem:
                        problems.append(f"{doc.relative_to(ROOT)}: `{shlex.join(cmd)}`: {problem}")
            done[doc] = (folder, runner, problems)
    finally:
        mp.undo()
    return done


@pytest.mark.xdist_group("test_docs")  # one worker builds the module fixture once
def test_every_command_in_the_readme_and_docs_runs(ran):
    problems = [p for _, _, ps in ran.values() for p in ps]
    assert not problems, "\n".join(problems)
    assert README in ran and len(ran) >= 4


@pytest.mark.xdist_group("test_docs")  # one worker builds the module fixture once
def test_readme_quick_start_writes_a_dataset_and_a_page(ran):
    folder, runner, _ = ran[README]
    assert (folder / "results" / "default" / "runs").is_dir()
    assert (folder / "results" / "default" / "report" / "index.html").is_file()
    printed = next(v for k, v in runner.outputs.items() if k.startswith("mcjax sweep sweeps/default.toml"))
    assert "1200 rows in results/default/runs" in printed
    # the summary prints numbers as the report does: 50000, not 5e+04
    assert re.search(r"^\s+50000\s+icf\s", printed, flags=re.M) and "e+04" not in printed


def _python_blocks(doc: Path) -> list[str]:
    return [text for lang, text, skip in fenced(doc) if lang == "python" and skip is None]


@pytest.mark.xdist_group("test_docs")  # one worker builds the module fixture once
@pytest.mark.parametrize("name", ["README.md", "docs/cli.md"])
def test_python_blocks_run_on_the_datasets(ran, name):
    doc = ROOT / name
    folder, _, _ = ran[doc]
    blocks = _python_blocks(doc)
    assert blocks
    for code in blocks:
        for module in re.findall(r"^import (\w+)", code, flags=re.M):
            pytest.importorskip(module)
        stdout = io.StringIO()
        with contextlib.chdir(folder), contextlib.redirect_stdout(stdout):
            exec(compile(code, name, "exec"), {})


@pytest.mark.xdist_group("test_docs")  # one worker builds the module fixture once
def test_readme_column_list_is_the_datasets_order(ran):
    folder, _, _ = ran[README]
    text = README.read_text(encoding="utf-8")
    m = re.search(r"columns, in the dataset's order: (.+?)\.\n\n", text, flags=re.S | re.I)
    assert m, "the README lists the dataset's columns"
    listed = [c.strip(" `\n") for c in m.group(1).replace("\n", " ").split(",")]
    listed = [c.split()[0].strip("`") for c in listed]
    columns = list(pd.read_parquet(folder / "results" / "default" / "runs").columns)
    assert listed == columns


def test_list_shows_a_configs_values_beside_the_defaults(tmp_path):
    cfg = tmp_path / "mine.toml"
    cfg.write_text('scenario = "leader_follower"\nseeds = 7\n\n[config]\nplanner = "cem"\n\n'
                   '[params]\ncomm_radius = 80e3\nsigma_range = 10.0\n')
    r = CliRunner().invoke(main, ["list", "leader_follower", "--config", str(cfg)])
    assert r.exit_code == 0, r.output
    lines = r.output.splitlines()

    def value_line(field: str) -> str:
        return lines[next(i for i, line in enumerate(lines) if line.startswith(f"  {field} ")
                          or line.startswith(f"  {field}:")) + 1]

    assert "seeds 7" in lines[1]
    assert value_line("comm_radius").strip().startswith("default 100000  <- mine.toml: 80000;")
    assert value_line("sigma_range").strip().startswith("default 10 (mine.toml: the same);")  # set, unchanged
    assert "<-" not in value_line("sensing_radius") and "mine.toml" not in value_line("sensing_radius")
    assert value_line("planner").strip().startswith("default 'none'  <- mine.toml: 'cem';")
    assert "<-" not in value_line("n_agents")
    # SCENARIO may be left out; a config of another scenario is a one-line error
    assert CliRunner().invoke(main, ["list", "--config", str(cfg)]).output == r.output
    bad = CliRunner().invoke(main, ["list", "uuv_imm", "--config", str(cfg)])
    assert bad.exit_code == 2 and "is a config of scenario 'leader_follower', not 'uuv_imm'" in bad.output
