"""Shared by the discrepancy tests: the length of the synthetic residual series."""

#: Samples of a synthetic residual series.
N = 2000
