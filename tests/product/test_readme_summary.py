"""The README's printed summary and the tolerance it states (benchmarks/papers/readme_summary.py compares
the first command's output with it): the comparison holds the README to its digits where every run kept
track and to 0.2 % where runs diverged, on the README's own table moved by hand."""

import re
from pathlib import Path

from benchmarks.papers.readme_summary import compare, readme_block, summary_cells

README = (Path(__file__).resolve().parents[2] / "README.md").read_text(encoding="utf-8")
BLOCK = readme_block(README)


def _moved(old: str, new: str) -> str:
    assert BLOCK.count(old) == 1, old
    return BLOCK.replace(old, new)


def test_the_readme_states_the_tolerance_and_its_table_reads():
    section = README.split("## What you should see", 1)[1].split("\n## ", 1)[0]
    assert "fourth digit" in section and "0.2 %" in section and "readme_summary.py" in section
    cells = summary_cells(BLOCK)
    assert len(cells) >= 4 and all({"rmse_mean", "div_rate", "n"} <= set(c) for c in cells.values())
    assert compare(README, BLOCK) == ([], [])


def test_a_cell_with_diverged_runs_may_move_in_its_fourth_digit_but_not_more():
    icf = re.search(r"^\s*50000\s+icf\s+100\s+(\S+)", BLOCK, flags=re.M).group(1)  # 99 % of its runs diverged
    nudged = f"{float(icf) + 0.1:.1f}"
    outside, moved = compare(README, _moved(f"icf           100      {icf}", f"icf           100      {nudged}"))
    assert outside == [] and len(moved) == 1
    far = f"{float(icf) * 1.01:.1f}"
    outside, _ = compare(README, _moved(f"icf           100      {icf}", f"icf           100      {far}"))
    assert len(outside) == 1


def test_a_cell_whose_runs_all_kept_track_keeps_its_digits():
    line = next(x for x in BLOCK.splitlines() if re.match(r"^\s*100000\s+cif\s", x))
    rmse = line.split()[3]
    last = 10.0 ** -len(rmse.split(".", 1)[1])
    for step, ok in ((1, True), (2, False)):
        changed = f"{float(rmse) + step * last:.{len(rmse.split('.', 1)[1])}f}"
        outside, moved = compare(README, _moved(line, line.replace(f" {rmse} ", f" {changed} ", 1)))
        assert (outside == [] and len(moved) == 1) if ok else len(outside) == 1
