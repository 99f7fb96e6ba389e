"""Compiled programs (mcjax.engine.compilation): loading one program on every device, JAX internals kept
in mcjax/runtime/jaxcompat.py, the one in-process cache, the program store across processes, compiler options."""

import dataclasses

import jax
import mcjax
import numpy as np
import pytest

from mcjax import engine
from mcjax.engine import compilation
from mcjax.scenarios import sun2011 as lf

from tests.engine.cases import CFG, points as _points


def test_deserialise_runs_a_program_as_compiled_with_and_without_jax_internals(monkeypatch):
    """jaxcompat.deserialise (the engine's way of loading one compiled program on every device)
    gives the compiled program's bits; with any of the JAX internals it uses taken away (as in
    a JAX that renamed them), it falls back on JAX's public deserialize_and_load (same device
    only) and still does."""
    import jax.numpy as jnp
    from jax._src import compiler
    from jax.experimental import serialize_executable

    from mcjax.runtime import jaxcompat

    assert jaxcompat.missing() == []  # the tested JAX has them all
    x = jnp.linspace(-3.0, 3.0, 7)
    compiled = jax.jit(lambda v: jnp.sin(v) * jnp.exp(v) - v**3).lower(x).compile()
    want = np.asarray(compiled(x))
    data = jaxcompat.serialise(compiled)

    def check():
        np.testing.assert_array_equal(np.asarray(jaxcompat.deserialise(data, jax.devices()[0])(x)), want)

    check()
    public, unpickler, constructor = (serialize_executable.deserialize_and_load,
                                      serialize_executable._JaxPjrtUnpickler, jax.stages.Compiled)
    used = []

    def public_stand_in(*args, **kwargs):  # the public function of a JAX whose internals differ
        used.append(1)
        with monkeypatch.context() as inner:
            inner.setattr(serialize_executable, "_JaxPjrtUnpickler", unpickler, raising=False)
            inner.setattr(jax.stages, "Compiled", constructor)
            return public(*args, **kwargs)

    monkeypatch.setattr(serialize_executable, "deserialize_and_load", public_stand_in)
    check()
    assert used == []  # the internals served
    for owner, name in ((compiler, "get_compile_options"), (serialize_executable, "_JaxPjrtUnpickler")):
        with monkeypatch.context() as m:
            m.delattr(owner, name)
            assert len(jaxcompat.missing()) == 1
            check()
    with monkeypatch.context() as m:  # a Compiled constructor of another signature

        class Other(constructor):
            def __init__(self, *args, **kwargs):
                raise TypeError("other signature")

        m.setattr(jax.stages, "Compiled", Other)
        check()
    assert len(used) == 3


def test_lapack_setup_falls_back_on_lowering_without_jaxlibs_internals(monkeypatch):
    """jaxcompat.lapack_targets (what a program loaded from the store needs set up): through
    jaxlib's internals, and without them by lowering a small program; either way it covers the
    LAPACK kernels a scenario's programs call, and a stored program calling them runs."""
    import jax.numpy as jnp
    from jaxlib import lapack

    from mcjax.runtime import jaxcompat

    def program(a):
        return jnp.linalg.cholesky(a), jnp.linalg.eigvalsh(a), jnp.linalg.solve(a, a[:, :1])

    a = jnp.array([[4.0, 1.0, 0.5], [1.0, 3.0, 0.2], [0.5, 0.2, 2.0]])
    lowered = jax.jit(program).lower(a)
    needed = jaxcompat.custom_call_targets(lowered)
    assert needed  # LAPACK kernels
    compiled = lowered.compile()
    want = [np.asarray(o) for o in compiled(a)]
    assert needed <= jaxcompat.lapack_targets()
    jaxcompat.lapack_targets.cache_clear()
    jaxcompat.lowered_targets.cache_clear()
    try:
        monkeypatch.delattr(lapack, "registrations")  # (JAX's own lowering needs _lapack.initialize)
        assert jaxcompat.missing() == ["jaxlib.lapack.registrations"]
        fallback = jaxcompat.lapack_targets()
        assert needed <= fallback and fallback == jaxcompat.lowered_targets()
        loaded = jaxcompat.deserialise(jaxcompat.serialise(compiled), jax.devices()[0])
        for got, w in zip(loaded(a), want):
            np.testing.assert_array_equal(np.asarray(got), w)
    finally:
        jaxcompat.lapack_targets.cache_clear()  # the next caller sets up through the internals again


