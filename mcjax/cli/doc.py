"""``docs/cli.md``'s option lists, generated from the click commands' own ``--help``.

``python -m mcjax.cli.doc`` rewrites every block between ``<!-- help: mcjax CMD -->`` and
``<!-- end help -->`` in ``docs/cli.md`` with that command's current ``--help`` text (and
appends a block for a command the page does not have yet); ``python -m mcjax.cli.doc
--check`` exits 1, naming the commands, when the page is out of date.
``tests/product/test_docs.py`` runs the check, so the page cannot drift from the code.
"""

from __future__ import annotations

import re
import sys
from pathlib import Path

import click

__all__ = ["WIDTH", "commands", "help_text", "render", "stale"]

#: Terminal width the help is rendered at (so the page does not depend on the terminal).
WIDTH = 100
START = "<!-- help: {} -->"
END = "<!-- end help -->"
_BLOCK = re.compile(r"<!-- help: (mcjax[\w -]*?) -->\n```text\n(?:.*?\n)?```\n<!-- end help -->", re.S)


def commands() -> list[str]:
    """``"mcjax"`` and ``"mcjax CMD"`` for every command of the CLI, in the group's order."""
    from mcjax.cli import main

    return ["mcjax", *(f"mcjax {name}" for name in main.commands)]


def help_text(command: str) -> str:
    """The ``--help`` text of ``command`` (``"mcjax"`` or ``"mcjax CMD"``) at :data:`WIDTH`."""
    from mcjax.cli import main

    settings = {**main.context_settings, "terminal_width": WIDTH, "max_content_width": WIDTH}
    root = click.Context(main, info_name="mcjax", **settings)
    words = command.split()[1:]
    if not words:
        return main.get_help(root).rstrip()
    cmd = main.get_command(root, words[0])
    if cmd is None:
        raise ValueError(f"no command {command!r}")
    ctx = click.Context(cmd, info_name=words[0], parent=root, terminal_width=WIDTH, max_content_width=WIDTH)
    return cmd.get_help(ctx).rstrip()


def _block(command: str) -> str:
    return f"{START.format(command)}\n```text\n$ {command} --help\n{help_text(command)}\n```\n{END}"


def render(text: str) -> str:
    """``text`` (the page) with every help block current and a block added at the end for
    every command that has none."""
    known = set(commands())
    seen = set()

    def fresh(m: re.Match) -> str:
        seen.add(m.group(1))
        return _block(m.group(1)) if m.group(1) in known else m.group(0)

    out = _BLOCK.sub(fresh, text)
    missing = [c for c in commands() if c not in seen]
    if missing:
        out = out.rstrip("\n") + "\n" + "".join(f"\n## `{c}`\n\n{_block(c)}\n" for c in missing)
    return out


def stale(text: str) -> list[str]:
    """The commands whose help block in ``text`` is missing, out of date, or names a command
    that does not exist."""
    known = set(commands())
    found = {m.group(1): m.group(0) for m in _BLOCK.finditer(text)}
    bad = [c for c in commands() if c not in found or found[c] != _block(c)]
    return bad + [c for c in found if c not in known]


def main(argv: list[str] | None = None) -> int:
    args = list(sys.argv[1:] if argv is None else argv)
    check = "--check" in args
    paths = [a for a in args if a != "--check"] or [str(Path(__file__).resolve().parents[2] / "docs" / "cli.md")]
    status = 0
    for path in map(Path, paths):
        text = path.read_text(encoding="utf-8")
        if check:
            bad = stale(text)
            if bad:
                print(f"{path}: out of date for {', '.join(bad)}; run: python -m mcjax.cli.doc", file=sys.stderr)
                status = 1
        else:
            new = render(text)
            if new != text:
                path.write_text(new, encoding="utf-8")
                print(f"updated {path}")
    return status


if __name__ == "__main__":
    sys.exit(main())
