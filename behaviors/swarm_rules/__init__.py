"""Canonical swarm rules on the peer table (docs/behaviors.md §9): gathering, flocking, dispersion.

``logic`` holds the pure rules (vectors in, a velocity out, no clock, no I/O); ``behavior`` the thin
plugins that feed them from ``ctx.peers`` and publish NED velocity commands.
"""
