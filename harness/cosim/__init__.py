"""Co-simulation: the scenario format, its run plan, the fmpy master and its FMI access,
run records, batches of runs."""
