"""The filter contract: what a filter provides, so that any scenario with a comm graph can run it.

A filter is a :class:`Filter`, a frozen record declared next to its code (as a scenario is a
:class:`mcjax.contract.Scenario`): its name, title and reference, one ``step`` with one signature, and
its :class:`Traits` as data. One registry (:mod:`mcjax.tracking.filters.registry`) resolves a name to
its record — the built-in ones, those installed packages declare under the entry-point group
``mcjax.filters``, or a reference ``"file.py:ATTRIBUTE"`` / ``"package.module:ATTRIBUTE"`` — and
nothing dispatches on a filter's name: the scenarios read the traits (who holds an estimate, who takes
late messages, what the consensus needs) and call ``step``.

``step(model, posterior, measurements) -> posterior``, pure and jittable, advances every agent of one
run by one step:

* ``model``: a :class:`Model` — the measurement function ``h(x, sensor) -> z``, the angle components
  of ``z`` (wrapped in the innovation), ``F`` and ``Q`` of the step (``F = I, Q = 0`` at the first
  measurement time, so step 0 corrects the prior without predicting), the static options
  (:class:`mcjax.tracking.filters.consensus.FilterOptions`: consensus steps and weights, exchange …)
  and two inputs only some filters read (the KCF's consensus step size; Chen & Lu 2013's formation term);
* ``posterior``: the previous posterior, a :class:`mcjax.tracking.filters.gaussian.Gaussian` with the
  agents on the leading axis — or one Gaussian without that axis for a centralised filter;
* ``measurements``: :class:`mcjax.tracking.filters.consensus.Measurements` — each agent's measurement
  (NaN where it has none), the sensors' positions, the links that carried a message this step, the
  inverse noise covariances, and the late messages where the scenario delays them.

No JAX here (the command line lists filters without it).
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import Any, Callable, NamedTuple

#: The consensus weights a filter may need (:attr:`Traits.weights`).
WEIGHTS = ("any", "doubly_stochastic")


class Traits(NamedTuple):
    """What the scenarios need to know of a filter, as data (no scenario names a filter to learn it).

    ``centralised``: one estimate shared by all agents (its state has no agent axis; no link carries
    it, so faults neither shield nor hold it); else one estimate per agent.
    ``late_messages``: it takes consensus messages that arrive ``message_delay`` steps late
    (``Measurements.late``) — or it sends none, so a delay does not concern it.
    ``messages``: it sends consensus messages (a scenario that delays messages posts this filter's
    predicted estimates into a mailbox); False for a filter that shares nothing or is centralised.
    ``weights``: the consensus weights it needs — ``"any"`` (the scenario's choice is used) or
    ``"doubly_stochastic"`` (it uses Metropolis weights of the links that carried a message, whatever
    the scenario's choice: the step asks for them itself, ``consensus_matrix(options, adjacency,
    "metropolis")``; the trait changes no option it is given, and tells the scenarios to refuse a set-up
    where such weights do not mean what the filter assumes).
    ``consensus_only``: it fuses by consensus alone, so it needs at least one consensus step."""

    centralised: bool = False
    late_messages: bool = False
    messages: bool = True
    weights: str = "any"
    consensus_only: bool = False

    def words(self) -> str:
        """The traits in a few plain words (``mcjax list filters``)."""
        out = ["centralised (one estimate for all)" if self.centralised else "per agent"]
        if self.messages and not self.centralised:
            out.append("takes late messages" if self.late_messages else "no late messages")
        if self.weights != "any":
            out.append(f"{self.weights.replace('_', ' ')} weights")
        if self.consensus_only:
            out.append("needs >= 1 consensus step")
        return ", ".join(out)


class Model(NamedTuple):
    """The step's model, as a filter's ``step`` receives it (module docstring)."""

    h: Callable                # h(x (d,), sensor (2,)) -> z (m,): the measurement function
    angle_mask: Any            # (m,) 1 where a component of z is an angle (its innovation is wrapped)
    F: Any                     # (d, d) the step's transition
    Q: Any                     # (d, d) the step's process noise
    options: Any               # FilterOptions: the static choices (consensus steps, weights, exchange …)
    epsilon: Any = None        # the consensus step size of Olfati-Saber's KCF (other filters ignore it)
    formation: Any = None      # Chen & Lu 2013's formation term (n, n, d) of the prior-consensus KCF, or None


_NAME = re.compile(r"^[a-z][a-z0-9_]*$")


class FilterError(ValueError):
    """A filter whose step does not keep the contract (what it returns): one line naming the filter and the
    field, raised when the step is first traced (:func:`mcjax.tracking.filters.steps.checked`)."""


@dataclass(frozen=True, eq=False)
class Filter:
    """One filter (module docstring); hashed by identity. Checked when it is built: a one-line
    ValueError names the field."""

    name: str              # the name the datasets' ``filter`` column, the tables and the pages show it by
    title: str             # one line: what it is
    reference: str         # where it comes from (a paper), or "ours"
    step: Callable         # step(model: Model, posterior, measurements) -> posterior
    traits: Traits = Traits()

    def __post_init__(self):
        me = f"filter {self.name!r}"
        if not isinstance(self.name, str) or not _NAME.match(self.name):
            raise ValueError(f"{me}: name must be lower-case letters, digits and '_', starting with a letter")
        for field in ("title", "reference"):
            if not isinstance(getattr(self, field), str) or not getattr(self, field).strip():
                raise ValueError(f"{me}: {field} must be a non-empty string")
        if not callable(self.step):
            raise ValueError(f"{me}: step must be a function step(model, posterior, measurements) -> posterior")
        if not isinstance(self.traits, Traits):
            raise ValueError(f"{me}: traits must be a mcjax.contract.filter.Traits; got {type(self.traits).__name__}")
        if self.traits.weights not in WEIGHTS:
            raise ValueError(f"{me}: traits.weights must be one of {', '.join(WEIGHTS)}; got {self.traits.weights!r}")
        for field in ("centralised", "late_messages", "messages", "consensus_only"):
            if not isinstance(getattr(self.traits, field), bool):
                raise ValueError(f"{me}: traits.{field} must be True or False")
