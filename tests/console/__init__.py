"""The operator console, TUI and web.

Moved here from the flat tests/ by retest.py (issue 26).
"""
