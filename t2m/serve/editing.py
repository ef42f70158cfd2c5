"""The page's edit panel and ``POST /api/edit``: motion editing through ``t2m.edit`` when this
build has it (the editing issue); otherwise the panel is shown disabled, saying so."""

from __future__ import annotations

import importlib.util

from dataset_tools.command import UsageError

UNAVAILABLE = "editing needs t2m.edit (the editing modes), which this build does not have yet"


def edit_available() -> bool:
    return importlib.util.find_spec("t2m.edit") is not None


def edit_info() -> dict:
    """What GET /api/info says about editing."""
    if not edit_available():
        return {"available": False, "reason": UNAVAILABLE}
    return {"available": False, "reason": "t2m.edit exists but the web app is not wired to it"}


def edit(app, payload: object) -> dict:
    """POST /api/edit."""
    raise UsageError(edit_info()["reason"])
