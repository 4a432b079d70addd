"""Copies of the numpy implementations the per-sample kernels replaced (test oracles)."""
