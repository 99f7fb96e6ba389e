"""mcjax.tracking.filters against an independent numpy implementation and against invariants."""


import numpy as np
import pytest

from mcjax.tracking.filters import run_filter

from benchmarks.peers import numpy_peer  # plain-numpy filters written from the equations

KM = 1e3


def _data(seed=0, T=40, comm_radius=100 * KM, sensing_radius=120 * KM):
    rng = np.random.default_rng(seed)
    positions = np.array([[20, 150], [80, 150], [130, 200], [130, 100], [180, 150]]) * KM
    z, s, a, truth = numpy_peer.simulate_open_loop_numpy(
        rng, T, positions, np.zeros(5), 800.0, np.array([200 * KM, 200.0, 180 * KM, -1000.0]),
        1.0, 50.0, 10.0, 0.017, sensing_radius, comm_radius)
    F, Q = numpy_peer.cv_matrices(1.0, 50.0)
    common = dict(measurements=z, sensor_positions=s, adjacency=a, x0=truth[0],
                  P0=np.diag([1e4, 1e2, 1e4, 1e2]), F=F, Q=Q, R=np.diag([10.0**2, 0.017**2]))
    return common, truth


def _peer(kind, common, **kw):
    c = dict(common)
    return numpy_peer.run_filter_numpy(kind, c.pop("measurements"), c.pop("sensor_positions"),
                                       c.pop("adjacency"), c["x0"], c["P0"], c["F"], c["Q"], c["R"], **kw)


@pytest.mark.parametrize("kind", ["cif", "local", "modified_icf", "icf", "kcf"])
def test_matches_numpy_reference(kind):
    common, _ = _data(seed=1)
    x, P = run_filter(kind, **common)
    xr, Pr = _peer(kind, common)
    assert np.all(np.isfinite(x))
    np.testing.assert_allclose(x, xr, rtol=1e-8, atol=1e-6)
    np.testing.assert_allclose(P, Pr, rtol=1e-7, atol=1e-8)


@pytest.mark.parametrize("options, kinds", [
    (dict(weights="metropolis", consensus_steps=3), ("modified_icf", "icf", "kcf")),
    (dict(weights="max_degree", contribution="one", consensus_steps=2), ("modified_icf", "icf", "kcf")),
    (dict(icf_variant="priors", weights="metropolis"), ("icf",)),  # the option of the ICF alone
    (dict(kcf_gain="mu_P", kcf_epsilon=0.05), ("kcf",)),           # the options of the KCF alone
])
def test_options_match_numpy_reference(options, kinds):
    common, _ = _data(seed=2, T=25)
    rng = np.random.default_rng(0)  # a random, changing, sometimes disconnected graph
    upper = np.triu(rng.random(common["adjacency"].shape) < 0.4, 1)
    common["adjacency"] = (upper | np.swapaxes(upper, 1, 2)).astype(float)
    peer_kw = {k: v for k, v in options.items()}
    for kind in kinds:
        x, _ = run_filter(kind, **common, **options)
        xr, _ = _peer(kind, common, **peer_kw)
        np.testing.assert_allclose(x, xr, rtol=1e-8, atol=1e-6, err_msg=f"{kind} {options}")


def test_cif_is_the_bound_on_average():
    """CIF (all measurements) is more accurate than every agent's local EKF on average."""
    errs = {"cif": [], "local": []}
    for seed in range(4):
        common, truth = _data(seed=10 + seed, T=60)
        for kind in errs:
            x, _ = run_filter(kind, **common)
            e = np.hypot(x[..., 0] - truth[:, None, 0], x[..., 2] - truth[:, None, 2])
            errs[kind].append(e[10:].mean())
    assert np.mean(errs["cif"]) < np.mean(errs["local"])


@pytest.mark.parametrize("steps, weights", [(1, "eq11"), (1, "metropolis"), (1, "max_degree"), (25, "metropolis")])
def test_complete_graph_converges_to_cif(weights, steps):
    common, _ = _data(seed=3, T=30)
    n = common["adjacency"].shape[1]
    common["adjacency"] = np.broadcast_to(1.0 - np.eye(n), common["adjacency"].shape).copy()
    x_cif, P_cif = run_filter("cif", **common)
    for kind in ("modified_icf", "icf"):
        x, P = run_filter(kind, **common, consensus_steps=steps, weights=weights)
        np.testing.assert_allclose(x, x_cif, rtol=1e-9, atol=1e-6, err_msg=kind)
        np.testing.assert_allclose(P, P_cif, rtol=1e-8, atol=1e-9, err_msg=kind)


