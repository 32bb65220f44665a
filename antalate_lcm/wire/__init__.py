"""The wire layer: the messages as antalate uses them, pure: the vocabulary, the topic table, field
validation, the fast codec, signing and verification, the peer table, JSON views of messages. One folder
is one layer (docs/architecture.md, "Layers"; tests/architecture/test_layers.py): a module here imports this folder
and the layers below, never one above. It holds ``fastcodec``, ``foxglove_msgs``, ``json_view``,
``lcm_json``, ``peers``, ``security``, ``topics``, ``validation``, ``vocabulary``.
"""