def test_only_jaxcompat_uses_jax_internals():
    """Every use of a JAX internal is in mcjax/runtime/jaxcompat.py: no other module imports jax._src or
    a jaxlib submodule, reads a private attribute of something imported from jax or jaxlib, or
    calls the jax.stages.Compiled constructor."""
    import ast
    from pathlib import Path

    root = Path(mcjax.__file__).resolve().parent
    bad = []
    for path in sorted(root.rglob("*.py")):
        if path.name == "jaxcompat.py" and path.parent == root / "runtime":
            continue
        rel = path.relative_to(root.parent)
        tree = ast.parse(path.read_text(encoding="utf-8"))
        from_jax = set()  # names bound to jax / jaxlib modules or their members
        for node in ast.walk(tree):
            if isinstance(node, ast.Import):
                for a in node.names:
                    if a.name.startswith(("jax._src", "jaxlib.")):
                        bad.append(f"{rel}:{node.lineno} imports {a.name}")
                    if a.name.split(".")[0] in ("jax", "jaxlib"):
                        from_jax.add(a.asname or a.name.split(".")[0])
            elif isinstance(node, ast.ImportFrom) and node.module and node.module.split(".")[0] in ("jax", "jaxlib"):
                for a in node.names:
                    if node.module.startswith(("jax._src", "jaxlib.")) or a.name.startswith("_") or (
                            node.module == "jaxlib" and a.name != "__version__"):
                        bad.append(f"{rel}:{node.lineno} imports {a.name} from {node.module}")
                    from_jax.add(a.asname or a.name)
        for node in ast.walk(tree):
            if isinstance(node, ast.Attribute):
                base = node.value
                while isinstance(base, ast.Attribute):
                    base = base.value
                private = node.attr.startswith("_") and not node.attr.endswith("__")
                if isinstance(base, ast.Name) and base.id in from_jax and private:
                    bad.append(f"{rel}:{node.lineno} reads {node.attr}")
            if isinstance(node, ast.Call) and "stages.Compiled" in ast.unparse(node.func):
                bad.append(f"{rel}:{node.lineno} calls {ast.unparse(node.func)}")
    assert not bad, bad


def test_the_engines_one_cache_keeps_jitted_functions_and_programs_by_key(monkeypatch):
    """engine.cached: one bounded dict for the process (least recently used out first);
    compiled() and program_futures() keep their entries there, forget() drops them."""
    from collections import OrderedDict

    monkeypatch.setattr(compilation, "_CACHE", OrderedDict())  # this test's own
    monkeypatch.setattr(compilation, "CACHE_MAX", 3)
    fn = engine.compiled(lf.SCENARIO, CFG)
    assert engine.compiled(lf.SCENARIO, CFG, records=False, timeseries=0) is fn
    assert engine.cached(("jit", lf.SCENARIO, CFG, False, False, None), lambda: None) is fn
    made = []
    assert engine.cached(("test", 1), lambda: made.append(1) or "one") == "one"
    assert engine.cached(("test", 1), lambda: made.append(1) or "again") == "one" and made == [1]
    engine.cached(("test", 2), lambda: 2)
    engine.cached(("jit", lf.SCENARIO, CFG, False, False, None), lambda: None)  # used: now the most recent
    engine.cached(("test", 3), lambda: 3)
    assert list(compilation._CACHE) == [("test", 2), ("jit", lf.SCENARIO, CFG, False, False, None), ("test", 3)]
    engine.forget("test")
    assert list(compilation._CACHE) == [("jit", lf.SCENARIO, CFG, False, False, None)]
    engine.forget()
    assert not compilation._CACHE


