"""Behavior plugins shipped with antalate (docs/design.md §8)."""
