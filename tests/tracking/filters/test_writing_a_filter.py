"""Every block of docs/library.md's "Writing a filter" runs as written, from a scratch folder outside the
repository that holds the files the section shows (``my_ekf.py``, ``spy.py``, the diffusion KF's package) and
a link to the repository's ``configs/``: each Python block in its own namespace, the output each says it prints
(in a ``# …`` comment after a ``print``) found in what it printed; each ``mcjax`` command of its shell blocks
through the command line's entry point, the table the worked example quotes found in what the command printed,
and the listings it quotes in ``mcjax list filters``. The ``pip install`` line, the league and its report are
run by tests/tracking/filters/test_diffusion_kf.py, which installs the package for real."""

from __future__ import annotations

import contextlib
import importlib.metadata
import io
import re
import shlex
from pathlib import Path

import pytest
from click.testing import CliRunner

from mcjax.cli import main
from mcjax.tracking.filters import registry

ROOT = Path(__file__).resolve().parents[3]
DOCS = ROOT / "docs" / "library.md"
#: What a reader types here that tests/tracking/filters/test_diffusion_kf.py runs (the package installed).
ELSEWHERE = ("pip", "mcjax league", "mcjax report")


def _section() -> str:
    text = DOCS.read_text(encoding="utf-8")
    return text.split("\n## Writing a filter\n", 1)[1].split("\n## ", 1)[0]


def _blocks() -> list[tuple[str, str, str | None]]:
    """``(language, text, the file it is, or None)`` of every fenced block of the section, in order."""
    out, lines = [], _section().splitlines()
    i = 0
    while i < len(lines):
        m = re.match(r"^```(\w+)\s*$", lines[i])
        if m:
            j = next(k for k in range(i + 1, len(lines)) if lines[k].startswith("```"))
            prev = next((lines[k] for k in range(i - 1, -1, -1) if lines[k].strip()), "")
            named = re.fullmatch(r"`([^`]+)`:", prev.strip())
            out.append((m.group(1), "\n".join(lines[i + 1:j]) + "\n", named.group(1) if named else None))
            i = j + 1
        else:
            i += 1
    return out


BLOCKS = _blocks()
PYTHON = [text for lang, text, file in BLOCKS if lang == "python" and file is None]
SHELL = [text for lang, text, file in BLOCKS if lang == "bash"]


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    """A folder outside the repository with the section's files and the repository's configs/."""
    here = tmp_path_factory.mktemp("writing_a_filter")
    (here / "configs").symlink_to(ROOT / "configs", target_is_directory=True)
    for lang, text, file in BLOCKS:
        if file is not None:
            (here / file).parent.mkdir(parents=True, exist_ok=True)
            (here / file).write_text(text, encoding="utf-8")
    assert (here / "my_ekf.py").is_file() and (here / "spy.py").is_file()
    return here


def _words(text: str) -> str:
    return " ".join(text.split())


def expected_outputs(code: str) -> list[str]:
    """What a block says it prints: the comment after a ``print(...)``, and the comment lines right after a
    line that prints."""
    out, printing = [], False
    for line in code.splitlines():
        stripped = line.strip()
        if stripped.startswith("# ") and printing:
            out.append(stripped[2:])
            continue
        m = re.match(r".*\bprint\(.*\)\s+#\s(.+)$", line)
        if m:
            out.append(m.group(1))
        printing = "print(" in line
    return out


def _found(expected: str, printed: str) -> bool:
    """Whether every piece of ``expected`` between the elisions (``/…/``, ``…``, ``...``) is in ``printed``."""
    pieces = [p.strip() for p in re.split(r"/…/|…|\.\.\.", expected)]
    return all(_words(p) in _words(printed) for p in pieces if p)


def test_the_section_has_the_blocks_it_should():
    files = [file for _, _, file in BLOCKS if file]
    assert {"my_ekf.py", "spy.py", "diffusion_league.toml"} <= set(files), files
    assert len(PYTHON) >= 6 and len(SHELL) == 2, (len(PYTHON), len(SHELL))
    for code in PYTHON:
        assert "import" in code  # each block is whole: a reader copies one and runs it