def test_consensus_approaches_cif_as_steps_grow_on_a_path_graph():
    """On a connected but sparse graph the gap to the CIF shrinks as L grows."""
    common, _ = _data(seed=4, T=30)
    n = common["adjacency"].shape[1]
    path = np.zeros((n, n))
    for i in range(n - 1):
        path[i, i + 1] = path[i + 1, i] = 1
    common["adjacency"] = np.broadcast_to(path, common["adjacency"].shape).copy()
    x_cif, _ = run_filter("cif", **common)
    gaps = [np.abs(run_filter("modified_icf", **common, consensus_steps=L, weights="metropolis")[0]
                   - x_cif)[5:, :, [0, 2]].max() for L in (1, 5, 60)]
    assert gaps[0] > gaps[1] > gaps[2]
    assert gaps[2] < 1e-3 * gaps[0]


def test_empty_graph_equals_local():
    common, _ = _data(seed=5, T=30)
    common["adjacency"] = np.zeros_like(common["adjacency"])
    x_loc, P_loc = run_filter("local", **common)
    for kind, kw in [("modified_icf", {}), ("icf", {}), ("icf", {"icf_variant": "priors"}), ("kcf", {})]:
        x, P = run_filter(kind, **common, consensus_steps=4, **kw)
        # Different but equivalent algebra (e.g. x̄ recovered from Ȳ⁻¹ȳ): round-off only.
        np.testing.assert_allclose(x, x_loc, rtol=1e-10, atol=1e-5, err_msg=kind)
        np.testing.assert_allclose(P, P_loc, rtol=1e-8, atol=1e-5, err_msg=kind)


def test_batch_axis_matches_single_runs():
    c1, _ = _data(seed=6, T=20)
    c2, _ = _data(seed=7, T=20)
    batched = {k: np.stack([c1[k], c2[k]]) for k in ("measurements", "sensor_positions", "adjacency")}
    rest = {k: v for k, v in c1.items() if k not in batched}
    xb, _ = run_filter("modified_icf", **batched, **rest)
    x2, _ = run_filter("modified_icf", **{**c2, **rest})
    np.testing.assert_allclose(xb[1], x2, rtol=1e-10, atol=1e-6)  # last-bit: XLA code differs by batch size


@pytest.mark.parametrize("kind", ["local", "modified_icf"])
def test_batched_kernel_matches_the_general_path(kind, monkeypatch):
    """The structure-of-arrays kernels (mcjax/tracking/filters/batched.py) against the one-run filters
    (steps.filter_step) vmapped over runs: same equations, different algebra and layout.
    Sparse graph and missed measurements; outputs of the documented shape, read-only."""
    from mcjax.tracking.filters import recorded

    batch, rest = _sparse_batch()
    assert np.isnan(batch["measurements"]).any() and 0 < batch["adjacency"].mean() < 0.8
    monkeypatch.setattr(recorded, "USE_NATIVE", False)
    x, P = run_filter(kind, **batch, **rest, consensus_steps=2)
    assert x.shape == (3, 25, 5, 4) and P.shape == (3, 25, 5, 4, 4)
    assert not x.flags.writeable and not P.flags.writeable
    monkeypatch.setattr(recorded, "BATCHED_KERNELS", {})
    xg, Pg = run_filter(kind, **batch, **rest, consensus_steps=2)
    # round-off of two algebras over 25 steps: measured 4.5e-10 … 1.19e-9 (x) and 1.1e-11 … 5.8e-11
    # (P) under XLA's defaults, its older CPU emitters, the suite's flags and both together (the
    # modified ICF's x: 1.11e-9 with XLA's defaults), so x's bound is 5e-9, not 1e-9
    scale = np.abs(xg).reshape(-1, 4).max(axis=0)
    assert np.max(np.abs(x - xg) / scale) < 5e-9
    d = np.sqrt(np.diagonal(Pg, axis1=-2, axis2=-1).reshape(-1, 4).max(axis=0))
    assert np.max(np.abs(P - Pg) / np.outer(d, d)) < 1e-9
    np.testing.assert_array_equal(P, np.swapaxes(P, -1, -2))


