"""``python -m gyrodiag_harness``: see :mod:`gyrodiag_harness.cli`.

The process ends with ``os._exit`` once the command has finished and its output is
flushed. pythonfmu 0.7 writes into its freed interpreter guard at process exit (its
static destructor runs before its ELF destructor), which aborted about one exit in ten
with glibc "corrupted double-linked list" after every result was written. Our FMUs'
status shim now resets that guard first (0 aborts in 400 runs, see
fmu_src/shim/fmi2_status_shim.c); ``os._exit`` stays so that FMUs built without the shim
(no C compiler) cannot turn a passing run into exit status 134.
"""

from gyrodiag_harness.cli import console

if __name__ == "__main__":
    console()