def test_a_devices_program_future_falls_back_only_when_loading_gave_nothing():
    """compilation._or_else: a device's program is the loaded one, else what the fallback makes; a
    failure reaches whoever waits for the program."""
    from concurrent.futures import Future

    def settled(value=None, error=None):
        f = Future()
        f.set_exception(error) if error else f.set_result(value)
        return f

    assert compilation._or_else(settled("loaded"), lambda: "made").result() == "loaded"
    assert compilation._or_else(settled(None), lambda: "made").result() == "made"
    pending = Future()
    later = compilation._or_else(pending, lambda: "made")
    assert not later.done()
    pending.set_result(None)
    assert later.result() == "made"
    with pytest.raises(RuntimeError, match="no program"):
        compilation._or_else(settled(error=RuntimeError("no program")), lambda: "made").result()
    with pytest.raises(ValueError, match="fallback failed"):
        compilation._or_else(settled(None), lambda: (_ for _ in ()).throw(ValueError("fallback failed"))).result()


def test_a_second_process_loads_the_stored_program_and_gets_the_same_bits(tmp_path):
    """The persistent cache: the first process compiles and stores the batch program, the
    second loads it (no compilation) and computes the same numbers; a damaged file is
    compiled again, never trusted; other XLA_FLAGS compile their own program."""
    import json
    import os
    import subprocess
    import sys

    script = tmp_path / "run.py"
    script.write_text(
        "import sys, json, numpy as np\n"
        "from mcjax import engine, runtime\n"
        "from mcjax.scenarios import chen2013 as wf\n"
        "cfg = wf.Config(n_steps=15)\n"
        "out = [o for *_, o in engine.run_chunks(wf.SCENARIO, cfg, engine.stack_points([wf.default_params(cfg)]),"
        " 20, chunk_size=100)]\n"
        "np.save(sys.argv[1], out[0]['rmse'])\n"
        "print(json.dumps(runtime.STATS))\n")
    env = {**os.environ, "MCJAX_CACHE_DIR": str(tmp_path / "cache"), "MCJAX_CPU_DEVICES": "1"}

    def run(name):
        r = subprocess.run([sys.executable, str(script), str(tmp_path / name)], env=env, timeout=300,
                           capture_output=True, text=True, check=True)
        return json.loads(r.stdout.strip().splitlines()[-1]), np.load(tmp_path / name)

    first, a = run("a.npy")
    second, b = run("b.npy")
    assert first == {"loaded": 0, "stored": 1} and second == {"loaded": 1, "stored": 0}
    np.testing.assert_array_equal(a, b)
    stored = list((tmp_path / "cache" / "mcjax-programs").glob("*.pkl"))
    assert len(stored) == 1
    stored[0].write_bytes(b"garbage")
    third, c = run("c.npy")
    assert third == {"loaded": 0, "stored": 1}
    np.testing.assert_array_equal(a, c)
    # other compiler options (XLA_FLAGS; here one more flag, set to its default value so the
    # compilation stays cheap) are another program: compiled and stored beside the first
    env["XLA_FLAGS"] = f"{os.environ.get('XLA_FLAGS', '')} --xla_cpu_enable_fast_math=false"
    fourth, d = run("d.npy")
    assert fourth == {"loaded": 0, "stored": 1}
    assert len(list((tmp_path / "cache" / "mcjax-programs").glob("*.pkl"))) == 2
    np.testing.assert_allclose(a, d, rtol=1e-9)