def test_a_filter_of_ones_own_runs_on_recorded_data_through_its_record(tmp_path):
    """run_filter takes any filter the registry resolves: a file's copy of the local EKF (a record of the public
    contract, not the built-in, so it runs its step under vmap) gives the built-in's results, which come from
    the hand-written batched kernels — chosen by the record, not by a name."""
    path = tmp_path / "my_local.py"
    path.write_text("from mcjax.contract.filter import Filter, Traits\n"
                    "from mcjax.tracking.filters.consensus import local_step\n"
                    "MINE = Filter('my_local', 'my local EKF', 'ours', lambda m, post, meas: local_step(\n"
                    "    m.h, m.angle_mask, post, meas, m.F, m.Q), Traits(late_messages=True, messages=False))\n")
    from mcjax.tracking.filters import recorded

    batch, rest = _sparse_batch()
    assert recorded.batched_kernel("local") == "local" and recorded.batched_kernel(f"{path}:MINE") is None
    x, P = run_filter("local", **batch, **rest)
    xm, Pm = run_filter(f"{path}:MINE", **batch, **rest)
    scale = np.abs(x).reshape(-1, 4).max(axis=0)
    assert np.max(np.abs(xm - x) / scale) < 5e-9  # two algebras: the bound of the test above
    d = np.sqrt(np.diagonal(P, axis1=-2, axis2=-1).reshape(-1, 4).max(axis=0))
    assert np.max(np.abs(Pm - P) / np.outer(d, d)) < 1e-9


def _sparse_batch(T=25):
    runs = [_data(seed=s, T=T, comm_radius=60 * KM, sensing_radius=90 * KM)[0] for s in (11, 12, 13)]
    batch = {k: np.stack([c[k] for c in runs]) for k in ("measurements", "sensor_positions", "adjacency")}
    return batch, {k: v for k, v in runs[0].items() if k not in batch}


@pytest.mark.parametrize("kind, options", [
    ("local", {}),
    ("modified_icf", {}),
    ("modified_icf", {"consensus_steps": 3, "weights": "metropolis"}),
    ("modified_icf", {"consensus_steps": 0, "weights": "max_degree", "contribution": "one"}),
    ("modified_icf", {"consensus_steps": 2, "weights": "max_degree"}),
])
def test_native_kernels_match_the_pure_jax_kernels(kind, options, monkeypatch):
    """The C++ kernels (mcjax/tracking/filters/native_kernels.cc, through XLA's FFI) against the pure-JAX
    structure-of-arrays kernels they transcribe: same equations, round-off only. C-ordered,
    every B (the runs are split over threads: each run's numbers must not depend on it)."""
    from mcjax.tracking.filters import native, recorded

    if not native.available():
        pytest.skip(f"native kernels not built: {native.STATUS['reason']}")
    batch, rest = _sparse_batch()
    x, P = run_filter(kind, **batch, **rest, **options)
    assert x.flags.c_contiguous and P.flags.c_contiguous
    x1, P1 = run_filter(kind, **{k: v[1] for k, v in batch.items()}, **rest, **options)
    np.testing.assert_array_equal(x1, x[1])
    np.testing.assert_array_equal(P1, P[1])
    # 19 runs: several blocks of the kernels' 8 vector lanes, split over the threads, the last
    # block partial — every copy of a run gives the same bits as the 3-run batch
    xb, Pb = run_filter(kind, **{k: v[np.arange(19) % 3] for k, v in batch.items()}, **rest, **options)
    np.testing.assert_array_equal(xb, x[np.arange(19) % 3])
    np.testing.assert_array_equal(Pb, P[np.arange(19) % 3])
    monkeypatch.setattr(recorded, "USE_NATIVE", False)
    xj, Pj = run_filter(kind, **batch, **rest, **options)
    # 1e-8: on this sparse, often unmeasured data the information form's inverse round trips
    # lose digits; the pure-JAX kernel and the general (vmap) path differ by up to 9e-10 here
    # as well (on the benchmark's data: 1e-11, tests/peers/test_filter_peers.py)
    assert np.max(np.abs(x - xj) / np.abs(xj).reshape(-1, 4).max(axis=0)) < 1e-8
    d = np.sqrt(np.diagonal(Pj, axis1=-2, axis2=-1).reshape(-1, 4).max(axis=0))
    assert np.max(np.abs(P - Pj) / np.outer(d, d)) < 1e-8


