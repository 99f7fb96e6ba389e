"""``mcjax report`` writes OUT/report/index.html: one self-contained page, checked with the
standard library's HTML parser (always) and in a real headless Chromium (when the machine
has one: Debian's ``chromium``; skipped otherwise)."""

from __future__ import annotations

import base64
import html
import json
import re
import shutil
import subprocess
import tomllib
from html.parser import HTMLParser
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from click.testing import CliRunner
from tests.analysis.test_tables import make_metadata, synthetic_runs, write_dataset
from tests.report.test_plots import check_png

from mcjax.base import parquet
from mcjax.cli import main
from mcjax.analysis import findings
from mcjax.report.html_page import page, spec_toml

PNG = b"\x89PNG\r\n\x1a\n"
GRID = {"comm_radius": [50e3, 100e3], "eps": [0.01, 1.0]}


class Page(HTMLParser):
    """Every start tag with its attributes, the text of each element kind, and the tables."""

    def __init__(self):
        super().__init__(convert_charrefs=True)
        self.tags: list[tuple[str, dict]] = []
        self.stack: list[str] = []
        self.text: dict[str, list[str]] = {}
        self.tables: list[list[list[str]]] = []
        self.figures: list[dict] = []
        self._cell: list[str] | None = None

    def handle_starttag(self, tag, attrs):
        attrs = dict(attrs)
        self.tags.append((tag, attrs))
        if tag not in ("img", "meta", "br"):
            self.stack.append(tag)
        if tag == "table":
            self.tables.append([])
        elif tag == "tr":
            self.tables[-1].append([])
        elif tag in ("td", "th"):
            self._cell = []
        elif tag == "figure":
            self.figures.append({"img": None, "caption": ""})
        elif tag == "img" and self.figures and "figure" in self.stack:
            self.figures[-1]["img"] = attrs

    def handle_endtag(self, tag):
        if tag in ("td", "th") and self._cell is not None:
            self.tables[-1][-1].append("".join(self._cell).strip())
            self._cell = None
        while self.stack and self.stack.pop() != tag:
            pass

    def handle_data(self, data):
        if self.stack:
            self.text.setdefault(self.stack[-1], []).append(data)
        if self._cell is not None:
            self._cell.append(data)
        if "figcaption" in self.stack and self.figures:
            self.figures[-1]["caption"] += data


def parse(path: Path) -> Page:
    p = Page()
    p.feed(path.read_text(encoding="utf-8"))
    p.close()
    return p


@pytest.fixture(scope="module")
def reported(tmp_path_factory):
    """A two-axis dataset with a few runs diverging, 24 of 30 planned runs present, reported through the CLI."""
    out = tmp_path_factory.mktemp("html") / "sweep"
    meta = make_metadata(GRID)
    # as a sweep writes a Param declared with display="km" (mcjax.contract.Param.as_json)
    meta["params"] = {**meta["params"], "comm_radius": {**meta["params"]["comm_radius"], "display_unit": "km",
                                                        "display_factor": 1e-3}}
    meta["spec"]["description"] = "Synthetic <sweep> & friends: accuracy vs comm radius and eps"
    meta.update(n_runs=5 * 6, git_revision="0123456789abcdef0123456789abcdef01234567",
                created_utc="2026-12-01T10:00:00+00:00", mcjax="0.1.0", jax="0.0.test")
    write_dataset(out, synthetic_runs(GRID, seeds=6), meta)
    r = CliRunner().invoke(main, ["report", str(out)])
    assert r.exit_code == 0, r.output
    return out, r.output


@pytest.mark.xdist_group("test_html_report")  # one worker builds the module fixture once
def test_report_writes_one_page_and_names_it(reported):
    out, output = reported
    page = out / "report" / "index.html"
    assert page.is_file()
    assert f"page: {page}" in output.splitlines()
    pngs = sorted((out / "report").glob("*.png"))
    assert len(pngs) == 2 * 4 + 3  # per axis: error, non-divergent error, divergence, connectivity; 3 heatmaps


