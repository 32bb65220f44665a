"""The node and what it stands on: executor, ticker, config and the plugin plan, the peer table,
geodesy, and signing, verification and the insecure-exposure policy.

Moved here from the flat tests/ by retest.py (issue 26).
"""
