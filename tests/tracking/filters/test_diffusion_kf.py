"""The ATC diffusion Kalman filter of Cattivelli & Sayed 2010 (IEEE TAC 55(9)), the complete example of
docs/library.md's "Writing a filter", shipped as the plugin package in benchmarks/plugins/diffusion_kf/: the docs'
files are the shipped ones byte for byte, written only through mcjax's public names; the filter against a numpy
reference written from the paper's equations, on a complete graph (one estimate for all, the centralised
filter's), with no links (the local EKF); and, built from the docs' blocks alone and installed for real as a
package, listed and run in a league of the three scenarios that take any filter, its rows carrying every output
the built-ins' rows carry."""

import ast
import difflib
import importlib
import importlib.util
import json
import os
import re
import subprocess
import sys
import tomllib
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import tomli_w

import mcjax

mcjax.configure()

import jax
import jax.numpy as jnp

from mcjax.contract.filter import Model
from mcjax.tracking.filters.consensus import CIF, LOCAL, FilterOptions, Measurements
from mcjax.tracking.filters.gaussian import Gaussian
from mcjax.tracking.models.sensors import range_bearing

ROOT = Path(__file__).resolve().parents[3]
PLUGIN = ROOT / "benchmarks" / "plugins" / "diffusion_kf"
DOCS = ROOT / "docs" / "library.md"
sys.path.insert(0, str(PLUGIN))
from mcjax_diffusion_kf import DIFFUSION_KF

sys.path.remove(str(PLUGIN))

ANGLE = jnp.array([False, True])
D = 4  # [x, ẋ, y, ẏ]


# --------------------------------------------------------------------------- a random lossy run


def _cv(dt=1.0, q=0.05):
    F = np.eye(D)
    F[0, 1] = F[2, 3] = dt
    block = q * np.array([[dt**3 / 3, dt**2 / 2], [dt**2 / 2, dt]])
    Q = np.zeros((D, D))
    Q[:2, :2] = Q[2:, 2:] = block
    return F, Q


def _run_data(n, steps, seed, link_p=0.4, miss_p=0.25, graph="random"):
    """A target on a CV path, sensors wandering around it, range–bearing measurements (NaN for some agents),
    a new symmetric graph each step (``"random"``: each link with probability ``link_p``; ``"complete"``;
    ``"empty"``)."""
    rng = np.random.default_rng(seed)
    F, Q = _cv()
    truth = np.array([0.0, 1.0, 0.0, 0.5])
    Fs, Qs, Z, S, A, Rinv = [], [], [], [], [], []
    sig = np.stack([rng.uniform(0.5, 2.0, n), rng.uniform(0.01, 0.05, n)], -1)
    for t in range(steps):
        if t > 0:
            truth = F @ truth + rng.multivariate_normal(np.zeros(D), Q)
        Fs.append(np.eye(D) if t == 0 else F)
        Qs.append(np.zeros((D, D)) if t == 0 else Q)
        sensors = truth[[0, 2]] + rng.uniform(-40.0, 40.0, (n, 2))
        z = np.array([_h(truth, s) for s in sensors]) + sig * rng.standard_normal((n, 2))
        z[:, 1] = _wrap(z[:, 1])
        z[rng.random(n) < miss_p] = np.nan
        if graph == "random":
            upper = np.triu(rng.random((n, n)) < link_p, 1)
            adj = (upper | upper.T).astype(float)
        else:
            adj = np.ones((n, n)) - np.eye(n) if graph == "complete" else np.zeros((n, n))
        Z.append(z)
        S.append(sensors)
        A.append(adj)
        Rinv.append(np.stack([np.diag(1.0 / s**2) for s in sig]))
    x0 = np.array([3.0, 0.5, -2.0, 0.0])
    P0 = np.diag([25.0, 4.0, 25.0, 4.0])
    return {"x0": x0, "P0": P0, "F": np.array(Fs), "Q": np.array(Qs), "z": np.array(Z), "sensors": np.array(S),
            "adjacency": np.array(A), "R_inv": np.array(Rinv)}