@pytest.mark.xdist_group("test_html_report")  # one worker builds the module fixture once
def test_page_is_self_contained(reported):
    out, _ = reported
    page = parse(out / "report" / "index.html")
    kinds = {t for t, _ in page.tags}
    assert not kinds & {"script", "link", "iframe", "object", "embed", "base"}, kinds
    for tag, attrs in page.tags:
        for name, value in attrs.items():
            if name in ("src", "href", "action", "data", "poster"):
                assert value.startswith(("data:image/png;base64,", "#")), (tag, name, value[:60])
    raw = (out / "report" / "index.html").read_text(encoding="utf-8")
    assert "url(" not in raw and "@import" not in raw and "http://" not in raw and "https://" not in raw


@pytest.mark.xdist_group("test_html_report")  # one worker builds the module fixture once
def test_every_plot_is_embedded_with_a_caption(reported):
    out, _ = reported
    page = parse(out / "report" / "index.html")
    on_disk = {p.read_bytes(): p.name for p in (out / "report").glob("*.png")}
    embedded = []
    for fig in page.figures:
        src = fig["img"]["src"]
        data = base64.b64decode(src.removeprefix("data:image/png;base64,"), validate=True)
        assert data[:8] == PNG
        assert data in on_disk  # the very file written beside the page
        embedded.append(on_disk[data])
        caption = " ".join(fig["caption"].split())
        assert caption.startswith(on_disk[data]) and len(caption) > len(on_disk[data]) + 40, caption
        alt = fig["img"].get("alt")  # says what the plot shows: the caption's first sentence, not the file name
        assert alt != on_disk[data] and len(alt) > 40 and caption.split(" — ", 1)[1].startswith(alt[:-1]), alt
    assert sorted(embedded) == sorted(on_disk.values())
    captions = {" ".join(f["caption"].split()).split(" — ")[0]: " ".join(f["caption"].split()) for f in page.figures}
    # the panels and the pooling are said in words
    assert "One panel per value of eps" in captions["rmse_vs_comm_radius.png"]
    assert "comm_radius [km]" in captions["rmse_vs_comm_radius.png"]


@pytest.mark.xdist_group("test_html_report")  # one worker builds the module fixture once
def test_page_holds_description_spec_provenance_and_tables(reported):
    out, _ = reported
    page = parse(out / "report" / "index.html")
    meta = parquet.read_metadata(out)
    headings = [" ".join(t.split()) for t in page.text.get("h2", [])]
    assert headings == ["What this shows", "Plots", "Summary", "Glossary", "Base Params", "Spec", "Provenance"]
    body = " ".join(" ".join(v) for v in page.text.values())
    assert "Synthetic <sweep> & friends" in body  # escaped in the file, the same text once parsed
    spec_text = "".join(page.text["pre"])
    assert tomllib.loads(spec_text) == meta["spec"]
    tables = page.tables
    provenance = {row[0]: row[1] for row in next(t for t in tables if t and t[0] == ["what", "value"])[1:]}
    assert provenance["runs present / planned"] == "24 / 30"
    # an incomplete dataset says so at the top of the page
    assert any("incomplete dataset: 24 of 30 planned runs present" in t for t in page.text.get("p", []))
    assert provenance["git revision of mcjax"] == "0123456789abcdef0123456789abcdef01234567"
    assert provenance["dataset written (UTC)"] == "2026-12-01T10:00:00+00:00"
    assert provenance["jax"] == "0.0.test" and provenance["mcjax"] == "0.1.0"
    assert provenance["report written (UTC)"][:4].isdigit()
    # the summary tables: one row per point and filter, in the report's number format
    glance = next(t for t in tables if t and t[0][:3] == ["comm_radius [km]", "eps", "filter"])
    assert len(glance) == 1 + 4 * 3
    assert {row[0] for row in glance[1:]} == {"50", "100"}  # km, as the plots show it
    full = next(t for t in tables if t and t[0][:4] == ["comm_radius", "eps", "filter", "n"])
    assert len(full) == 1 + 4 * 3
    text_rows = CliRunner().invoke(main, ["report", str(out), "--no-plots"]).output.splitlines()
    text_rows = text_rows[text_rows.index("") + 2:]
    assert [r.split() for r in text_rows if r.strip()] == [row for row in full[1:]]  # the same cells