@pytest.mark.parametrize("index", range(len(PYTHON)))
def test_every_python_block_runs_and_prints_what_it_says(folder, index):
    code = PYTHON[index]
    printed = io.StringIO()
    with contextlib.chdir(folder), contextlib.redirect_stdout(printed):
        exec(compile(code, f"docs/library.md, 'Writing a filter', Python block {index + 1}", "exec"), {})
    for expected in expected_outputs(code):
        assert _found(expected, printed.getvalue()), (expected, printed.getvalue())


def _commands(text: str) -> list[list[str]]:
    return [shlex.split(line) for line in text.splitlines() if line.strip() and not line.startswith("#")]


def _run(folder: Path, args: list[str]) -> str:
    with contextlib.chdir(folder):
        r = CliRunner().invoke(main, args)
    assert r.exit_code == 0, r.output
    return r.output


def _quoted_table() -> list[list[str]]:
    """The worked example's table as the section quotes it: each row's words, the elisions left out."""
    text = next(t for lang, t, _ in BLOCKS if lang == "text" and t.startswith("filter "))
    return [[w for w in line.split() if w != "..."] for line in text.splitlines()[1:] if line.strip()]


def _in_order(words: list[str], row: list[str]) -> bool:
    at = 0
    for w in words:
        try:
            at = row.index(w, at) + 1
        except ValueError:
            return False
    return True


def test_the_worked_example_runs_as_written_and_prints_the_table_it_quotes(folder):
    """``mcjax run configs/chen2013.toml --seeds 20 …my_ekf.py:MY_EKF`` as written: every number the section
    quotes is in the printed row of its filter, in order; my_ekf's row is local's (the same filter)."""
    (command,) = _commands(SHELL[0])
    assert command[:2] == ["mcjax", "run"] and "my_ekf.py:MY_EKF" in command[-1], command
    printed = _run(folder, command[1:])
    rows = {line.split()[0]: line.split() for line in printed.splitlines() if line.split()
            and line.split()[0] in ("kcf", "local", "my_ekf")}
    quoted = _quoted_table()
    assert [q[0] for q in quoted] == ["kcf", "local", "my_ekf"], quoted
    for q in quoted:
        assert _in_order(q, rows[q[0]]), (q, rows[q[0]])
    assert rows["my_ekf"][1:] == rows["local"][1:]
    assert "/my_ekf.py" not in printed.strip().split("\n\n")[-1]  # the table shows the record's name


def _diffusion_plugin(folder: Path, monkeypatch) -> None:
    """The section's package, as if installed: its folder on the path and its entry point declared."""
    monkeypatch.syspath_prepend(str(folder / "diffusion_kf"))
    point = importlib.metadata.EntryPoint(name="diffusion_kf", value="mcjax_diffusion_kf:DIFFUSION_KF",
                                          group=registry.ENTRY_POINT_GROUP)
    real = importlib.metadata.entry_points

    def entry_points(**kw):
        return [point] if kw.get("group") == registry.ENTRY_POINT_GROUP else real(**kw)

    monkeypatch.setattr(registry, "entry_points", entry_points)
    monkeypatch.setattr(importlib.metadata, "entry_points", entry_points)
    monkeypatch.setattr(registry, "_FOUND", dict(registry._FOUND))


def _listing(block: str) -> list[str]:
    return [line for line in block.splitlines() if line.strip()]


def test_the_plugins_commands_run_and_the_listings_quoted_are_what_list_filters_prints(folder, monkeypatch):
    _diffusion_plugin(folder, monkeypatch)
    commands = _commands(SHELL[1])
    run = [c for c in commands if not any(shlex.join(c).startswith(e) for e in ELSEWHERE)]
    assert [c[:2] for c in run] == [["mcjax", "list"], ["mcjax", "run"]], run
    listed = _run(folder, run[0][1:])
    listings = [t for lang, t, _ in BLOCKS if lang == "text" and "\n    traits: " in t]
    assert [b.split()[0] for b in listings] == ["ci", "diffusion_kf"], listings
    for block in listings:
        for line in _listing(block):
            assert _found(line, listed), (line, listed)
    printed = _run(folder, run[1][1:])
    table = printed.strip().split("\n\n")[-1]
    assert [line.split()[0] for line in table.splitlines()[1:] if line.strip()] == ["kcf", "local", "diffusion_kf"]
