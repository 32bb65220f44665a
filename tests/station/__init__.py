"""The ground station: its API, authentication, sectors and fuzzing.

Moved here from the flat tests/ by retest.py (issue 26).
"""
