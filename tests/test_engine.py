"""The batch engine: chunking, keys, NaN isolation."""

import dataclasses

import jax
import numpy as np
import pytest

from mcjax import engine
from mcjax.scenarios import leader_follower as lf

# 10 steps: what these tests check (chunking, keys, NaN isolation, bit-identity) does not
# depend on the length of a run, and the 1000-run test runs 2,600 of them
CFG = lf.Config(n_steps=10, warmup_steps=5)


def _points(*overrides):
    return engine.stack_points([lf.default_params(CFG, **o) for o in overrides])


def _collect(cfg, points, n_seeds, chunk_size):
    outs = [out for _, _, _, out in engine.run_chunks(lf.SCENARIO, cfg, points, n_seeds, chunk_size=chunk_size)]
    return {k: np.concatenate([o[k] for o in outs]) for k in outs[0]}


def test_chunk_plan_covers_every_run_once():
    plan = engine.chunk_plan(1003, 100)
    covered = np.concatenate([np.arange(a, b) for a, b in plan])
    np.testing.assert_array_equal(covered, np.arange(1003))
    assert all(b - a == 100 for a, b in plan[:-1]) and plan[-1] == (1000, 1003)


@pytest.mark.xdist_group("test_engine.batch100")  # one worker compiles the 100-run program once
def test_1000_runs_bit_identical_for_chunk_sizes_100_and_1000():
    points = _points({"comm_radius": 80e3}, {"comm_radius": 100e3})  # 2 points x 500 seeds
    a = _collect(CFG, points, 500, 100)
    b = _collect(CFG, points, 500, 1000)
    assert a["rmse"].shape == (1000, len(CFG.filters))
    for key in a:
        np.testing.assert_array_equal(a[key], b[key], err_msg=key)
    # and an uneven chunk size (three batches per chunk: the devices take them in turn), on
    # its first two chunks
    outs = [out for *_, out in engine.run_chunks(lf.SCENARIO, CFG, points, 500, chunk_size=300, chunks=[0, 1])]
    for key in a:
        np.testing.assert_array_equal(a[key][:600], np.concatenate([o[key] for o in outs]), err_msg=key)


@pytest.mark.xdist_group("test_engine.records")  # one worker compiles the 6-run records program once
@pytest.mark.parametrize("base_seed", [0, 1, 2**31 - 1, 2**32 - 1, 2**32, 2**40 + 5, -1, -2**63, 2**63 - 1])
def test_numpy_run_keys_are_jax_keys(base_seed):
    """The engine's numpy Threefry gives JAX's own PRNGKey/fold_in keys, bit for bit (seed
    indices from 0 up, random 32-bit ones and the largest), also for base seeds past 32 bits."""
    idx = np.concatenate([np.arange(40), np.random.default_rng(3).integers(0, 2**32, 100), [2**32 - 1]]).astype(np.uint32)
    want = np.stack([np.asarray(jax.random.fold_in(jax.random.PRNGKey(base_seed), int(i))) for i in idx[::7]])
    got = engine.run_keys(base_seed, idx)
    assert got.dtype == np.uint32 and got.shape == (len(idx), 2)
    np.testing.assert_array_equal(got[::7], want)
    np.testing.assert_array_equal(got, np.asarray(jax.vmap(lambda s: engine.run_key(base_seed, s))(idx)))


def test_common_random_numbers_across_points():
    """Seed s draws the same target and the same measurement noise at every point: with a comm
    radius that changes nothing for the CIF (it ignores the graph), the target path, the
    measurements and the CIF's errors are the same at both points, while the graph-based
    modified ICF differs. (The CIF is compared to 1e-12: XLA may round a lane of a batch
    differently from another in the last bit; runs keep their lanes whatever the chunk size.)"""
    fn = engine.compiled(lf.SCENARIO, CFG, records=True)
    rec = fn(*engine.chunk_inputs(_points({"comm_radius": 60e3}, {"comm_radius": 100e3}), 3, 0, 0, 6, 6))
    for name in ("target", "positions", "measurements"):
        a = np.asarray(getattr(rec, name))
        np.testing.assert_array_equal(a[:3], a[3:], err_msg=name)
    err = np.asarray(rec.error)
    cif, mod = CFG.filters.index("cif"), CFG.filters.index("modified_icf")
    np.testing.assert_allclose(err[:3, :, cif], err[3:, :, cif], rtol=1e-12, atol=1e-9)
    assert not np.allclose(err[:3, :, mod], err[3:, :, mod])
    assert len({float(err[s, -1, cif, 0]) for s in range(3)}) == 3  # different seeds differ


