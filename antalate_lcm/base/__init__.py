"""The base layer: what every layer uses and that knows no message and does no I/O: the exception root, rate
limits, strict pydantic checks, plugin lookup, geodesy, the state-machine engine, the safety geometry.
One folder is one layer (docs/architecture.md, "Layers"; tests/architecture/test_layers.py): a module here imports
this folder and the layers below, never one above. It holds ``deprecation``, ``errors``, ``geo``, ``plugins``,
``ratelimit``, ``safety``, ``state_machine``, ``strict``.
"""
