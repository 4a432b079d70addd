"""Testing: scenario files as pytest tests (the ``gyrodiag`` pytest plugin) and fixtures
for users' own tests; see :mod:`gyrodiag_harness.testing.plugin`."""
