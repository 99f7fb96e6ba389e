"""The progress bars of a command's long work (tqdm, imported when the first bar is drawn), fed by
the sweep and tune runners' progress callbacks; a message closes the bar drawn so far."""

from __future__ import annotations

import click


class Bars:
    """The progress bars of a command (tqdm), one stage at a time: a new stage, or a message,
    closes the bar drawn so far, so the lines come out in order."""

    def __init__(self, **units: str) -> None:
        self.units = units  # stage -> unit
        self.stage = self.bar = None

    def show(self, stage: str, done: int, total: int, **postfix) -> None:
        """Draw ``done`` of ``total`` in ``stage``'s bar (a new one at a stage's first call)."""
        if self.bar is None or stage != self.stage:
            from tqdm import tqdm

            self.close()
            self.stage = stage
            self.bar = tqdm(total=total, initial=done, unit=self.units[stage], desc=stage, disable=None)
        else:
            if postfix:
                self.bar.set_postfix(**postfix)
            self.bar.update(done - self.bar.n)

    def echo(self, line: str) -> None:
        self.close()
        click.echo(line)

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()
        self.bar = None

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self.close()
