"""The cases of the stored-rows test: each built-in config and the docs' example scenario,
run for 6 seeds x 40 steps through the public sweep API."""

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
CONFIGS = sorted(p.stem for p in (ROOT / "configs").glob("*.toml"))
CASES = [*CONFIGS, "static_sensors"]
SEEDS, STEPS = 6, 40


def docs_example(folder: Path) -> Path:
    """The example scenario of docs/library.md written to ``folder``; its config file's path."""
    text = (ROOT / "docs" / "library.md").read_text(encoding="utf-8")
    blocks = re.findall(r"`(static_[a-z]+\.(?:py|toml))`:\s*```[a-z]*\n(.*?)```", text, re.S)
    for name, body in blocks:
        (folder / name).write_text(body, encoding="utf-8")
    return folder / "static_sensors.toml"


def case_rows(name: str):
    """The tidy rows of one case."""
    import tempfile

    from mcjax.study import build_spec, run_sweep

    with tempfile.TemporaryDirectory() as tmp:
        base = docs_example(Path(tmp)) if name == "static_sensors" else ROOT / "configs" / f"{name}.toml"
        spec = build_spec({"base": str(base)}, ROOT, seeds=SEEDS, overrides={"config.n_steps": STEPS})
        return run_sweep(spec)
