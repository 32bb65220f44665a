"""lcm-gen's field tables of a generated message class, typed.

``__slots__``, ``__typenames__`` and ``__dimensions__`` are what lcm-gen emits on every class, and the
tests that walk every field read them; antalate's ``topics.Message`` protocol (what the product relies on)
does not declare them, so a table of mixed types (``MESSAGE_TYPES``) reaches them through the class dict.
"""

from __future__ import annotations


def slots(cls: type) -> list[str]:
    """The field names, in wire order."""
    return [str(name) for name in vars(cls)["__slots__"]]


def typenames(cls: type) -> list[str]:
    """Each field's LCM type (``int8_t``, ``string``, ``antalate_lcm.msgs.header_t``…)."""
    return [str(name) for name in vars(cls)["__typenames__"]]


def dimensions(cls: type) -> list[list[str | int] | None]:
    """Each field's array dimensions (a length field's name or a fixed size), None for a scalar."""
    dims: list[list[str | int] | None] = vars(cls)["__dimensions__"]
    return dims


def fingerprint(cls: type) -> bytes:
    """The packed fingerprint every encoded message starts with (a static method lcm-gen emits)."""
    packed: bytes = vars(cls)["_get_packed_fingerprint"]()
    return packed
