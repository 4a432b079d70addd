"""Versioned algorithm state.

A class that saves its state declares ``STATE_VERSION`` and, for every older version,
a migration to the next one. :func:`stamp` tags a saved state with the version;
:func:`migrate` brings a restored state up to the current version step by step, so
``set_state`` reads one format only. States saved before versioning are version 0.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any

#: Key of the version in a saved state (absent: version 0).
STATE_VERSION_KEY = "state_version"

Migration = Callable[[dict[str, Any]], dict[str, Any]]


def stamp(state: dict[str, Any], version: int) -> dict[str, Any]:
    """Tag ``state`` with ``version`` (in place) and return it."""
    state[STATE_VERSION_KEY] = version
    return state


def migrate(state: Mapping[str, Any], version: int, migrations: Mapping[int, Migration],
            owner: str) -> dict[str, Any]:
    """Return ``state`` brought up to ``version`` by ``migrations[v]`` (v → v + 1).

    Raises
    ------
    ValueError
        The state's version is not an integer in 0..``version`` (e.g. a state of a newer
        library), naming ``owner``.
    """
    found = state.get(STATE_VERSION_KEY, 0)
    if isinstance(found, bool) or not isinstance(found, int) or not 0 <= found <= version:
        raise ValueError(f"{owner} state version {found!r}: this library reads versions "
                         f"0 to {version}")
    out = dict(state)
    for v in range(found, version):
        out = migrations[v](out)
    out[STATE_VERSION_KEY] = version
    return out
