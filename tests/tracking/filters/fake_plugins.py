"""An installed filter plugin, faked for a test: the entry points of the group ``mcjax.filters`` replaced by one."""

import importlib.metadata

from mcjax.tracking.filters import registry


def install(monkeypatch, name: str, value: str) -> None:
    """Make ``name = "value"`` the one installed entry point of ``mcjax.filters`` for this test (the registry's
    cache emptied); other groups' entry points stay the real ones."""
    point = importlib.metadata.EntryPoint(name=name, value=value, group=registry.ENTRY_POINT_GROUP)
    real = importlib.metadata.entry_points

    def entry_points(**kw):
        return [point] if kw.get("group") == registry.ENTRY_POINT_GROUP else real(**kw)

    monkeypatch.setattr(registry, "entry_points", entry_points)
    monkeypatch.setattr(importlib.metadata, "entry_points", entry_points)
    monkeypatch.setattr(registry, "_FOUND", {})
