"""A tiny league: Chen & Lu 2013's wind formation, 10 steps, kcf and local, two fault points that share
one Config (so one program), 8 seeds in chunks of 4."""

from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]

TINY = f"""
title = "tiny league"
seeds = 8
chunk_size = 4
timing_runs = 0
filters = ["kcf", "local"]

[scenarios.wind]
base = "{ROOT / 'configs' / 'chen2013.toml'}"
config = {{ n_steps = 10, faults = "on" }}

[points.none]
description = "no faults"
params = {{ link_loss = 0.0 }}

[points.iid]
description = "i.i.d. link loss 0.3"
params = {{ link_loss = 0.3 }}
"""


@pytest.fixture
def league_file(tmp_path):
    def write(text: str = TINY, name: str = "tiny.toml") -> Path:
        path = tmp_path / name
        path.write_text(text, encoding="utf-8")
        return path
    return write