def _run_filter(f, data, options=None, centralised=False):
    """The filter ``f``'s step, jitted once, scanned over the run; its posteriors (steps, n, ·)."""
    n = data["z"].shape[1]
    options = FilterOptions() if options is None else options
    x0, P0 = jnp.asarray(data["x0"]), jnp.asarray(data["P0"])
    post = Gaussian(x0, P0, jnp.linalg.inv(P0))
    if not centralised:
        post = jax.tree.map(lambda a: jnp.broadcast_to(a, (n,) + a.shape), post)

    @jax.jit
    def run(post, seq):
        def body(post, s):
            F, Q, z, sensors, adj, R_inv = s
            new = f.step(Model(range_bearing, ANGLE, F, Q, options), post, Measurements(z, sensors, adj, R_inv))
            return new, new

        return jax.lax.scan(body, post, seq)[1]

    seq = tuple(jnp.asarray(data[k]) for k in ("F", "Q", "z", "sensors", "adjacency", "R_inv"))
    return jax.tree.map(np.asarray, run(post, seq))


# --------------------------------------------------------------------------- the reference, from the paper


def _wrap(a):
    return (np.asarray(a) + np.pi) % (2 * np.pi) - np.pi


def _h(x, s):
    """Range–bearing of the target position p = (x[0], x[2]) from a sensor at s."""
    dx, dy = x[0] - s[0], x[2] - s[1]
    return np.array([np.hypot(dx, dy), np.arctan2(dy, dx)])


def _H(x, s):
    """∂h/∂x by hand."""
    dx, dy = x[0] - s[0], x[2] - s[1]
    r2 = dx * dx + dy * dy
    r = np.sqrt(r2)
    return np.array([[dx / r, 0.0, dy / r, 0.0], [-dy / r2, 0.0, dx / r2, 0.0]])


def _combination_weights(adj, kind):
    """c_{l,k} as a matrix C[k, l] (row k sums to one over N_k ∪ {k})."""
    n = adj.shape[0]
    deg = adj.sum(1)
    C = np.zeros((n, n))
    for k in range(n):
        for l in range(n):
            if l != k and adj[k, l]:
                C[k, l] = 1 / (1 + deg[k]) if kind == "eq11" else 1 / (1 + max(deg[k], deg[l]))
        C[k, k] = 1 / (1 + deg[k]) if kind == "eq11" else 1 - C[k].sum()
    return C


def _reference(data, kind):
    """Cattivelli & Sayed 2010's ATC diffusion KF, EKF form, in plain numpy loops over nodes and neighbours."""
    n = data["z"].shape[1]
    x = [data["x0"].copy() for _ in range(n)]
    P = [data["P0"].copy() for _ in range(n)]
    xs, Ps = [], []
    eye = np.eye(D)
    for t in range(data["z"].shape[0]):
        F, Q, z, s, adj, Rinv = (data[k][t] for k in ("F", "Q", "z", "sensors", "adjacency", "R_inv"))
        psi, P_new = [], []
        for k in range(n):
            xb = F @ x[k]                                    # time update
            Pb = F @ P[k] @ F.T + Q
            info = np.linalg.solve(Pb, eye)                  # P̄_k⁻¹
            vec = info @ xb                                  # P̄_k⁻¹ x̄_k
            for l in range(n):                               # incremental update over N_k ∪ {k}
                if (l == k or adj[k, l]) and np.all(np.isfinite(z[l])):
                    H = _H(xb, s[l])                         # linearised at node k's own prediction
                    nu = z[l] - _h(xb, s[l])
                    nu[1] = _wrap(nu[1])
                    info = info + H.T @ Rinv[l] @ H
                    vec = vec + H.T @ Rinv[l] @ (nu + H @ xb)
            P_new.append(np.linalg.solve(info, eye))
            psi.append(np.linalg.solve(info, vec))
        C = _combination_weights(adj, kind)
        x = [sum(C[k, l] * psi[l] for l in range(n) if l == k or adj[k, l]) for k in range(n)]  # combine
        P = P_new
        xs.append(np.array(x))
        Ps.append(np.array(P))
    return np.array(xs), np.array(Ps)


