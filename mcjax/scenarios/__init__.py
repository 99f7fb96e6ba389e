"""Scenarios: one module per seed system, assembling the layers below.

Each module follows the contract of design.md: ``Config`` (frozen dataclass), ``Params``
(NamedTuple of arrays), ``default_params``, ``init``, ``step``, ``summarize``.
"""

from __future__ import annotations

from types import ModuleType

from mcjax.scenarios import leader_follower, uuv_imm

SCENARIOS: dict[str, ModuleType] = {
    leader_follower.NAME: leader_follower,
    uuv_imm.NAME: uuv_imm,
}


def get(name: str) -> ModuleType:
    """The scenario module called ``name``; ValueError listing the known ones otherwise."""
    try:
        return SCENARIOS[name]
    except KeyError:
        raise ValueError(f"scenario must be one of {', '.join(sorted(SCENARIOS))}; got {name!r}") from None
