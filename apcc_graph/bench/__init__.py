"""Benchmarks behind ``apcc-graph bench ...``: each returns a result object with its figures and
the ratios against the peers measured in the same run. They are commands, never timed tests."""