def test_more_agents_than_the_native_kernel_holds_run_in_jax(monkeypatch):
    from mcjax.tracking.filters import native

    monkeypatch.setattr(native, "MAX_AGENTS", 4)  # the 5-agent team is then "too large"
    batch, rest = _sparse_batch(T=6)
    x, P = run_filter("modified_icf", **batch, **rest)
    assert not x.flags.c_contiguous  # the pure-JAX kernel's batch-last view
    xr, Pr = _peer("modified_icf", {**rest, **{k: v[0] for k, v in batch.items()}})
    np.testing.assert_allclose(x[0], xr, rtol=1e-8, atol=1e-6)
    np.testing.assert_allclose(P[0], Pr, rtol=1e-7, atol=1e-8)


def test_native_kernels_can_be_turned_off(monkeypatch):
    from mcjax.tracking.filters import native

    monkeypatch.setenv("MCJAX_NATIVE", "off")
    native.available.cache_clear()
    try:
        assert native.available() is False and native.STATUS["reason"] == "MCJAX_NATIVE=off"
        monkeypatch.setenv("MCJAX_NATIVE", "of")
        native.available.cache_clear()
        with pytest.raises(ValueError, match=r"^MCJAX_NATIVE must be 'on' or 'off'; got 'of'$"):
            native.available()
    finally:
        native.available.cache_clear()


def test_float32_tracks_float64():
    common, truth = _data(seed=8, T=40)
    x64, _ = run_filter("cif", **common)
    x32, _ = run_filter("cif", **common, dtype="float32")
    assert x32.dtype == np.float32
    # float32 holds ~7 digits of 2e5 m coordinates: agreement to a few metres is expected.
    assert np.max(np.abs(x32 - x64)[..., [0, 2]]) < 5.0


@pytest.mark.parametrize("change, match", [
    (dict(kind="ukf"), "kind: filter must be one of .*; got 'ukf'"),
    (dict(measurements=np.zeros((5, 3, 3))), "measurements must have shape"),
    (dict(sensor_positions=np.zeros((5, 3, 3))), r"sensor_positions must have shape \(5, 3, 2\)"),
    (dict(adjacency=np.zeros((5, 3, 2))), r"adjacency must have shape \(5, 3, 3\)"),
    (dict(x0=np.zeros(3)), r"x0 must have shape \(4,\)"),
    (dict(P0=-np.eye(4)), "P0 must be a positive definite"),
    (dict(R=np.diag([1.0, -1.0])), "R must be a positive definite"),
    (dict(Q=-np.eye(4)), "Q must be a positive semi-definite"),
    (dict(consensus_steps=-1), "consensus_steps must be an integer"),
    (dict(dtype="float16"), "dtype must be"),
    (dict(weights="uniform"), "weights must be one of"),
    (dict(adjacency=np.ones((5, 3, 3))), "zero diagonal"),
    (dict(adjacency=np.full((5, 3, 3), 0.5) * (1 - np.eye(3))), "adjacency must contain only 0 and 1"),
    (dict(adjacency=np.triu(np.ones((5, 3, 3)), 1)), r"adjacency must be symmetric"),
    (dict(sensor_positions=np.where(np.arange(2) == 1, np.nan, np.zeros((5, 3, 2)))), "sensor_positions must be finite"),
    (dict(kind="local", adjacency=np.triu(np.ones((2, 5, 3, 3)), 1), measurements=np.full((2, 5, 3, 2), np.nan),
          sensor_positions=np.zeros((2, 5, 3, 2))), r"adjacency must be symmetric"),
    (dict(adjacency=np.where(np.eye(3) == 0, np.nan, 0.0) * np.ones((5, 1, 1))), "adjacency must contain only 0 and 1"),
    (dict(adjacency=np.triu(np.full((5, 3, 3), 2.0), 1)), "adjacency must contain only 0 and 1"),  # and asymmetric
])
@pytest.mark.parametrize("native_checks", [True, False], ids=["native-checks", "numpy-checks"])
def test_bad_input_names_the_argument(change, match, native_checks, monkeypatch):
    from mcjax.tracking.filters import recorded
    monkeypatch.setattr(recorded, "USE_NATIVE", native_checks)
    args = dict(kind="cif", measurements=np.full((5, 3, 2), np.nan), sensor_positions=np.zeros((5, 3, 2)),
                adjacency=np.zeros((5, 3, 3)), x0=np.zeros(4), P0=np.eye(4), F=np.eye(4),
                Q=np.zeros((4, 4)), R=np.eye(2))
    args.update(change)
    kind = args.pop("kind")
    with pytest.raises(ValueError, match=match):
        run_filter(kind, **args)