@pytest.mark.xdist_group("test_engine.batch100")
def test_nan_in_one_run_is_flagged_and_isolated():
    good = lf.default_params(CFG)
    bad = lf.default_params(CFG, p0_diag=[np.nan, 100.0, 1e4, 100.0])
    # 2 points x 50 seeds: the 100-run program the chunk-size test compiles too
    clean = _collect(CFG, engine.stack_points([good, good]), 50, 100)
    mixed = _collect(CFG, engine.stack_points([good, bad]), 50, 100)
    assert mixed["nonfinite"][50:].all() and mixed["diverged"][50:].all()
    assert not clean["nonfinite"].any()
    for key in clean:
        np.testing.assert_array_equal(clean[key][:50], mixed[key][:50], err_msg=key)


@pytest.mark.xdist_group("test_engine.records")
def test_records_can_be_kept():
    fn = engine.compiled(lf.SCENARIO, CFG, records=True)
    params, keys = engine.chunk_inputs(_points({}), 6, 0, 0, 6, 6)  # the CRN test's program
    rec = fn(params, keys)
    assert rec.error.shape == (6, CFG.n_steps, len(CFG.filters), CFG.n_agents)
    assert rec.lambda2.shape == (6, CFG.n_steps)


def test_float32_config_runs():
    cfg = dataclasses.replace(CFG, dtype="float32", filters=("modified_icf",))
    out = _collect(cfg, _points({}), 4, 4)
    assert out["rmse"].dtype == np.float32
    assert np.isfinite(out["rmse"]).all()


@pytest.mark.parametrize("emitters", [True, False], ids=["fusion-emitters", "older-emitters"])
def test_nan_aware_max_and_min_keep_a_nan_in_a_large_batch(emitters):
    """XLA's CPU min/max over (100, 300) can drop a NaN; mcjax.metrics.nan_max / nan_min
    must not, since max_error and min_distance are how a blow-up shows in a summary. With both
    of XLA's CPU code generators (the suite's flags pick the older one; users get the newer one
    for a scenario without compiler options)."""
    import jax
    import jax.numpy as jnp

    from mcjax.metrics import nan_max, nan_min

    x = np.ones((100, 300))
    x[-1, 5] = np.nan
    opts = {"xla_cpu_use_fusion_emitters": emitters}
    got_max = np.asarray(jax.jit(jax.vmap(nan_max), compiler_options=opts)(jnp.asarray(x)))
    got_min = np.asarray(jax.jit(jax.vmap(nan_min), compiler_options=opts)(jnp.asarray(x)))
    assert np.isnan(got_max[-1]) and np.isnan(got_min[-1])
    np.testing.assert_array_equal(got_max[:-1], 1.0)
    np.testing.assert_array_equal(got_min[:-1], 1.0)


def test_results_do_not_depend_on_the_device_count(tmp_path):
    """The same sweep on 3 CPU devices (a subprocess: the count is fixed when JAX starts) and on
    one (chunks of one batch use one device) gives the same bits; the subprocess really has 3.
    There the program is compiled once and loaded on the other two devices; and again with that
    loading failing (as with a JAX that refuses it), when each device compiles its own."""
    import os
    import subprocess
    import sys

    from mcjax.scenarios import wind_formation as wf

    cfg = wf.Config(n_steps=20)
    points = engine.stack_points([wf.default_params(cfg), wf.default_params(cfg, comm_radius=2500.0)])
    one = [o for *_, o in engine.run_chunks(wf.SCENARIO, cfg, points, 150, chunk_size=100)]
    one = {k: np.concatenate([o[k] for o in one]) for k in one[0]}
    script = tmp_path / "three.py"
    script.write_text(
        "import sys, numpy as np\n"
        "from mcjax import engine, jaxcompat, runtime\n"
        "from mcjax.scenarios import wind_formation as wf\n"
        "assert runtime.settings()['cpu_devices'] == 3, runtime.settings()\n"
        "cfg = wf.Config(n_steps=20)\n"
        "pts = engine.stack_points([wf.default_params(cfg), wf.default_params(cfg, comm_radius=2500.0)])\n"
        "def run(name):\n"
        "    out = [o for *_, o in engine.run_chunks(wf.SCENARIO, cfg, pts, 150, chunk_size=1000)]\n"
        "    np.savez(sys.argv[1] + name, **{k: np.concatenate([o[k] for o in out]) for k in out[0]})\n"
        "run('three.npz')\n"
        "def refuse(*args):\n"
        "    raise RuntimeError('no')\n"
        "jaxcompat.deserialise = refuse\n"
        "engine.forget('programs')\n"
        "run('fallback.npz')\n")
    env = {**os.environ, "MCJAX_CPU_DEVICES": "3", "MCJAX_CACHE_DIR": "off"}  # compiled here, not loaded
    subprocess.run([sys.executable, str(script), str(tmp_path) + "/"], check=True, env=env, timeout=300)
    for name in ("three.npz", "fallback.npz"):
        three = np.load(tmp_path / name)
        assert set(three.files) == set(one)
        for key in one:
            np.testing.assert_array_equal(one[key], three[key], err_msg=f"{name}: {key}")