def test_table_cells_are_escaped(tmp_path):
    grid = {"eps": [0.1, 1.0]}
    meta = make_metadata(grid)
    meta["config"] = {"label": "<b>bold</b> & co", "n_steps": 50}
    text = page(tmp_path, synthetic_runs(grid, seeds=2), meta, [])
    assert "&lt;b&gt;bold&lt;/b&gt; &amp; co" in text and "<b>bold" not in text
    parsed = Page()
    parsed.feed(text)
    config = next(t for t in parsed.tables if t and t[0] == ["field", "value"])
    assert config[1:] == [["label", "<b>bold</b> & co"], ["n_steps", "50"]]


def test_spec_toml_round_trips():
    spec = {"description": 'a "quoted" spec — ünïcode', "base": "../configs/x.toml", "seeds": 100,
            "timeseries": True, "config": {"filters": ["icf", "cif"], "n_steps": 50},
            "params": {"sigma": 0.5, "positions": [[0.0, 1.0], [2.0, 3.0]]},
            "grid": {"comm_radius": {"linspace": [40e3, 120e3, 9]}, "alpha_I": [0.0, 1e3]}}
    assert tomllib.loads(spec_toml(spec)) == spec


# ------------------------------------------------------------------------------ a real browser

BROWSERS = ("chromium", "chromium-browser", "google-chrome", "chromium-headless-shell", "headless_shell")


def _browser() -> str | None:
    return next((shutil.which(b) for b in BROWSERS if shutil.which(b)), None)


def _run_browser(browser: str, *args: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [browser, "--headless", "--no-sandbox", "--disable-gpu", "--hide-scrollbars", "--no-first-run",
         "--host-resolver-rules=MAP * ~NOTFOUND",  # no network: anything remote would fail to load
         "--enable-logging=stderr", "--v=0", "--virtual-time-budget=5000", *args],
        capture_output=True, text=True, timeout=120)


@pytest.mark.xdist_group("test_html_report")  # one worker builds the module fixture once
@pytest.mark.skipif(_browser() is None, reason="no headless Chromium on this machine (apt-get install chromium)")
def test_page_in_a_headless_browser(reported, tmp_path):
    """A screenshot of the page, every image decoded by the browser, no console message."""
    out, _ = reported
    browser = _browser()
    page = out / "report" / "index.html"
    n_figures = len(parse(page).figures)
    shot = tmp_path / "page.png"
    shot_run = _run_browser(browser, "--window-size=1200,2400", f"--screenshot={shot}", page.as_uri())
    assert shot.is_file(), shot_run.stderr[-2000:]
    check_png(shot)
    # the same page with a probe appended: after the load event it writes what it found into the DOM
    probe = tmp_path / "probe.html"
    probe.write_text(page.read_text(encoding="utf-8").replace("</body>", (
        '<pre id="probe"></pre><script>window.addEventListener("load", () => {'
        'document.getElementById("probe").textContent = JSON.stringify([...document.images].map('
        'i => [i.complete, i.naturalWidth, i.naturalHeight]));});</script></body>')), encoding="utf-8")
    r = _run_browser(browser, "--dump-dom", probe.as_uri())
    found = r.stdout.split('<pre id="probe">', 1)[1].split("</pre>", 1)[0]
    images = json.loads(found)
    assert len(images) == n_figures > 0
    assert all(done and w > 100 and h > 100 for done, w, h in images), images
    for run in (shot_run, r):
        console = [line for line in run.stderr.splitlines() if ":CONSOLE" in line]
        assert not console, console
    # the screenshot shows the page, not an error page: mostly white with dark text
    import matplotlib.image as mpimg

    img = mpimg.imread(shot)[..., :3]
    assert 0.5 < float(np.mean(img)) < 0.999


# ------------------------------------------------------------------------------ the default sweep's page

ROOT = Path(__file__).resolve().parents[2]
#: Mean error per comm radius (m) and the filters' factors, roughly the default sweep's.
LEVELS = {50e3: 700.0, 60e3: 120.0, 80e3: 35.0, 100e3: 17.0}
DIVERGED = {50e3: 0.95, 60e3: 0.6, 80e3: 0.03, 100e3: 0.0}