def test_native_adjacency_check_finds_each_defect():
    """The one-pass native check of the adjacency (mcjax/tracking/filters/native_kernels.cc) on valid
    graphs and on each kind of defect, n = 1 … 9: the expected verdict, and numpy's 0/1 bytes."""
    from mcjax.tracking.filters import native
    if not native.available():
        pytest.skip(f"native kernels not built: {native.STATUS['reason']}")
    rng = np.random.default_rng(3)
    for n in (1, 2, 5, 9):
        upper = np.triu(rng.random((40, n, n)) < 0.5, 1)
        valid = (upper | np.swapaxes(upper, -1, -2)).astype(np.float64)
        valid[3] = np.where(valid[3] == 0, -0.0, 1.0)  # -0.0 is a zero
        cases = {"valid": (valid, 0)}
        if n > 1:
            asym = valid.copy()
            asym[7, 0, 1] = 1.0 - asym[7, 0, 1]
            cases["asymmetric"] = (asym, 2)
        diag = valid.copy()
        diag[11, n - 1, n - 1] = 1.0
        cases["diagonal"] = (diag, 4)
        value = valid.copy()
        value[19, 0, 0] = np.nan
        half = valid.copy()
        half[23, n - 1, 0] = 0.5
        for a in (value, half):  # a wrong value is reported (the other bits do not matter then)
            assert native.adjacency_bytes(a)[1] & 1
        for name, (a, expected) in cases.items():
            a8, bad = native.adjacency_bytes(a)
            assert bad == expected, (n, name, bad)
            np.testing.assert_array_equal(a8, a.astype(np.uint8))


@pytest.mark.parametrize("flags", [[], ["-DMCJAX_LIBMVEC", "-mavx2", "-mno-avx512f"], ["-DMCJAX_LIBMVEC", "-mavx512f"]],
                         ids=["scalar-atan2", "libmvec-avx2", "libmvec-avx512"])
def test_native_source_compiles_in_each_atan2_variant(flags):
    """The kernels' three atan2 paths (the machine builds only one of them): each compiles."""
    import platform
    import subprocess

    import jax
    from mcjax.tracking.filters import native

    cxx = native._compiler()
    if cxx is None or (flags and platform.machine() not in ("x86_64", "AMD64")):
        pytest.skip("needs a C++ compiler (and x86-64 for the libmvec variants)")
    done = subprocess.run([cxx, "-fsyntax-only", "-std=c++17", "-O1", f"-I{jax.ffi.include_dir()}", *flags,
                           str(native.SOURCE)], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]


@pytest.mark.parametrize("kind", ["local", "modified_icf"])
def test_native_kernels_keep_the_guards_of_range_bearing(kind, monkeypatch):
    """A sensor exactly on the estimate (zero range: H's rows are zero, no update from it), one
    next to it, and a measurement with one NaN component (missing): the native kernels give what
    the pure-JAX kernels give."""
    from mcjax.tracking.filters import native, recorded

    if not native.available():
        pytest.skip(f"native kernels not built: {native.STATUS['reason']}")
    T, n = 3, 2
    x0 = np.array([1000.0, 1.0, 2000.0, -1.0])
    z = np.full((T, n, 2), [500.0, 0.3])
    z[2, 0, 1] = np.nan
    s = np.zeros((T, n, 2))
    s[0, 0] = x0[[0, 2]]
    s[1, 1] = [1001.0, 1998.0]
    a = np.zeros((T, n, n))
    a[:, 0, 1] = a[:, 1, 0] = 1
    F = np.eye(4)
    F[0, 1] = F[2, 3] = 1.0
    args = dict(measurements=z, sensor_positions=s, adjacency=a, x0=x0, P0=100 * np.eye(4), F=F,
                Q=0.1 * np.eye(4), R=np.diag([25.0, 1e-4]))
    xn, Pn = run_filter(kind, **args)
    monkeypatch.setattr(recorded, "USE_NATIVE", False)
    xj, Pj = run_filter(kind, **args)
    np.testing.assert_allclose(xn, xj, rtol=1e-12, atol=1e-9)
    np.testing.assert_allclose(Pn, Pj, rtol=1e-12, atol=1e-9)
    if kind == "local":
        np.testing.assert_array_equal(xn[0, 0], x0)  # the sensor on the prior: no update


