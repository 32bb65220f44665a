"""Subcommands that run nodes: ``mc``, ``hlc``, ``bma``, ``osc``, ``agent``, ``station``, ``demo``, ...

Each is added here as the node it runs exists; none prints "not implemented".
"""

from __future__ import annotations

import argparse


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Add the node-running subcommands to the ``antalate`` parser."""