def _default_like(out: Path) -> Path:
    """The default sweep's dataset with made-up numbers: its real metadata (the scenario's
    declarations, the spec, the config), 4 comm radii x 100 seeds x 3 filters, its columns."""
    from mcjax.study import load_spec, part_metadata

    study = load_spec(ROOT / "sweeps" / "default.toml")
    meta = part_metadata(study, study.chunk_size)
    rng = np.random.default_rng(3)
    rows = []
    for pid, radius in enumerate(LEVELS):
        for s in range(study.seeds):
            run = {k: float(rng.uniform(0.1, 2.0)) for k, o in meta["outputs"].items() if not o["per_filter"]}
            run["disconnected_steps"] = int(rng.poisson(40)) if radius < 70e3 else 0
            for fi, f in enumerate(meta["filters"]):
                row = {k: float(rng.uniform(1, 50)) for k, o in meta["outputs"].items() if o["per_filter"]}
                div = bool(rng.random() < DIVERGED[radius] * (1 - 0.2 * fi))
                row.update(rmse=LEVELS[radius] * (1.6 - 0.3 * fi) * float(rng.lognormal(0, 0.3)), diverged=div,
                           nonfinite=False)
                rows.append(dict(scenario=meta["scenario"], point_id=pid, seed_index=s, comm_radius=radius,
                                 filter=f, **row, **run))
    write_dataset(out, pd.DataFrame(rows), meta)
    r = CliRunner().invoke(main, ["report", str(out)])
    assert r.exit_code == 0, r.output
    return out / "report" / "index.html"


@pytest.fixture(scope="module")
def default_page(tmp_path_factory):
    return _default_like(tmp_path_factory.mktemp("default") / "default")


@pytest.mark.xdist_group("test_html_report")
def test_the_default_sweeps_page_leads_with_findings_and_fits_1280_px(default_page):
    """Structural: the findings block comes first, every image is a PNG written beside the page,
    every table sits in a box that scrolls sideways, nothing is wider than 1280 px."""
    raw = default_page.read_text(encoding="utf-8")
    page = parse(default_page)
    sections = [a.get("id") for tag, a in page.tags if tag == "section"]
    assert sections[0] == "findings", sections
    first_figure = next(i for i, (tag, _) in enumerate(page.tags) if tag in ("figure", "table"))
    findings_at = next(i for i, (tag, a) in enumerate(page.tags) if tag == "section" and a.get("id") == "findings")
    assert findings_at < first_figure
    box = raw.split('<section id="findings"', 1)[1].split("</ul>", 1)[0]
    sentences = [html.unescape(" ".join(t.split())) for t in re.findall(r"<li>(.*?)</li>", box)]
    assert 4 <= len(sentences) <= 8, sentences  # the box fits a screen
    assert any(s.startswith("Runs diverge at ") and re.search(r"\d+\.\d % \[\d+\.\d, \d+\.\d\]", s)
               for s in sentences), sentences
    on_disk = {p.read_bytes() for p in default_page.parent.glob("*.png")}
    imgs = [a for tag, a in page.tags if tag == "img"]
    assert len(imgs) == len(on_disk) == 4
    for a in imgs:
        assert base64.b64decode(a["src"].removeprefix("data:image/png;base64,")) in on_disk
        assert int(a["width"]) <= 1280 and len(a["alt"]) > 40
    widths = [int(w) for w in re.findall(r'width="(\d+)"', raw)] + [int(w) for w in re.findall(r"width:\s*(\d+)px", raw)]
    assert max(widths) <= 1280, widths
    assert raw.count("<table") == raw.count('<div class="scroll"><table')  # every table in its scroll box
    assert re.search(r"\.scroll \{[^}]*overflow-x: auto", raw)
    # the plots are drawn at 2x: the PNG is twice the size the page shows it at
    for a in imgs:
        data = base64.b64decode(a["src"].removeprefix("data:image/png;base64,"))
        assert int.from_bytes(data[16:20], "big") in (2 * int(a["width"]), 2 * int(a["width"]) - 1)
    headings = [" ".join(t.split()) for t in page.text.get("h2", [])]
    assert headings[0] == "What this shows" and headings[-2:] == ["Spec", "Provenance"]


