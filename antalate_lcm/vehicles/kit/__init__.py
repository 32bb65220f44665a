"""The vehicle kit: the one version of what every vehicle adapter (and its protocol emulator) is built from.

* `params` -- the params base model (closed, strict, finite) and the parser that names the key;
* `adapter` -- `LinkedAdapter` (params, link opener, worker threads), `LinkAge`, `Workers`;
* `memory` -- `MemoryPipe`, the in-memory link seam each protocol's ``MemoryLink`` frames.

An adapter package is then its params model, its protocol modules, its link and an adapter class
holding only what its vehicle makes different.
"""

from antalate_lcm.vehicles.kit.adapter import LinkAge, LinkedAdapter, Workers
from antalate_lcm.vehicles.kit.memory import MemoryPipe
from antalate_lcm.vehicles.kit.params import AdapterParams, defaults, parse_params

__all__ = [
    "AdapterParams",
    "LinkAge",
    "MemoryPipe",
    "LinkedAdapter",
    "Workers",
    "defaults",
    "parse_params",
]
