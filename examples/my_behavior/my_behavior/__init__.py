"""Worked example of an antalate behavior plugin (see docs/behaviors.md)."""

from my_behavior.circle import Circle

__all__ = ["Circle"]
