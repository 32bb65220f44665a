"""The command line: its one table of subcommands, and the demo it launches.

Moved here from the flat tests/ by retest.py (issue 26).
"""
