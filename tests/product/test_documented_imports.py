"""Every import of mcjax that README.md and docs/*.md show works: a reader who copies one gets the module.

The imports are taken from fenced code blocks (Python blocks, and ``python -c "..."`` in shell
blocks), from ``>>>`` console lines, and from inline code spans that are an import (the README's
``import mcjax.notebook as mc; …``) or a ``python -c`` command. Those of ``mcjax`` and of the
repository's ``benchmarks`` package run together in one fresh Python process, from the repository's
root, each on its own so that every failure is named by file and line. An import of a module the
docs' own examples define (docs/library.md's example files) is skipped by name
(:data:`DOC_EXAMPLE_MODULES`); any other import of something neither mcjax nor installed fails.
"""

from __future__ import annotations

import ast
import importlib.util
import json
import os
import re
import shlex
import subprocess
import sys
from pathlib import Path
from typing import NamedTuple

ROOT = Path(__file__).resolve().parents[2]
DOCS = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]

#: Our own packages, whose documented imports are run.
OURS = ("mcjax", "benchmarks")
#: Modules that only the docs' own examples define (files a reader writes next to a config), with the
#: example file that defines each: imports of these are skipped, by name.
DOC_EXAMPLE_MODULES = {
    "static_sensors": "docs/library.md",
    "faulty_sensors": "docs/library.md",
    "my_package": "docs/library.md",
}
#: Fewer imports than this found means the extraction broke, not that the docs have none.
MIN_IMPORTS = 10

FENCE = re.compile(r"^\s*```(\w*)")
INLINE = re.compile(r"`([^`\n]+)`")
PYTHON_C = re.compile(r"\bpython3?\s+-c\s")


class Import(NamedTuple):
    where: str      # "docs/library.md:18"
    statement: str  # "from mcjax.tracking.filters import run_filter"
    module: str     # "mcjax.tracking.filters" (for an ``import a.b as c``: "a.b")


def _statements(code: str) -> list[ast.stmt]:
    """The import statements of a piece of code: parsed whole, or else line by line and ``;`` part by
    part (a snippet with ``...`` or a shell line around it)."""
    try:
        tree = ast.parse(code)
        return [n for n in ast.walk(tree) if isinstance(n, (ast.Import, ast.ImportFrom))]
    except SyntaxError:
        pass
    out = []
    for line in code.splitlines():
        for part in line.split(";"):
            part = part.strip()
            if not part.startswith(("import ", "from ")):
                continue
            try:
                node = ast.parse(part).body[0]
            except SyntaxError:
                continue
            if isinstance(node, (ast.Import, ast.ImportFrom)):
                out.append(node)
    return out


def _python_c(text: str) -> list[str]:
    """The code of each ``python -c CODE`` in a shell line."""
    out = []
    for line in text.replace("\\\n", " ").splitlines():
        if not PYTHON_C.search(line):
            continue
        try:
            words = shlex.split(line, comments=True)
        except ValueError:
            continue
        out += [words[i + 1] for i, w in enumerate(words[:-1]) if w == "-c" and i and "python" in words[i - 1]]
    return out


def _imports(code: str, where: str) -> list[Import]:
    found = []
    for node in _statements(code):
        if isinstance(node, ast.ImportFrom):
            if node.level:
                continue
            found.append(Import(where, ast.unparse(node), node.module or ""))
        else:
            for alias in node.names:
                one = ast.Import(names=[alias])
                found.append(Import(where, ast.unparse(one), alias.name))
    return found


