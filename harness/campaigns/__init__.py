"""Campaigns: Monte Carlo fault-injection campaigns and their summary, DTG fault-signature
learning from training runs."""
