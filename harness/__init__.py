"""fmpy co-simulation harness for gyrodiag (master, scenarios, metrics, CLI)."""
