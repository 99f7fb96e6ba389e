"""The README's printed summary against the README's first command run here, with the tolerance the README
states: a cell whose runs all kept track prints the same digits (or one unit of its last digit, for a value
at a rounding edge); a cell with diverged runs agrees within 0.2 %, its counts within one run and its
rates within 1/n — runs that diverge amplify another CPU model's rounding (XLA compiles other vector code
there), so such a cell may differ in its fourth digit.

    python benchmarks/papers/readme_summary.py            # runs `mcjax sweep sweeps/default.toml` (~1 min)
    python benchmarks/papers/readme_summary.py --printed FILE   # compares a summary printed before

Prints each cell that differs with the tolerance it met, and exits 1 if one is outside it.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def summary_cells(text: str) -> dict:
    """{(comm_radius, filter): {column: printed text}} of a printed summary table (the README's trimmed one:
    its '...' columns skipped; a table cut into blocks of columns: merged)."""
    cells: dict = {}
    header = None
    for line in text.splitlines():
        words = line.split()
        if words[:2] == ["comm_radius", "filter"]:
            header = words
        elif header and len(words) == len(header) and words[0].isdigit():
            row = cells.setdefault((words[0], words[1]), {})
            row.update({h: w for h, w in zip(header, words) if h not in ("...", "comm_radius", "filter")})
    return cells


def readme_block(readme: str) -> str:
    """The README's printed summary (the text block of "What you should see")."""
    return readme.split("## What you should see", 1)[1].split("```text", 1)[1].split("```", 1)[0]


def tolerance(cells: dict, column: str) -> float:
    """How far a printed number of this cell may move (module docstring)."""
    want = cells[column]
    if float(cells["div_rate"]) == 0:
        return (10.0 ** -len(want.split(".", 1)[1]) if "." in want else 1.0) * 1.0001
    if column.startswith("div_"):
        return max(2e-3 * abs(float(want)), 1.0001 / int(cells["n"]))
    if column in ("n", "n_ok"):
        return 1.0
    return 2e-3 * abs(float(want))


def compare(readme_text: str, printed: str) -> tuple[list[str], list[str]]:
    """``(outside, moved)``: lines for the cells outside the tolerance and for those that moved within it."""
    readme, got = summary_cells(readme_block(readme_text)), summary_cells(printed)
    missing = sorted(set(readme) - set(got))
    if missing or not readme:
        return [f"the printed summary has no row {k}" for k in missing] or ["the README shows no summary"], []
    outside, moved = [], []
    for key, cells in readme.items():
        for column, want in cells.items():
            a, tol = float(got[key][column]), tolerance(cells, column)
            if got[key][column] != want:
                line = f"{key} {column}: {got[key][column]} here, {want} in the README (tolerance {tol:.3g})"
                (outside if abs(a - float(want)) > tol else moved).append(line)
    return outside, moved


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--printed", type=Path, help="a summary printed by `mcjax sweep sweeps/default.toml` before")
    args = ap.parse_args(argv)
    if args.printed:
        printed = args.printed.read_text(encoding="utf-8")
    else:
        with tempfile.TemporaryDirectory() as tmp:
            r = subprocess.run([sys.executable, "-m", "mcjax", "sweep", "sweeps/default.toml", "--out",
                                str(Path(tmp) / "default")], cwd=ROOT, capture_output=True, text=True)
            if r.returncode:
                print(r.stdout, r.stderr, sep="\n")
                return r.returncode
            printed = r.stdout
    outside, moved = compare((ROOT / "README.md").read_text(encoding="utf-8"), printed)
    for line in moved:
        print("moved within the tolerance:", line)
    for line in outside:
        print("OUTSIDE the tolerance:", line)
    print("the README's summary holds" if not outside else "the README's summary does not hold")
    return 1 if outside else 0


if __name__ == "__main__":
    sys.exit(main())
