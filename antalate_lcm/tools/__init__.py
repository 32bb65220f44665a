"""The message contract's tooling: what turns ``lcmtypes/*.lcm`` into code and reads it back.

* `codegen` -- runs ``lcm-gen`` (Python, Java), writes each generated module's typed stub, and the
  staleness checks the tests use (``make gen`` is ``python -m antalate_lcm.tools.codegen``);
* `lcm_parse` -- reads ``.lcm`` files the way lcm-gen does (structs, constants, comments, fingerprints),
  for the Go emitter and for `antalate_lcm.wire.lcm_json`;
* `golang` -- lcm-gen 1.5.3's Go emitter ported to Python (``antalate types --lang go``,
  docs/other-languages.md), with `golang_layout` (Go names, array loops, the writer) and
  `golang_decode` (the decoder, bounds-checked).

Build-time code, kept out of the package's top level so that the top level is the public surface; it
sits in the base layer (docs/architecture.md) because `lcm_json` reads the contract through it.
"""
