"""Tests of the benchmarks' own tools (results and sections, statistics, measures): run with the suite
(``pyproject.toml``'s ``testpaths``). The service and its engines are tested in ``tests/``; what both use is
``harness/``."""