def _rel(a, b):
    """Largest |a − b| over each step's agents, relative to the largest |b| of that step."""
    axes = tuple(range(1, a.ndim))
    return float(np.max(np.max(np.abs(a - b), axis=axes) / np.max(np.abs(b), axis=axes)))


# --------------------------------------------------------------------------- tests


@pytest.mark.parametrize("weights, exchange", [("eq11", "dense"), ("metropolis", "dense"),
                                               ("metropolis", "sparse")])
def test_it_is_the_papers_filter_over_a_changing_lossy_graph(weights, exchange):
    """200 steps of a random symmetric graph, some agents without a measurement: the plugin's step (jitted,
    scanned) against the numpy reference written from the paper's equations."""
    data = _run_data(n=6, steps=200, seed=7)
    options = FilterOptions(weights=weights, exchange=exchange, max_neighbours=5)
    got = _run_filter(DIFFUSION_KF, data, options)
    x_ref, P_ref = _reference(data, weights)
    assert np.all(np.isfinite(got.x)) and np.all(np.isfinite(got.P))
    rel_x, rel_P = _rel(got.x, x_ref), _rel(got.P, P_ref)
    print(f"diffusion_kf vs numpy reference ({weights}, {exchange}): max rel x {rel_x:.2e}, P {rel_P:.2e}")
    assert rel_x <= 1e-9 and rel_P <= 1e-9
    np.testing.assert_allclose(got.Y, np.linalg.inv(got.P), rtol=1e-8, atol=1e-10)
    # the run is one of diffusion: agents' estimates differ (the graph is not complete), and the fusion helps
    assert np.ptp(got.x[-1], axis=0).max() > 0


def test_on_a_complete_graph_with_uniform_weights_every_agent_holds_the_centralised_estimate():
    """Max-degree weights on a complete graph are 1/n everywhere (Chen & Lu 2013 eq. 7: a_ij/n and
    1 − (n−1)/n): every node pools every measurement and combines equal ψ's — all agents hold one estimate,
    the centralised information filter's."""
    data = _run_data(n=5, steps=40, seed=3, graph="complete")
    got = _run_filter(DIFFUSION_KF, data, FilterOptions(weights="max_degree"))
    for a in (got.x, got.P):
        assert _rel(a, np.broadcast_to(a[:, :1], a.shape)) <= 1e-12
    cif = _run_filter(CIF, data, centralised=True)
    assert _rel(got.x, np.broadcast_to(cif.x[:, None], got.x.shape)) <= 1e-9
    assert _rel(got.P, np.broadcast_to(cif.P[:, None], got.P.shape)) <= 1e-9


def test_with_no_links_it_is_the_local_ekf():
    data = _run_data(n=5, steps=60, seed=11, graph="empty")
    got = _run_filter(DIFFUSION_KF, data)
    local = _run_filter(LOCAL, data)
    assert _rel(got.x, local.x) <= 1e-12 and _rel(got.P, local.P) <= 1e-12


def test_the_record_and_its_traits():
    assert DIFFUSION_KF.name == "diffusion_kf" and "Cattivelli & Sayed 2010" in DIFFUSION_KF.reference
    t = DIFFUSION_KF.traits
    assert (t.centralised, t.late_messages, t.messages, t.weights, t.consensus_only) == (False, False, True, "any",
                                                                                          False)



# --------------------------------------------------------------------------- the docs' example is the plugin

#: The package's files, as docs/library.md's "Writing a filter" shows them (paths inside the package's folder).
PACKAGE_FILES = ("pyproject.toml", "mcjax_diffusion_kf/__init__.py", "mcjax_diffusion_kf/diffusion.py")


def _docs_section() -> str:
    text = DOCS.read_text(encoding="utf-8")
    return text.split("\n## Writing a filter\n", 1)[1].split("\n## ", 1)[0]


