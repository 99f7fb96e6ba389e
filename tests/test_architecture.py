"""The package's shape: modules use each other's public names only, stay short, import only
from their own layer or below, and docs/architecture.md lists exactly the modules there are."""

import ast
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "mcjax"

#: Modules allowed past MAX_LINES, with the reason (none today).
LONG_MODULES: dict[str, str] = {}
MAX_LINES = 500


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


#: Layers from the bottom: a module may import its own layer or lower ones only.
LAYERS = [
    {"validation", "units", "contract", "smoothing", "envvars", "files", "interrupt", "jaxcompat", "runtime", "numerics", "results",
     "peers"},
    {"models"},
    {"graph", "robustness"},
    {"metrics"},
    {"filters"},
    {"planning"},
    {"scenarios"},
    {"engine", "statistics", "verdicts"},
    {"study", "tables", "schema", "quality", "plots", "listing"},
    {"tune", "claims"},
    {"report", "html_report", "findings", "glossary", "tune_report", "notebook"},
    {"cli", "cli_executor", "clidoc", "__main__", "progress"},
]


def _layer(module: str) -> int:
    top = module.split(".")[1] if module.startswith("mcjax.") else module
    if not (PACKAGE / top).is_dir() and not (PACKAGE / f"{top}.py").is_file():
        return -1  # a name of the package itself: mcjax.__version__, mcjax.configure
    return next(i for i, names in enumerate(LAYERS) if top in names)


def test_no_module_imports_from_a_layer_above():
    bad = []
    for path in sorted(PACKAGE.rglob("*.py")):
        rel = path.relative_to(ROOT).with_suffix("")
        parts = rel.parts if rel.name != "__init__" else rel.parts[:-1]
        if len(parts) == 1:
            continue  # mcjax/__init__.py
        me = _layer(".".join(parts))
        for node in ast.walk(ast.parse(path.read_text())):
            names = []
            if isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("mcjax"):
                names = [node.module] if node.module != "mcjax" else [f"mcjax.{a.name}" for a in node.names]
            elif isinstance(node, ast.Import):
                names = [a.name for a in node.names if a.name.startswith("mcjax.")]
            for name in names:
                if name.count(".") >= 1 and _layer(name) > me:
                    bad.append(f"{rel} imports {name}")
    assert not bad, bad


def test_no_scenario_filter_or_unit_names_above_the_scenarios():
    words = re.compile(r"\b(leader_follower|uuv_imm|modified_icf|cif|icf|kcf|imm|lambda2_min|mean_error)\b")
    above = ["engine", "results.py", "report.py", "html_report.py", "tables.py", "statistics.py", "cli.py",
             "listing.py", "files.py", "interrupt.py", "study", "plots", "findings.py", "tune_report.py", "schema.py", "glossary.py",
             "verdicts.py", "claims"]
    paths = [p for name in above for p in ((PACKAGE / name).rglob("*.py") if (PACKAGE / name).is_dir()
                                            else [PACKAGE / name])]
    assert len(paths) > 15
    for path in paths:
        code = path.read_text(encoding="utf-8")
        assert not words.search(code), (path.name, words.search(code).group(0))
        assert not re.search(r"(?<![A-Za-z_])\[m\]", code), path.name


def test_the_command_line_starts_without_jax():
    """`mcjax --help`, `mcjax report` and the CLI's up-front checks import no JAX (~0.6 s) and no
    scenario: importing the CLI module leaves both out."""
    import subprocess
    import sys

    code = "import sys, mcjax.cli; print(sorted(m for m in ('jax', 'mcjax.scenarios', 'mcjax.study') if m in sys.modules))"
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip() == "[]", r.stdout