def documented_imports(paths=DOCS, root: Path = ROOT) -> list[Import]:
    """Every import statement the docs show, in order, with where it is (paths relative to ``root``)."""
    found: list[Import] = []
    for path in paths:
        name = path.relative_to(root).as_posix()
        lines = path.read_text(encoding="utf-8").splitlines()
        i = 0
        while i < len(lines):
            m = FENCE.match(lines[i])
            if m:
                lang = m.group(1).lower()
                j = next((k for k in range(i + 1, len(lines)) if lines[k].lstrip().startswith("```")), len(lines))
                body = lines[i + 1:j]
                if lang in ("python", "py", "pycon", ""):
                    for k, line in enumerate(body):  # line by line, so each import is named by its line
                        code = line.strip()[4:] if line.strip().startswith(">>> ") else line
                        found += _imports(code.strip(), f"{name}:{i + 2 + k}")
                if lang in ("bash", "sh", "shell", "console", ""):
                    for k, line in enumerate(body):
                        for code in _python_c(line):
                            found += _imports(code, f"{name}:{i + 2 + k}")
                i = j + 1
                continue
            line = lines[i]
            if line.lstrip().startswith(">>> "):
                found += _imports(line.lstrip()[4:], f"{name}:{i + 1}")
            for span in INLINE.findall(line):
                span = span.strip()
                if span.startswith(("import ", "from ")):
                    found += _imports(span, f"{name}:{i + 1}")
                elif PYTHON_C.search(span):
                    for code in _python_c(span):
                        found += _imports(code, f"{name}:{i + 1}")
            i += 1
    return found


def _top(module: str) -> str:
    return module.split(".", 1)[0]


def test_the_extraction_finds_each_form(tmp_path):
    doc = tmp_path / "x.md"
    doc.write_text(
        "Inline `import mcjax.notebook as mc; res = mc.sweep(...)` and `python -c \"from mcjax import a; a.b()\"`.\n"
        "```python\nimport numpy as np\nfrom mcjax.tracking.filters import run_filter\n```\n"
        "```bash\npython -c \"import mcjax.cli; print(1)\"\nmcjax sweep x.toml\n```\n"
        "    >>> from mcjax.base import parquet\n"
        "```toml\nimport = 'not python'\n```\n", encoding="utf-8")
    got = [(w.split(":")[1], s) for w, s, _ in documented_imports([doc], tmp_path)]
    assert got == [("1", "import mcjax.notebook as mc"), ("1", "from mcjax import a"), ("3", "import numpy as np"),
                   ("4", "from mcjax.tracking.filters import run_filter"), ("7", "import mcjax.cli"),
                   ("10", "from mcjax.base import parquet")], got


def test_every_documented_import_works():
    found = documented_imports()
    ours = [imp for imp in found if _top(imp.module) in OURS]
    assert len(ours) > MIN_IMPORTS, f"only {len(ours)} imports of mcjax found in the docs: {ours}"
    assert {imp.where.split(":")[0] for imp in ours} >= {"README.md", "docs/library.md"}, ours

    # the docs' own example modules are skipped by name; anything else not ours must at least be installed
    others = [imp for imp in found if _top(imp.module) not in OURS and _top(imp.module) not in DOC_EXAMPLE_MODULES]
    unknown = [f"{imp.where}: {imp.statement}" for imp in others if importlib.util.find_spec(_top(imp.module)) is None]
    assert not unknown, ("the docs import modules that are neither mcjax, nor installed, nor a docs example "
                         "(DOC_EXAMPLE_MODULES):\n" + "\n".join(unknown))
    code = ("import json, sys, traceback\nfailed = []\n"
            f"for where, statement in {[(imp.where, imp.statement) for imp in ours]!r}:\n"
            "    try:\n        exec(statement, {})\n"
            "    except BaseException as e:\n"
            "        failed.append(f'{where}: {statement}  ->  {type(e).__name__}: {e}')\n"
            "print(json.dumps(failed))\nsys.exit(1 if failed else 0)\n")
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH")]))}
    r = subprocess.run([sys.executable, "-c", code], cwd=ROOT, env=env, capture_output=True, text=True, timeout=300)
    lines = r.stdout.strip().splitlines()
    failed = json.loads(lines[-1]) if lines else [r.stderr[-2000:]]
    assert r.returncode == 0 and not failed, "documented imports that fail:\n" + "\n".join(failed)


def test_the_docs_example_modules_are_still_in_the_docs():
    """Each skipped name is a file one of the docs writes out (so the skip list cannot go stale)."""
    for module, doc in DOC_EXAMPLE_MODULES.items():
        text = (ROOT / doc).read_text(encoding="utf-8")
        assert f"{module}.py" in text or f"{module}." in text, (module, doc)
