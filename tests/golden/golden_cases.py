"""The cases of the stored-rows test: each built-in config and the docs' example scenario,
run for 6 seeds x 40 steps through the public sweep API; and each config with a fault model,
with every fault drawn and the per-step series written (FAULT_CASES, 6 seeds x 30 steps)."""

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


def closed_loop(name: str) -> bool:
    """Whether a case's config steers by its estimates (a planner): its rows are judged as a closed loop's
    (tests/golden/rule.py)."""
    from mcjax.study import build_spec

    base = ROOT / "configs" / f"{name}.toml"
    if not base.is_file():
        return False
    return getattr(build_spec({"base": str(base)}, ROOT, seeds=1).config, "planner", "none") not in ("none", None)


def case_rows(name: str):
    """The tidy rows of one case."""
    import tempfile

    from mcjax.study import build_spec, run_sweep

    with tempfile.TemporaryDirectory() as tmp:
        base = docs_example(Path(tmp)) if name == "static_sensors" else ROOT / "configs" / f"{name}.toml"
        spec = build_spec({"base": str(base)}, ROOT, seeds=SEEDS, overrides={"config.n_steps": STEPS})
        return run_sweep(spec)


#: Configs with a fault model, run with every kind of fault drawn and the per-step series kept.
FAULT_CASES = ["chen2013", "lou2013", "ren2017", "sun2011"]
FAULTS = {"config.faults": "on", "params.link_loss": 0.2, "params.link_burst": 3.0,
          "params.agent_loss_rate": 0.03, "params.min_alive": 2, "params.sensor_dropout": 0.1}


def fault_rows(name: str):
    """``(runs, timeseries)``: the tidy rows and per-step rows of a config under every fault,
    6 seeds x 30 steps, sorted by their keys."""
    import tempfile

    import pandas as pd

    from mcjax.base.parquet import read_table
    from mcjax.study import build_spec, run_sweep

    def tidy(df, keys):
        df = df.copy()
        for c in df.columns:
            if isinstance(df[c].dtype, pd.CategoricalDtype):
                df[c] = df[c].astype(str)
        return df.sort_values([k for k in keys if k in df.columns]).reset_index(drop=True)

    with tempfile.TemporaryDirectory() as tmp:
        spec = build_spec({"base": str(ROOT / "configs" / f"{name}.toml"), "timeseries": True}, ROOT, seeds=SEEDS,
                          overrides={"config.n_steps": 30, **FAULTS})
        run_sweep(spec, Path(tmp) / "out")
        keys = ["point_id", "seed_index", "t", "filter"]
        return (tidy(read_table(Path(tmp) / "out"), keys),
                tidy(read_table(Path(tmp) / "out", "timeseries"), keys))