def test_range_bearing_linearisation_matches_the_sensor_model():
    """The batch-last kernels' range–bearing (mcjax/tracking/filters/batched.py: written on separate
    arrays, H's velocity columns left out as structural zeros) against the generic path,
    ``jax.jvp`` of mcjax.tracking.models.sensors.range_bearing: the same h and H to round-off, and the
    same guards where a target sits on its sensor (range 0, bearing 0, finite zero H)."""
    import jax.numpy as jnp

    from mcjax.tracking.filters import batched
    from mcjax.tracking.models.sensors import range_bearing

    rng = np.random.default_rng(5)
    x = [jnp.asarray(rng.normal(0, 1e5, (3, 7))) for _ in range(4)]
    sensor = [jnp.asarray(rng.normal(0, 1e5, (3, 7))) for _ in range(2)]
    x[0], x[2] = x[0].at[0, :2].set(sensor[0][0, :2]), x[2].at[0, :2].set(sensor[1][0, :2])
    h1, H1 = batched.linearise_range_bearing(tuple(x), tuple(sensor))
    h2, H2 = batched.linearise(range_bearing, tuple(x), tuple(sensor))
    for a in range(2):
        np.testing.assert_allclose(h1[a], h2[a], rtol=1e-14, atol=1e-18)
        for k in range(4):
            if H1[a][k] is None:
                assert k in (1, 3) and np.all(np.asarray(H2[a][k]) == 0)
            else:
                np.testing.assert_allclose(H1[a][k], H2[a][k], rtol=1e-13, atol=1e-18)
                assert np.all(np.asarray(H1[a][k])[0, :2] == 0)
    assert np.all(np.asarray(h1[0])[0, :2] == 0) and np.all(np.asarray(h1[1])[0, :2] == 0)


@pytest.mark.parametrize("steps", [0, 2])
def test_materialising_the_information_pair_changes_no_number(steps):
    """The modified ICF's kernel writes the weighted information pair to memory before the
    consensus (batched.materialise: a division by a traced 1.0, so XLA does not recompute it in
    every agent's mix). The same update without it gives the same numbers."""
    import jax
    import jax.numpy as jnp

    from mcjax.tracking.filters import batched
    from mcjax.tracking.filters.consensus import FilterOptions
    from mcjax.tracking.models.sensors import range_bearing

    batch, rest = _sparse_batch(T=3)
    B, n = 3, 5
    z = jnp.moveaxis(jnp.asarray(batch["measurements"][:, 2]), 0, -1)  # (n, 2, B)
    s = jnp.moveaxis(jnp.asarray(batch["sensor_positions"][:, 2]), 0, -1)
    a = jnp.moveaxis(jnp.asarray(batch["adjacency"][:, 2]), 0, -1)
    rng = np.random.default_rng(2)
    xb = tuple(jnp.asarray(rest["x0"][k] + rng.normal(0, 100.0, (n, B))) for k in range(4))
    Pb = tuple(jnp.full((n, B), rest["P0"][i, j] * (1.5 if i == j else 1.0)) for i, j in batched.UPPER)
    R_inv = jnp.asarray(np.linalg.inv(rest["R"]))
    opts = FilterOptions(steps, "eq11", "component", "contributions", "gamma_M")

    @jax.jit
    def both(xb, Pb, one):
        args = (range_bearing, (False, True), opts, xb, Pb, tuple(z[:, m] for m in range(2)),
                tuple(s[:, m] for m in range(2)), a, R_inv)
        return batched.modified_icf_update(*args, one), batched.modified_icf_update(*args)

    kept, plain = both(xb, Pb, jnp.asarray(1.0))
    assert np.isnan(np.asarray(z)).any()  # missed measurements among the agents
    for u, v in zip(jax.tree.leaves(kept), jax.tree.leaves(plain)):
        np.testing.assert_array_equal(np.asarray(u), np.asarray(v))
