"""Assembling and running nodes: one node, one agent, or many agents in one process."""
