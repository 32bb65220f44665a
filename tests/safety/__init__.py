"""The safety filter, geofences, failsafes and the velocity guard, and the fence mirrored to the
autopilot: what keeps a vehicle inside its limits whatever it is told.

Moved here from the flat tests/ by retest.py (issue 26).
"""
