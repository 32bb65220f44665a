"""Experiments: simulated time, sweeps, scripted faults, replay.

Moved here from the flat tests/ by retest.py (issue 26).
"""