def docs_package() -> dict[str, str]:
    """The diffusion KF package of docs/library.md's "Writing a filter": each block preceded by its path line
    ```diffusion_kf/PATH`:``, as ``{PATH: the block's text}``."""
    found = re.findall(r"^`diffusion_kf/([^`\n]+)`:\n```\w+\n(.*?)^```$", _docs_section(), re.M | re.S)
    files = dict(found)
    assert len(files) == len(found), [p for p, _ in found]
    return files


def docs_league() -> str:
    """The league file ``diffusion_league.toml`` of docs/library.md's "Writing a filter"."""
    m = re.search(r"^`diffusion_league\.toml`:\n```toml\n(.*?)^```$", _docs_section(), re.M | re.S)
    assert m, "docs/library.md shows diffusion_league.toml"
    return m.group(1)


def _shipped_sources() -> set[str]:
    """The plugin folder's source files (.py, .toml), build output and caches left out."""
    out = set()
    for p in PLUGIN.rglob("*"):
        parts = p.relative_to(PLUGIN).parts
        if p.is_file() and p.suffix in (".py", ".toml") and not any(
                part in ("build", "__pycache__") or part.endswith(".egg-info") for part in parts):
            out.add("/".join(parts))
    return out


def test_the_docs_complete_example_is_the_shipped_plugin_byte_for_byte():
    """Every file of the package the docs show is the shipped plugin's file, byte for byte, and the plugin has
    no source file the docs do not show: the shipped plugin is the docs' example."""
    files = docs_package()
    assert tuple(files) == PACKAGE_FILES, list(files)
    assert _shipped_sources() == set(PACKAGE_FILES), _shipped_sources()
    for path, body in files.items():
        shipped = (PLUGIN / path).read_bytes()
        if shipped != body.encode("utf-8"):
            diff = "\n".join(difflib.unified_diff(shipped.decode("utf-8").splitlines(), body.splitlines(),
                                                  f"benchmarks/plugins/diffusion_kf/{path}", "docs/library.md",
                                                  lineterm=""))
            pytest.fail(f"docs/library.md's diffusion_kf/{path} differs from the shipped file:\n{diff}")


def test_the_docs_module_uses_only_mcjax_public_names_and_jax():
    """The docs' package imports mcjax's filter contract, other public mcjax names (no module or name with a
    leading underscore) and JAX, and its own modules — nothing else; it reaches into no private attribute. Each
    mcjax name it imports exists. Its pyproject.toml registers the record under the group ``mcjax.filters``."""
    files = docs_package()
    own = {Path(p).stem for p in files if p.startswith("mcjax_diffusion_kf/")}
    contract = set()
    for path, body in files.items():
        if not path.endswith(".py"):
            continue
        for node in ast.walk(ast.parse(body, path)):
            if isinstance(node, ast.Attribute):
                assert not (node.attr.startswith("_") and not node.attr.endswith("__")), (path, node.attr)
            if isinstance(node, ast.ImportFrom) and node.level:
                assert node.level == 1 and (node.module or "").split(".")[0] in own, (path, ast.unparse(node))
                continue
            if isinstance(node, ast.ImportFrom):
                modules, names = [node.module], [a.name for a in node.names]
            elif isinstance(node, ast.Import):
                modules, names = [a.name for a in node.names], []
            else:
                continue
            for module in modules:
                top = module.split(".")[0]
                assert top in ("__future__", "jax", "mcjax"), (path, ast.unparse(node))
                if top != "mcjax":
                    continue
                assert not any(part.startswith("_") for part in module.split(".")), (path, module)
                assert names and not any(n.startswith("_") or n == "*" for n in names), (path, ast.unparse(node))
                loaded = importlib.import_module(module)
                assert all(hasattr(loaded, n) for n in names), (path, ast.unparse(node))
                if module.startswith("mcjax.contract"):
                    contract |= set(names)
    assert {"Filter", "Traits"} <= contract, contract
    pyproject = tomllib.loads(files["pyproject.toml"])
    assert pyproject["project"]["entry-points"]["mcjax.filters"] == {"diffusion_kf": "mcjax_diffusion_kf:DIFFUSION_KF"}
    assert "mcjax" in pyproject["project"]["dependencies"]


