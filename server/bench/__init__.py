"""Benchmark commands (``teachrepeat bench ...``): each prints a table and saves JSON."""