def test_scenario_compiler_options_apply_and_unknown_ones_are_dropped():
    """A scenario's ``compiler_options`` reach its programs; an option this JAX does not know
    is dropped instead of failing every compilation. The built-in leader–follower scenario
    compiles with XLA's older CPU fusion emitters (:data:`mcjax.contract.FAST_COMPILE`): its
    records equal those of XLA's default emitters to rounding (a one-filter open loop)."""
    from mcjax.contract import FAST_COMPILE

    assert engine.compiler_options(lf.SCENARIO) == dict(FAST_COMPILE)
    odd = dataclasses.replace(lf.SCENARIO, compiler_options={"xla_no_such_option_in_mcjax": 1, **FAST_COMPILE})
    with pytest.warns(RuntimeWarning, match="does not know the XLA compiler option xla_no_such_option_in_mcjax=1"):
        assert engine.compiler_options(odd) == dict(FAST_COMPILE)
    plain = dataclasses.replace(lf.SCENARIO, compiler_options=None)
    assert engine.compiler_options(plain) is None
    cfg = dataclasses.replace(CFG, filters=("modified_icf",), n_steps=12)
    params, keys = engine.chunk_inputs(_points({}), 3, 0, 0, 3, 3)
    fn = engine.compiled(lf.SCENARIO, cfg, records=True)
    a = fn(params, keys)
    # inside a transformation of the caller's the same function runs with the caller's options:
    # here XLA's newer emitters, named (the suite's XLA_FLAGS pick the older ones for every
    # program), the program the plain scenario compiles for a user (one compilation for both
    # checks; a third, of the plain scenario's own jit, compiled the same function again)
    b = jax.jit(lambda p, k: fn(p, k), compiler_options={"xla_cpu_use_fusion_emitters": True})(params, keys)
    for name in ("error", "positions", "lambda2", "robustness"):
        x, y = np.asarray(getattr(a, name)), np.asarray(getattr(b, name))
        assert np.all(np.isfinite(x)), name
        np.testing.assert_allclose(x, y, rtol=1e-9, atol=1e-9, err_msg=name)


def test_compiler_options_given_as_a_function_of_the_config():
    """A scenario may give its options as ``cfg -> mapping``: the engine asks it with the Config
    the program is built for, and the program store's label names the options used. The
    leader–follower scenario keeps :data:`FAST_COMPILE` below ``LARGE_TEAM`` UAVs (the program
    of its golden rows) and drops XLA's YNN reduction kernels from there."""
    from mcjax.contract import FAST_COMPILE
    from mcjax.scenarios.sun2011.scenario import LARGE_TEAM

    small, large = (dataclasses.replace(CFG, n_agents=n) for n in (LARGE_TEAM - 1, LARGE_TEAM))
    assert engine.compiler_options(lf.SCENARIO, small) == dict(FAST_COMPILE)
    assert engine.compiler_options(lf.SCENARIO, large) == {**FAST_COMPILE, "xla_cpu_experimental_ynn_fusion_type": ""}
    assert engine.compiler_options(lf.SCENARIO) == dict(FAST_COMPILE)  # Config() has five UAVs
    assert "ynn" in compilation.store_label(lf.SCENARIO, large, False, False)
    assert "ynn" not in compilation.store_label(lf.SCENARIO, small, False, False)
    asked = []
    mine = dataclasses.replace(lf.SCENARIO, compiler_options=lambda cfg: asked.append(cfg) or dict(FAST_COMPILE))
    cfg = dataclasses.replace(CFG, filters=("local",), n_steps=3, warmup_steps=0)
    params, keys = engine.chunk_inputs(_points({}), 2, 0, 0, 2, 2)
    engine.compiled(mine, cfg)(params, keys)
    assert asked == [cfg]


