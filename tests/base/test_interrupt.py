"""mcjax.base.interrupt: which processes are the mcjax command itself (they keep their Ctrl-C handling to the
end and leave without the interpreter's teardown) — the script and both ``python -m`` forms, nobody else."""

import sys

import pytest

from mcjax.base import interrupt


@pytest.mark.parametrize("argv0, own", [
    ("/usr/local/bin/mcjax", True),
    ("/site-packages/mcjax/cli/__main__.py", True),   # python -m mcjax.cli
    ("/site-packages/mcjax/__main__.py", True),       # python -m mcjax
    ("/usr/local/bin/pytest", False),
    ("/site-packages/other/cli/__main__.py", False),
    ("-c", False),
])
def test_own_process_is_the_command_in_each_of_its_forms(monkeypatch, argv0, own):
    monkeypatch.setattr(sys, "argv", [argv0])
    assert interrupt.own_process() is own
