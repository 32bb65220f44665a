"""The core layer: what runs a node: the executor and simulated clock, the bus, the config, the node and the
behavior contract, the LCM log reader and the MCAP log writer. One folder is one layer (docs/architecture.md, "Layers";
tests/architecture/test_layers.py): a module here imports this folder and the layers below, never one above. It holds
``behavior``, ``bus``, ``config``, ``executor``, ``lcm_log``, ``mcap_log``, ``node``, ``simclock``.
"""
