"""Every variable of the Diagnoser FMU, declared once (issue 31 item 3).

One module per channel lists its variables as :class:`~.spec.Var` records (name, kind,
causality, start, description, unit, range, tunable, the config field it fills);
``gd_diagnoser_fmu`` declares them in the order of :data:`VARIABLES` (which fixes the
value references), build_fmu.py takes units and ranges from :data:`VARIABLE_META`, and
the channels' configs are built from the tables by :func:`~.spec.config_fields`.
"""

from __future__ import annotations

from typing import Any

from . import common, df, dtg, grey
from .spec import Var, variable_meta

#: Declaration order: sample period, DTG, grey, detection filter, summary.
VARIABLES: tuple[Var, ...] = (*common.HEAD, *dtg.VARIABLES, *grey.VARIABLES,
                              *df.VARIABLES, *common.SUMMARY)
#: Units and ranges (name -> unit/min/max) of the variables that have one.
VARIABLE_META: dict[str, dict[str, Any]] = variable_meta(VARIABLES)
#: Parameters that may change between steps, per channel (a change applies from the
#: next sample: the channel is rebuilt with the new value and takes over the old state).
TUNABLE: dict[str, tuple[str, ...]] = {
    name: tuple(v.name for v in module.VARIABLES if v.tunable)
    for name, module in (("dtg", dtg), ("grey", grey))
}
#: Library argument names -> FMU parameter names, per channel (validation messages).
MESSAGE_NAMES: dict[str, dict[str, str]] = {
    "dtg": dtg.MESSAGE_NAMES, "grey": grey.MESSAGE_NAMES, "df": df.MESSAGE_NAMES,
}

__all__ = ["MESSAGE_NAMES", "TUNABLE", "VARIABLES", "VARIABLE_META", "Var"]
