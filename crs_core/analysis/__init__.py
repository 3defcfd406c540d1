"""Metrics and the suite's small numerics, each computed in one place.

``angles`` (the one angle wrap), ``statistics`` (summaries of a sample), ``latency`` (end-to-end
latencies from recorded stamps), ``laps`` (lap counting), ``metrics`` (estimation errors, lap
statistics), ``consistency`` (model vs data) and ``figures``. Nothing is imported here, so a
low-level module can import ``crs_core.analysis.angles`` without pulling in the rest.
"""
