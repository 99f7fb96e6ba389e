"""The package's shape: modules use each other's public names only, stay short, import only
from their own layer or below, and docs/architecture.md lists exactly the modules there are."""

import ast
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
PACKAGE = ROOT / "mcjax"

#: Modules allowed past MAX_LINES, with the reason (none today).
LONG_MODULES: dict[str, str] = {}
MAX_LINES = 500
#: Past ONE_CONCERN_LINES a module must hold one concern, named here (split it when a second one moves in).
ONE_CONCERN_LINES = 400
ONE_CONCERN = {
    "mcjax/base/parquet.py": "the Parquet parts of an output folder: write, list, read, check, remove",
    "mcjax/claims/spec.py": "reading and checking a claims file into its claims and sweeps",
    "mcjax/analysis/findings.py": "the sentences a sweep's intervals support (the report's 'What this shows')",
    "mcjax/study/spec.py": "reading and checking a sweep spec or a config file into a Study, every mistake named",
    "mcjax/base/validation.py": "the one validation layer: exact kinds, ranges, keys, and the lines that name a mistake",
}


def _modules() -> dict[str, Path]:
    """``{"mcjax.study.spec": path, "mcjax.study": path/__init__.py, …}``."""
    out = {}
    for path in sorted(PACKAGE.rglob("*.py")):
        parts = path.relative_to(ROOT).with_suffix("").parts
        out[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = path
    return out


def _private(name: str) -> bool:
    return name.startswith("_") and not (name.startswith("__") and name.endswith("__"))


def private_uses(modules: dict[str, Path], root: Path = ROOT) -> list[str]:
    """``path:line: what`` for every use of another mcjax module's private name: ``from X import
    _name``, ``import X as m; m._name``, ``from P import X; X._name`` (X another mcjax module)."""
    bad = []
    for me, path in modules.items():
        tree = ast.parse(path.read_text(encoding="utf-8"))
        package = me if path.name == "__init__.py" else me.rpartition(".")[0]
        aliases = {}  # local name -> the mcjax module it names
        for node in ast.walk(tree):
            if isinstance(node, ast.ImportFrom):
                source = node.module or ""
                if node.level:  # a relative import
                    base = package.split(".")[:len(package.split(".")) - node.level + 1]
                    source = ".".join(base + ([source] if source else []))
                if not source.startswith("mcjax"):
                    continue
                for a in node.names:
                    full = f"{source}.{a.name}"
                    if full in modules:
                        aliases[a.asname or a.name] = full
                    elif _private(a.name) and source != me:
                        bad.append(f"{path.relative_to(root)}:{node.lineno}: from {source} import {a.name}")
            elif isinstance(node, ast.Import):
                for a in node.names:
                    if a.name.startswith("mcjax"):
                        aliases[a.asname or a.name.split(".")[0]] = a.name if a.asname else a.name.split(".")[0]
        for node in ast.walk(tree):
            if isinstance(node, ast.Attribute) and _private(node.attr) and isinstance(node.value, ast.Name):
                target = aliases.get(node.value.id)
                if target is not None and target != me:
                    bad.append(f"{path.relative_to(root)}:{node.lineno}: {node.value.id}.{node.attr} ({target})")
    return bad


def test_no_module_uses_another_modules_private_names():
    bad = private_uses(_modules())
    assert not bad, "\n".join(bad)


def test_the_private_names_check_finds_each_form(tmp_path):
    pkg = tmp_path / "mcjax"
    (pkg / "sub").mkdir(parents=True)
    (pkg / "__init__.py").write_text("")
    (pkg / "sub" / "__init__.py").write_text("")
    (pkg / "a.py").write_text("_hidden = 1\ndef public():\n    return _hidden\n")
    (pkg / "sub" / "b.py").write_text("from mcjax.a import _hidden\n")
    (pkg / "sub" / "c.py").write_text("from mcjax import a\nx = a._hidden\ny = a.public()\n")
    (pkg / "sub" / "d.py").write_text("import mcjax.a as m\nz = m._hidden\n")
    (pkg / "sub" / "e.py").write_text("from .. import a\nw = a._hidden\n")
    (pkg / "sub" / "f.py").write_text("from mcjax import a\nv = a.__name__\nu = a.public\n")
    modules = {}
    for path in sorted(pkg.rglob("*.py")):
        parts = path.relative_to(tmp_path).with_suffix("").parts
        modules[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = path
    bad = private_uses(modules, tmp_path)
    assert sorted(line.split(":")[0] for line in bad) == ["mcjax/sub/b.py", "mcjax/sub/c.py", "mcjax/sub/d.py",
                                                          "mcjax/sub/e.py"], bad


def test_no_module_is_longer_than_the_limit():
    long = {str(p.relative_to(ROOT)): n for p in PACKAGE.rglob("*.py")
            if (n := len(p.read_text(encoding="utf-8").splitlines())) > MAX_LINES}
    assert set(long) <= set(LONG_MODULES), long


def test_a_module_past_400_lines_holds_one_named_concern():
    long = sorted(str(p.relative_to(ROOT)) for p in PACKAGE.rglob("*.py")
                  if len(p.read_text(encoding="utf-8").splitlines()) > ONE_CONCERN_LINES)
    assert set(long) <= set(ONE_CONCERN), f"name the one concern of (or split): {sorted(set(long) - set(ONE_CONCERN))}"


def _listed_modules() -> set[str]:
    """The ``mcjax/…`` paths the Layout block of docs/architecture.md names."""
    text = (ROOT / "docs" / "architecture.md").read_text(encoding="utf-8")
    block = text.split("## Layout", 1)[1].split("```")[1]
    names = set()
    for line in block.splitlines():
        first = line.split()[0] if line.split() else ""
        if first.startswith("mcjax/"):
            names.add(first)
    return names


def test_architecture_lists_every_module_and_only_modules_that_exist():
    listed = _listed_modules()
    files = {str(p.relative_to(ROOT)) for p in PACKAGE.rglob("*.py")}
    files |= {str(p.relative_to(ROOT)) for p in PACKAGE.rglob("*.cc")}
    missing = sorted(f for f in files if f not in listed and not f.endswith("__init__.py"))
    assert not missing, f"docs/architecture.md's Layout does not list: {missing}"
    gone = sorted(name for name in listed if not (ROOT / name).exists())
    assert not gone, f"docs/architecture.md's Layout lists modules that do not exist: {gone}"
    assert re.search(r"mcjax/study/", (ROOT / "docs" / "architecture.md").read_text(encoding="utf-8"))


#: The layers from the bottom, each a folder of mcjax/ (or one of the faces on top): a module imports only from
#: its own layer or lower ones. A new folder must be placed here (the test below fails until it is).
LAYERS = ["base", "contract", "analysis", "runtime", "tracking", "scenarios", "engine", "study", "tune", "claims", "league",
          "report", "notebook", "cli", "__main__"]
#: The same rule inside a layer that has rooms of its own: tracking's, from the bottom.
SUBLAYERS = {"tracking": ["numerics", "models", ("graph", "connectivity"), "metrics", "filters", "planning"]}
#: Folders whose modules import no JAX (the command line starts without it; a report needs none).
NO_JAX = ["base", "contract", "analysis", "report", "cli"]
#: What may stand on mcjax/'s top floor: the faces, and one folder per layer.
MAX_TOP_ENTRIES = 16


def _layer(module: str) -> tuple[int, int]:
    """``(layer, sublayer)`` of ``mcjax.X.Y…`` from its folders; (-1, 0) for the package itself."""
    parts = module.split(".")
    if len(parts) == 1:
        return -1, 0  # mcjax: __version__, configure
    top = parts[1]
    if top not in LAYERS:
        raise AssertionError(f"mcjax/{top} is in no layer: place it in tests/product/test_architecture.py's LAYERS")
    rooms = SUBLAYERS.get(top)
    if rooms is None or len(parts) < 3:
        return LAYERS.index(top), 0
    return LAYERS.index(top), next(i for i, r in enumerate(rooms) if parts[2] in ((r,) if isinstance(r, str) else r))


def imports(modules: dict[str, Path]) -> dict[str, set[str]]:
    """Each module's imports of other mcjax modules, at any depth of its code (lazy imports too):
    ``from P import name`` counts as an import of the module ``P.name`` where that is a module, else of ``P``."""
    edges = {m: set() for m in modules}
    for me, path in modules.items():
        package = me if path.name == "__init__.py" else me.rpartition(".")[0]
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.ImportFrom):
                source = node.module or ""
                if node.level:
                    base = package.split(".")[:len(package.split(".")) - node.level + 1]
                    source = ".".join(base + ([source] if source else []))
                for a in node.names if source.startswith("mcjax") else ():
                    target = f"{source}.{a.name}" if f"{source}.{a.name}" in modules else source
                    if target in modules and target != me:
                        edges[me].add(target)
            elif isinstance(node, ast.Import):
                edges[me] |= {a.name for a in node.names if a.name in modules and a.name != me}
    return edges


def circles(edges: dict[str, set[str]]) -> list[list[str]]:
    """The import circles: every strongly connected set of two or more modules (Tarjan's algorithm)."""
    index, low, stack, on, out = {}, {}, [], set(), []

    def visit(v):
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in sorted(edges[v]):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            group = []
            while True:
                w = stack.pop()
                on.discard(w)
                group.append(w)
                if w == v:
                    break
            if len(group) > 1:
                out.append(sorted(group))

    for v in sorted(edges):
        if v not in index:
            visit(v)
    return out


def test_every_folder_is_a_layer_and_the_top_floor_holds_only_the_faces():
    entries = sorted(p.name for p in PACKAGE.iterdir() if p.name != "__pycache__" and not p.name.endswith(".egg-info"))
    assert len(entries) <= MAX_TOP_ENTRIES, entries
    folders = {p.name for p in PACKAGE.iterdir() if p.is_dir() and p.name != "__pycache__"}
    assert folders <= set(LAYERS), sorted(folders - set(LAYERS))
    faces = {p.stem for p in PACKAGE.glob("*.py")} - {"__init__"}
    assert faces == {"__main__", "notebook"}, faces  # the contract is a folder of its own (the record + relaxation)
    rooms = {p.name if p.is_dir() else p.stem for p in (PACKAGE / "tracking").iterdir()
             if p.name not in ("__init__.py", "__pycache__")}
    listed = {r for room in SUBLAYERS["tracking"] for r in ((room,) if isinstance(room, str) else room)}
    assert rooms == listed, (sorted(rooms - listed), sorted(listed - rooms))


def test_no_module_imports_from_a_layer_above():
    modules = _modules()
    bad = [f"{me} imports {target}" for me, targets in imports(modules).items() for target in sorted(targets)
           if me != "mcjax" and _layer(target) > _layer(me)]
    assert not bad, "\n".join(bad)


def test_no_import_circle_anywhere_in_the_package():
    found = circles(imports(_modules()))
    assert not found, found


def test_the_layer_and_circle_checks_find_what_they_look_for():
    """An arrow back up and a circle inside a folder are found (the checks above can fail)."""
    assert _layer("mcjax.base.files") < _layer("mcjax.tracking.graph") < _layer("mcjax.tracking.filters.steps")
    assert _layer("mcjax.tracking.models.motion") < _layer("mcjax.tracking.graph")
    edges = {"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}, "e": set()}
    assert circles(edges) == [["a", "b", "c"]]
    modules = _modules()
    assert "mcjax.tracking.filters.steps" in imports(modules)["mcjax.scenarios.kit.sensing"]


@pytest.mark.parametrize("folder", NO_JAX)
def test_these_folders_import_no_jax(folder):
    """Importing every module of the folder loads no JAX (checked in a fresh process)."""
    import subprocess
    import sys

    names = sorted(m for m in _modules() if m == f"mcjax.{folder}" or m.startswith(f"mcjax.{folder}."))
    code = (f"import importlib, sys\nfor m in {names!r}: importlib.import_module(m)\n"
            "print(sorted(k for k in ('jax', 'jaxlib') if k in sys.modules))")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip() == "[]", (folder, r.stdout)


def test_no_scenario_filter_or_unit_names_above_the_scenarios():
    words = re.compile(r"\b(leader_follower|uuv_imm|urban_bearing|flocking|wind_formation|modified_icf|cif|icf|kcf|imm|"
                       r"lambda2_min|mean_error)\b")
    above = ["engine", "study", "analysis", "report", "claims", "cli", "base/parquet.py", "base/files.py",
             "base/interrupt.py"]
    paths = [p for name in above for p in ((PACKAGE / name).rglob("*.py") if (PACKAGE / name).is_dir()
                                            else [PACKAGE / name])]
    assert len(paths) > 15
    for path in paths:
        code = path.read_text(encoding="utf-8")
        assert not words.search(code), (path.name, words.search(code).group(0))
        assert not re.search(r"(?<![A-Za-z_])\[m\]", code), path.name


def test_the_command_line_starts_without_jax():
    """`mcjax --help`, `mcjax report` and the CLI's up-front checks import no JAX (~0.6 s), no numpy or pandas
    and no scenario: importing the CLI leaves them all out."""
    import subprocess
    import sys

    code = ("import sys, mcjax.cli; print(sorted(m for m in ('jax', 'numpy', 'pandas', 'mcjax.scenarios', 'mcjax.study')"
            " if m in sys.modules))")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip() == "[]", r.stdout
