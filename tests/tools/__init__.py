"""Tools around the swarm: spy, the type emitters (Go, C), analysis and metrics, MCAP and Foxglove.

Moved here from the flat tests/ by retest.py (issue 26).
"""
