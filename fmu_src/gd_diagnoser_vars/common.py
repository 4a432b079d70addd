"""Variables of no channel: the sample period and the summary outputs."""

from __future__ import annotations

from .spec import POSITIVE, Var, out, par

HEAD: tuple[Var, ...] = (
    par("sample_period_s", "Real", 1e-3,
        "Sample period of every channel; a communication step must be a whole number "
        "of sample periods", "s", POSITIVE),
)

SUMMARY: tuple[Var, ...] = (
    out("any_alarm", "Boolean", False, "Any enabled channel in alarm"),
    out("fault_code", "Integer", 0,
        "0 none; 100+j DTG signature j (99 unknown); 200 grey alarm; "
        "300+i sensor i isolated by the detection filter (299 not isolated, "
        "298 several sensors)"),
    out("inputs_valid", "Boolean", True, "All enabled channels' inputs finite"),
)
