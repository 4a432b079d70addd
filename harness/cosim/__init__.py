"""Co-simulation: the scenario format, the fmpy master, run records, batches of runs."""