@pytest.mark.xdist_group("test_html_report")
@pytest.mark.skipif(_browser() is None, reason="no headless Chromium on this machine (apt-get install chromium)")
def test_the_default_sweeps_page_in_a_browser_at_1280_px(default_page, tmp_path):
    """In a real browser 1280 px wide: the findings block is the first thing, every image is
    decoded, the page does not scroll sideways, the wide table scrolls inside its box."""
    probe = tmp_path / "probe.html"
    probe.write_text(default_page.read_text(encoding="utf-8").replace("</body>", (
        '<pre id="probe"></pre><script>window.addEventListener("load", () => {'
        'const boxes = [...document.querySelectorAll(".scroll")];'
        'document.getElementById("probe").textContent = JSON.stringify({'
        'page: document.documentElement.scrollWidth, view: document.documentElement.clientWidth,'
        'first: document.querySelector("main section").id,'
        'findingsTop: document.getElementById("findings").getBoundingClientRect().top,'
        'figureTop: document.querySelector("figure").getBoundingClientRect().top,'
        'images: [...document.images].map(i => [i.complete, i.naturalWidth, i.getBoundingClientRect().right]),'
        'boxes: boxes.map(b => [b.scrollWidth, b.clientWidth, b.getBoundingClientRect().right])});});'
        '</script></body>')), encoding="utf-8")
    r = _run_browser(_browser(), "--window-size=1280,900", "--dump-dom", probe.as_uri())
    found = json.loads(r.stdout.split('<pre id="probe">', 1)[1].split("</pre>", 1)[0])
    assert found["view"] == 1280 and found["page"] <= 1280, found  # no horizontal page overflow
    assert found["first"] == "findings" and found["findingsTop"] < found["figureTop"]
    assert len(found["images"]) == 4 and all(done and w > 100 and right <= 1280 for done, w, right in found["images"])
    assert all(right <= 1280 for _, _, right in found["boxes"])
    assert any(inner > outer for inner, outer, _ in found["boxes"]), found["boxes"]  # the wide table scrolls inside


@pytest.mark.xdist_group("test_html_report")
def test_the_default_sweeps_box_leads_with_the_headline_and_folds_the_tables(default_page):
    """The first sentence is the scenario's headline, the modified ICF against the ICF with both intervals
    (recomputed here with scipy); the order at each point and the consistency table are folded under the
    box, the verdict "not judged" where most runs diverged; the config table's note says anees was computed
    though the consistency setting reads off."""
    from scipy import stats

    raw = default_page.read_text(encoding="utf-8")
    first = html.unescape(raw.split('<section id="findings"', 1)[1].split("<li>", 1)[1].split("</li>", 1)[0])
    assert first.startswith("Modified ICF against ICF: lower mean rmse at "), first
    df = parquet.read_table(default_page.parents[1])
    at = re.search(r"\(at (\d+) km: ", first)
    assert at, first
    for f in ("modified_icf", "icf"):
        x = df[(df["comm_radius"] == 1e3 * float(at.group(1))) & (df["filter"] == f)]["rmse"].to_numpy()
        lo, hi = stats.t.interval(0.95, len(x) - 1, loc=x.mean(), scale=stats.sem(x))
        assert findings.quote(x.mean(), lo, hi, "m") in first, (f, first)
    page = parse(default_page)
    assert [a.get("id") for tag, a in page.tags if tag == "details"] == ["orders", "quality"]
    orders = next(t for t in page.tables if t and t[0] == ["comm_radius [km]", "order of the mean rmse, lowest first"])
    assert [r[0] for r in orders[1:]] == ["50", "60", "80", "100"] and all("CIF" in r[1] for r in orders[1:])
    quality = next(t for t in page.tables if t and t[0][:3] == ["comm_radius [km]", "filter", "runs judged"])
    verdicts = {(r[0], r[1]): r[5] for r in quality[1:]}
    k = int(df[(df["comm_radius"] == 50e3) & (df["filter"] == "icf")]["diverged"].sum())
    assert verdicts[("50", "icf")] == f"not judged: {k} % of runs diverged"  # 100 runs: k of them is k %
    assert verdicts[("100", "cif")] in ("consistent", "over-confident", "under-confident")
    note = next(p for p in page.text.get("p", []) if p.startswith("Computed in every run of this dataset"))
    assert "anees" in note and "(bound, consistency, faults)" in note, note
