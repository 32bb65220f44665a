"""Programs the tests start as child processes (``python -m tests.children.NAME``), kept as modules so
ruff and mypy check them like the rest of the suite. Each reads its arguments from ``sys.argv`` and
speaks to its test over stdout, as its docstring says."""
