"""The applications layer: commands built on the layers below that no node needs: bridge, spy, types, MCAP
export, Foxglove, the MAVLink GCS, log analysis; above the console, whose loopback check the Foxglove
server shares. One folder is one layer (docs/architecture.md, "Layers"; tests/architecture/test_layers.py): a module
here imports this folder and the layers below, never one above. It holds ``analysis``, ``bridge``,
``foxglove_server``, ``gcs``, ``mcap_record``, ``spy``, ``types_cmd``.
"""
