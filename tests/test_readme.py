"""The run_filter example of docs/library.md (once the README's) runs as written."""

import re
from pathlib import Path


def test_readme_run_filter_example_runs(capsys):
    text = (Path(__file__).parents[1] / "docs" / "library.md").read_text()
    blocks = re.findall(r"```python\n(.*?)```", text, flags=re.S)
    example = next(b for b in blocks if "run_filter(" in b)
    exec(compile(example, "docs/library.md", "exec"), {})
    out = capsys.readouterr().out
    assert "(50, 3, 4) (50, 3, 4, 4)" in out
    errors = re.search(r"final position errors, m: \[(.*?)\]", out).group(1).split()
    assert all(float(e) < 200.0 for e in errors)  # a working filter, not a diverged one
