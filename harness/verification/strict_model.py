"""The one strict base of the harness's pydantic models (scenario files, expectations,
campaign specs): an unknown key is an error, never silently ignored.

Subclasses add their own options, which pydantic merges into this configuration, e.g.
``model_config = ConfigDict(frozen=True, use_attribute_docstrings=True)``.  It lives in
the lowest layer (:mod:`gyrodiag_harness.verification`) so that every subpackage may use it.
"""

from __future__ import annotations

from pydantic import BaseModel, ConfigDict


class StrictModel(BaseModel):
    """A pydantic model that forbids extra keys (``extra="forbid"``)."""

    model_config = ConfigDict(extra="forbid")
