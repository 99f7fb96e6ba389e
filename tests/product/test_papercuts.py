"""The first hour's papercuts stay fixed: a fresh clone's datasets say "no uncommitted changes" with the
README's .venv in it; a folder left by a sweep that wrote nothing is reused without --force; one warning
without mcjax.configure(); no undated timing in a sweep file's comments; the stored-program warning reads
as English."""

import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from mcjax import runtime
from mcjax.study import OutputError, load_spec, prepare_output

ROOT = Path(__file__).resolve().parents[2]


@pytest.mark.skipif(shutil.which("git") is None, reason="needs git")
def test_a_fresh_clone_with_its_venv_and_results_is_clean(tmp_path):
    """The README makes .venv in the checkout and writes results/: neither makes git report a change."""
    repo = tmp_path / "clone"
    repo.mkdir()
    shutil.copy(ROOT / ".gitignore", repo / ".gitignore")

    def git(*args):
        return subprocess.run(["git", "-c", "user.name=t", "-c", "user.email=t@t", *args], cwd=repo, check=True,
                              capture_output=True, text=True).stdout

    git("init", "-q")
    git("add", ".gitignore")
    git("commit", "-qm", "init")
    for path in (".venv/bin/python", "results/default/runs/part.parquet", "mcjax.egg-info/PKG-INFO"):
        (repo / path).parent.mkdir(parents=True, exist_ok=True)
        (repo / path).write_text("x")
    assert git("status", "--porcelain") == ""


def _study(out):
    return load_spec(ROOT / "sweeps" / "floors.toml", seeds=2, out_dir=out,
                     overrides={"base": "../configs/chen2013.toml", "config.wind_noise": "gaussian"})


def test_a_folder_left_by_a_sweep_that_wrote_nothing_is_reused(tmp_path):
    out = tmp_path / "out"
    (out / "runs").mkdir(parents=True)
    (out / "sweep.json").write_text("{}")
    said = []
    assert prepare_output(_study(out), out, note=said.append) is None
    assert said == [f"{out} held only the identity file of a sweep that wrote nothing; reusing it"]
    assert (out / "sweep.json").read_text() != "{}"  # this sweep's identity now
    # a folder with a part in it is still refused without --force or --resume
    (out / "runs" / "point_id=0").mkdir(parents=True)
    (out / "runs" / "point_id=0" / "part-000000.parquet").write_bytes(b"PAR1")
    with pytest.raises(OutputError, match="not empty"):
        prepare_output(_study(out), out)


def test_one_warning_without_configure(tmp_path):
    """docs/library.md's example without mcjax.configure(): the one warning the docs promise, not JAX's too."""
    text = (ROOT / "docs" / "library.md").read_text(encoding="utf-8")
    code = re.search(r"```python\n(.*?)```", text, flags=re.S).group(1).replace("mcjax.configure()", "pass")
    script = tmp_path / "example.py"
    script.write_text(code, encoding="utf-8")
    done = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, timeout=300,
                          env={"PATH": "/usr/bin:/bin", "PYTHONPATH": str(ROOT), "JAX_PLATFORMS": "cpu"})
    assert done.returncode == 0, done.stderr
    warnings = [line for line in done.stderr.splitlines() if "Warning" in line]
    assert len(warnings) == 1 and "mcjax.configure()" in warnings[0], done.stderr


def test_no_undated_timing_in_a_sweep_files_comments():
    """A measured duration in a comment block of sweeps/*.toml (a time with "took", "takes", a compile, a
    machine) comes with the date it was measured."""
    duration = re.compile(r"\b\d+(\.\d+)?\s?(s|min|minutes|seconds|h|hours)\b")
    measured = re.compile(r"took|takes|compil|machine|\bVM\b|load average|wall")
    date = re.compile(r"20\d\d-\d\d-\d\d")
    for spec in sorted((ROOT / "sweeps").glob("*.toml")):
        blocks, block = [], []
        for line in spec.read_text(encoding="utf-8").splitlines():
            comment = line.split("#", 1)[1] if "#" in line else None
            if comment is None:
                if block:
                    blocks.append(" ".join(block))
                block = []
            else:
                block.append(comment)
        blocks.append(" ".join(block))
        for text in blocks:
            if duration.search(text) and measured.search(text):
                assert date.search(text), (spec.name, text)


def test_the_stored_program_warning_reads_as_english(tmp_path, capsys):
    folder = tmp_path / "store"
    folder.mkdir(mode=0o700)
    path = folder / f"program-{'0' * 64}.bin"
    path.write_bytes(b"altered")
    path.chmod(0o600)
    data, why = runtime.trusted_read(path)
    assert data is None
    runtime.distrust(path, why)
    err = capsys.readouterr().err
    assert f"{path}: it does not match the hash recorded when it was written" in err
    assert "it its" not in err


def test_library_md_states_run_filters_conventions():
    """The state order, the bearing convention and why run_filter's icf_variant default differs from the
    paper's config are in docs/library.md's prose (they were only in docstrings)."""
    text = (ROOT / "docs" / "library.md").read_text(encoding="utf-8")
    assert "`[x, ẋ, y, ẏ]`" in text and "atan2(y − s_y, x − s_x)" in text
    default = re.search(r'icf_variant: str = "(\w+)"', (ROOT / "mcjax" / "tracking" / "filters" / "recorded.py").read_text())
    paper = re.search(r'icf_variant = "(\w+)"', (ROOT / "configs" / "sun2011.toml").read_text())
    assert default and paper and default.group(1) != paper.group(1)
    assert f'`icf_variant =\n"{default.group(1)}"`' in text or f'`icf_variant = "{default.group(1)}"`' in text
    assert f'`"{paper.group(1)}"`' in text