# --------------------------------------------------------------------------- built from the docs, installed


def _offline_build_missing() -> str:
    """Why pip cannot build a wheel here without the network, or "" if it can: setuptools builds it, with
    its own bdist_wheel from setuptools 70.1 on, with the ``wheel`` package's before."""
    if importlib.util.find_spec("setuptools") is None:
        return "setuptools is not installed"
    import setuptools

    version = tuple(int(p) for p in setuptools.__version__.split(".")[:2] if p.isdigit())
    if version < (70, 1) and importlib.util.find_spec("wheel") is None:
        return (f"setuptools {setuptools.__version__} has no bdist_wheel of its own (from 70.1) and the 'wheel' "
                "package is not installed")
    return ""


SCENARIOS = ("leader_follower", "flocking", "wind_formation")
BUILT_INS = ("kcf", "local")
SEEDS = 3


def _tiny_league(folder: Path) -> Path:
    """docs/library.md's league file made tiny (10 steps, a flock of 6, no timing pass), its configs the
    repository's: everything else — filters, scenarios, fault points, outputs switched on — as the docs say."""
    league = tomllib.loads(docs_league())
    assert league["filters"] == [*BUILT_INS, "diffusion_kf"] and tuple(league["scenarios"]) == SCENARIOS, league
    league["timing_runs"] = 0
    for entry in league["scenarios"].values():
        entry["base"] = str(ROOT / entry["base"])
        entry.setdefault("config", {}).update(n_steps=10, warmup_steps=2)
    league["scenarios"]["flocking"]["config"]["n_agents"] = 6
    league["scenarios"]["flocking"].setdefault("params", {})["n_sensing"] = 3
    path = folder / "diffusion_league.toml"
    path.write_text(tomli_w.dumps(league), encoding="utf-8")
    return path


#: Run in one subprocess with only the installed plugin (and mcjax) on the path: the commands, as a user types
#: them, through the command line's entry point; what each printed and its exit code.
DRIVER = r'''
import json, sys
from click.testing import CliRunner
from mcjax.cli import main
done = {}
for args in json.loads(sys.argv[1]):
    r = CliRunner().invoke(main, args)
    done[args[0]] = {"exit_code": r.exit_code, "output": r.output, "exception": repr(r.exception)}
print("REPORT " + json.dumps(done))
'''


def _carried(rows: pd.DataFrame) -> set:
    """The columns every one of ``rows`` has a value in."""
    return {c for c in rows.columns if rows[c].notna().all()}


