"""The guards every commit runs: the layer map, ruff/mypy, dead code, the public API, the docs'
examples, optional extras and the installed wheel.

Moved here from the flat tests/ by retest.py (issue 26).
"""
