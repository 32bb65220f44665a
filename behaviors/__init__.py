"""Behavior plugins shipped with antalate (DESIGN §8)."""
