"""The agent layer: the nodes of one agent: MC, HLC, BMA, OSC, and ``plan.py``, the one plugin-loading path
they share. One folder is one layer (docs/architecture.md, "Layers"; tests/architecture/test_layers.py): a module here
imports this folder and the layers below, never one above. It holds ``bma``, ``hlc``, ``mc``, ``osc``,
``plan``.
"""