def test_built_from_the_docs_alone_it_installs_is_listed_and_runs_in_a_league_of_the_three_scenarios(tmp_path):
    """The package written from docs/library.md's blocks alone (not the repository's folder), pip-installed
    into a folder of its own: ``mcjax list filters`` shows it as a plugin from there, and the docs' league (made
    tiny) runs it beside kcf and local in the three scenarios, without faults and under link loss. In every
    scenario x point — a sweep, written as ``mcjax sweep`` writes one — its rows carry every output the
    built-ins' rows carry, with finite errors; in the league table its rows carry every column theirs do."""
    reason = _offline_build_missing()
    if reason:
        pytest.skip(f"pip cannot build the plugin offline (--no-build-isolation): {reason}")
    source = tmp_path / "diffusion_kf"
    for path, body in docs_package().items():
        (source / path).parent.mkdir(parents=True, exist_ok=True)
        (source / path).write_text(body, encoding="utf-8")
    target = tmp_path / "site"
    env = {**os.environ, "PIP_NO_INDEX": "1", "PIP_DISABLE_PIP_VERSION_CHECK": "1"}
    pip = subprocess.run([sys.executable, "-m", "pip", "install", "--no-deps", "--no-build-isolation", "--quiet",
                          "--target", str(target), str(source)], check=False, capture_output=True, text=True,
                         env=env, timeout=300)
    assert pip.returncode == 0, pip.stderr
    env["PYTHONPATH"] = os.pathsep.join([str(target), *[p for p in sys.path if p]])
    league, out = _tiny_league(tmp_path), tmp_path / "league"
    commands = [["list", "filters"], ["league", str(league), "--seeds", str(SEEDS), "--out", str(out)],
                ["report", str(out)]]  # the docs' `mcjax report results/league_diffusion_league`
    run = subprocess.run([sys.executable, "-c", DRIVER, json.dumps(commands)], check=False, capture_output=True,
                         text=True, env=env, cwd=tmp_path, timeout=900)
    assert run.returncode == 0 and "REPORT " in run.stdout, run.stderr[-3000:]
    done = json.loads(run.stdout.split("REPORT ", 1)[1])

    listed = done["list"]
    assert listed["exit_code"] == 0, listed
    lines = listed["output"].splitlines()
    at = next((i for i, x in enumerate(lines) if x.startswith("diffusion_kf ")), None)
    assert at is not None, listed["output"]
    assert "[plugin:" in lines[at] and str(target) in lines[at], lines[at]  # the installed copy, not the repository's
    assert lines[at + 1].strip() == "reference: Cattivelli & Sayed 2010, IEEE TAC 55(9), ATC diffusion KF"
    assert lines[at + 3].strip() == f"scenarios: {', '.join(SCENARIOS)}", lines[at:at + 4]

    ran = done["league"]
    assert ran["exit_code"] == 0, ran["output"][-3000:] + ran["exception"]
    table = pd.read_parquet(out / "league.parquet")
    points = sorted(set(table["point"]))
    assert sorted(set(table["scenario"])) == sorted(SCENARIOS) and len(points) == 2, table[["scenario", "point"]]
    for (scenario, point), cell in table.groupby(["scenario", "point"]):
        where = f"{scenario}/{point}"
        ours = cell[cell["filter"] == "diffusion_kf"]
        assert len(ours) == 1 and ours["status"].item() == "run" and ours["runs"].item() == SEEDS, (where, cell)
        assert np.isfinite(ours["rmse"].item()) and pd.notna(ours["rank"].item()), (where, ours.T)
        for name in BUILT_INS:
            theirs = cell[cell["filter"] == name]
            assert len(theirs) == 1 and theirs["status"].item() == "run", (where, name)
            assert _carried(theirs) <= _carried(ours), (where, name, sorted(_carried(theirs) - _carried(ours)))

        rows = pd.read_parquet(out / scenario / point / "runs")  # the cell's sweep, every output of every run
        assert set(rows["filter"]) == {*BUILT_INS, "diffusion_kf"}, (where, set(rows["filter"]))
        ours = rows[rows["filter"] == "diffusion_kf"]
        assert len(ours) == SEEDS, where
        for name in BUILT_INS:
            theirs = rows[rows["filter"] == name]
            assert _carried(theirs) <= _carried(ours), (where, name, sorted(_carried(theirs) - _carried(ours)))
        assert np.isfinite(ours["rmse"].to_numpy(float)).all() and not ours["nonfinite"].any(), (where, ours.T)
        assert {"anees", "anis"} <= _carried(ours), where  # the consistency outputs the docs' league switches on
        if scenario != "wind_formation":
            assert "pcrb_rmse" in _carried(ours), where  # the error floor (bound = "on")
        if point != "none":
            assert rows["links_lost"].sum() > 0, where  # the faults were drawn

    reported = done["report"]  # the league's page: the table by rank, as docs/library.md says
    assert reported["exit_code"] == 0, reported["output"][-3000:] + reported["exception"]
    page = (out / "report" / "index.html").read_text(encoding="utf-8")
    assert "diffusion_kf" in page and "rank" in page and not list((out / "report").glob("*.png"))
    assert all(f in reported["output"] for f in ("kcf", "local", "diffusion_kf")), reported["output"]
