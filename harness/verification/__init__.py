"""Verification: metrics on recorded signals, ``[[expect]]`` kinds and their evaluation,
the isolability analysis of the seed aircraft."""
