"""One agent's nodes: the MC and HLC machines and their engine, the BMA and the shipped behaviors,
the OSC, and whole agents flown end to end in one or several processes.

Moved here from the flat tests/ by retest.py (issue 26).
"""