def test_deserialise_runs_a_program_as_compiled_with_and_without_jax_internals(monkeypatch):
    """jaxcompat.deserialise (the engine's way of loading one compiled program on every device)
    gives the compiled program's bits; with any of the JAX internals it uses taken away (as in
    a JAX that renamed them), it falls back on JAX's public deserialize_and_load (same device
    only) and still does."""
    import jax.numpy as jnp
    from jax._src import compiler
    from jax.experimental import serialize_executable

    from mcjax import jaxcompat

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

    from mcjax import jaxcompat

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
    """Every use of a JAX internal is in mcjax/jaxcompat.py: no other module imports jax._src or
    a jaxlib submodule, reads a private attribute of something imported from jax or jaxlib, or
    calls the jax.stages.Compiled constructor."""
    import ast
    from pathlib import Path

    root = Path(engine.__file__).resolve().parent
    bad = []
    for path in sorted(root.rglob("*.py")):
        if path.name == "jaxcompat.py" and path.parent == root:
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

    monkeypatch.setattr(engine, "_CACHE", OrderedDict())  # this test's own
    monkeypatch.setattr(engine, "CACHE_MAX", 3)
    fn = engine.compiled(lf.SCENARIO, CFG)
    assert engine.compiled(lf.SCENARIO, CFG, records=False, timeseries=0) is fn
    assert engine.cached(("jit", lf.SCENARIO, CFG, False, False, None), lambda: None) is fn
    made = []
    assert engine.cached(("test", 1), lambda: made.append(1) or "one") == "one"
    assert engine.cached(("test", 1), lambda: made.append(1) or "again") == "one" and made == [1]
    engine.cached(("test", 2), lambda: 2)
    engine.cached(("jit", lf.SCENARIO, CFG, False, False, None), lambda: None)  # used: now the most recent
    engine.cached(("test", 3), lambda: 3)
    assert list(engine._CACHE) == [("test", 2), ("jit", lf.SCENARIO, CFG, False, False, None), ("test", 3)]
    engine.forget("test")
    assert list(engine._CACHE) == [("jit", lf.SCENARIO, CFG, False, False, None)]
    engine.forget()
    assert not engine._CACHE


def test_a_devices_program_future_falls_back_only_when_loading_gave_nothing():
    """engine._or_else: a device's program is the loaded one, else what the fallback makes; a
    failure reaches whoever waits for the program."""
    from concurrent.futures import Future

    def settled(value=None, error=None):
        f = Future()
        f.set_exception(error) if error else f.set_result(value)
        return f

    assert engine._or_else(settled("loaded"), lambda: "made").result() == "loaded"
    assert engine._or_else(settled(None), lambda: "made").result() == "made"
    pending = Future()
    later = engine._or_else(pending, lambda: "made")
    assert not later.done()
    pending.set_result(None)
    assert later.result() == "made"
    with pytest.raises(RuntimeError, match="no program"):
        engine._or_else(settled(error=RuntimeError("no program")), lambda: "made").result()
    with pytest.raises(ValueError, match="fallback failed"):
        engine._or_else(settled(None), lambda: (_ for _ in ()).throw(ValueError("fallback failed"))).result()


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
        "from mcjax.scenarios import wind_formation as wf\n"
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


def test_the_program_store_keeps_under_its_limit_dropping_the_least_recently_used(tmp_path, monkeypatch):
    """runtime._prune: past the limit the oldest files go (loading a program touches its time),
    never the one just stored; MCJAX_CACHE_MAX_GB sets the limit and a bad value names itself."""
    import os

    from mcjax import envvars, runtime

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

    sys.path.insert(0, str(Path(__file__).parent / "golden"))
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