def test_the_program_store_keeps_under_its_limit_dropping_the_least_recently_used(tmp_path, monkeypatch):
    """runtime._prune: past the limit the oldest files go (loading a program touches its time),
    never the one just stored; MCJAX_CACHE_MAX_GB sets the limit and a bad value names itself."""
    import os

    from mcjax import runtime

    from mcjax.base import envvars
    files = []
    for i in range(5):  # 5 programs of 100 bytes, used at times 1000, 2000, … (file 0 the least recent)
        f = tmp_path / f"p{i}.pkl"
        f.write_bytes(bytes(100))
        os.utime(f, (1000.0 * (i + 1), 1000.0 * (i + 1)))
        files.append(f)
    (tmp_path / "other.txt").write_bytes(bytes(1000))  # not a program: neither counted nor deleted
    runtime._prune(tmp_path, 350, keep=files[0])  # the just-stored one is kept even though oldest
    assert [f.exists() for f in files] == [True, False, False, True, True]
    assert (tmp_path / "other.txt").exists()
    runtime._prune(tmp_path, 10_000, keep=files[4])
    assert [f.exists() for f in files] == [True, False, False, True, True]
    monkeypatch.setenv("MCJAX_CACHE_MAX_GB", "0.25")
    assert envvars.cache_max_bytes() == 250_000_000
    monkeypatch.delenv("MCJAX_CACHE_MAX_GB")
    assert envvars.cache_max_bytes() == int(envvars.CACHE_MAX_GB * 1e9)
    for bad in ("0", "-1", "nan", "two"):
        monkeypatch.setenv("MCJAX_CACHE_MAX_GB", bad)
        with pytest.raises(ValueError, match="MCJAX_CACHE_MAX_GB must be a positive number of gigabytes"):
            envvars.cache_max_bytes()


def test_a_file_scenarios_second_process_loads_its_program_keyed_on_its_source(tmp_path):
    """A scenario in a user's file (docs/library.md's example) uses the program store too, keyed
    on its source: a second process loads the program (same bits), from a copy of the file in
    another folder as well; an edited file compiles and stores its own."""
    import json
    import os
    import shutil
    import subprocess
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).parents[1] / "golden"))
    try:
        from golden_cases import docs_example
    finally:
        sys.path.pop(0)
    (tmp_path / "a").mkdir()
    docs_example(tmp_path / "a")
    script = tmp_path / "run.py"
    script.write_text(
        "import sys, json, numpy as np\n"
        "from mcjax import engine, runtime, scenarios\n"
        "sc = scenarios.get(sys.argv[1] + ':SCENARIO')\n"
        "cfg = sc.Config(n_steps=15)\n"
        "out = [o for *_, o in engine.run_chunks(sc, cfg, engine.stack_points([sc.default_params(cfg)]), 20)]\n"
        "np.save(sys.argv[2], out[0]['rmse'])\n"
        "print(json.dumps(runtime.STATS))\n")
    env = {**os.environ, "MCJAX_CACHE_DIR": str(tmp_path / "cache"), "MCJAX_CPU_DEVICES": "1"}

    def run(folder, name):
        r = subprocess.run([sys.executable, str(script), str(tmp_path / folder / "static_sensors.py"),
                            str(tmp_path / name)], env=env, timeout=300, capture_output=True, text=True, check=True)
        return json.loads(r.stdout.strip().splitlines()[-1]), np.load(tmp_path / name)

    first, a = run("a", "a.npy")
    second, b = run("a", "b.npy")
    assert first == {"loaded": 0, "stored": 1} and second == {"loaded": 1, "stored": 0}
    np.testing.assert_array_equal(a, b)
    shutil.copytree(tmp_path / "a", tmp_path / "b")
    third, c = run("b", "c.npy")
    assert third == {"loaded": 1, "stored": 0}
    np.testing.assert_array_equal(a, c)
    edited = tmp_path / "b" / "static_sensors.py"
    edited.write_text(edited.read_text().replace("100.0 * jnp.eye(2)", "101.0 * jnp.eye(2)"))
    fourth, d = run("b", "d.npy")
    assert fourth == {"loaded": 0, "stored": 1}
    assert not np.array_equal(a, d)
