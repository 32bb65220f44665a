"""Buses and transports (udpm and its own reader, zenoh, the LCM datagram format, the bridge): what
a bus URL opens and what crosses it.

Moved here from the flat tests/ by retest.py (issue 26).
"""
