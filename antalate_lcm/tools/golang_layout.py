"""How an ``.lcm`` struct maps onto Go, for the Go emitter (``tools/golang.py``) and its decoder
(``tools/golang_decode.py``): lcm-gen 1.5.3's names and types (lcmgen/emit_go.c ``go_name``,
``go_typename``), the field a member becomes, the nested loops over its arrays, and a writer that takes
Go as Go reads, so each emitted function is one block of Go text rather than a call per line.
"""

from __future__ import annotations

import string
import textwrap

from antalate_lcm.tools.lcm_parse import Member, Struct

# As with ``lcm-gen --go-tag-name lcm``: field tags `lcm:"mac_len"`, which ``go vet`` accepts;
# lcm-gen's default bare `mac_len` is not a valid tag and fails vet's structtag check.
TAG_NAME = "lcm"

BUILTIN = {
    "boolean": "bool",
    "byte": "byte",
    "int8_t": "int8",
    "int16_t": "int16",
    "int32_t": "int32",
    "int64_t": "int64",
    "float": "float32",
    "double": "float64",
    "string": "string",
}

# Methods every generated type has: a member whose Go name is one of them would not compile
# (payload_t.size is, and lcm-gen emits it as is).
_METHODS = frozenset({"Copy", "Encode", "MarshalBinary", "Decode", "UnmarshalBinary", "Size"})


def strip_dots(s: str) -> str:
    return s.rsplit(".", 1)[-1]


def _go_name(s: str) -> str:
    """``this_is.a_string`` -> ``thisIsAString`` (emit_go.c ``go_name``)."""
    out, upper = [], False
    for c in s:
        if c in "._":
            upper = True
        else:
            out.append(c.upper() if upper else c)
            upper = False
    return "".join(out)


def member_name(s: str) -> str:
    name = _go_name(s)
    return name[:1].upper() + name[1:]


def go_type(package: str, type_package: str, type_full: str) -> str:
    if type_full in BUILTIN:
        return BUILTIN[type_full]
    gotype = member_name(type_full)
    return gotype if package == type_package else f"{strip_dots(type_package)}.{gotype}"


class _Writer:
    def __init__(self) -> None:
        self.parts: list[str] = []

    def emit(self, indent: int, text: str) -> None:
        self.parts.append("\t" * indent + text + "\n")

    def start(self, indent: int, text: str) -> None:
        self.parts.append("\t" * indent + text)

    def end(self, text: str) -> None:
        self.parts.append(text + "\n")

    def nl(self) -> None:
        self.parts.append("\n")

    def comment(self, indent: int, comment: str | None) -> None:
        if comment is not None:
            for line in comment.split("\n"):
                self.emit(indent, f"// {line}")

    def go(self, indent: int, template: str, **values: object) -> None:
        """Go text at ``indent``: ``template`` is indented four spaces a level (a tab each in the output),
        its ``$name`` placeholders filled from ``values``; a line left empty is a blank line, but for
        the line after the opening quotes and the one that holds the closing quotes."""
        lines = string.Template(textwrap.dedent(template).removeprefix("\n")).substitute(values).split("\n")
        for line in lines[:-1] if lines[-1] == "" else lines:
            code = line.lstrip(" ")
            if code:
                self.emit(indent + (len(line) - len(code)) // 4, code)
            else:
                self.nl()

    def check(self, indent: int, statement: str) -> None:
        """lcm-gen's way with every call that can fail: ``if <statement>; err != nil { return }``."""
        self.go(indent, "if $statement; err != nil {\n    return\n}\n", statement=statement)


class GoStruct:
    """One struct's Go names and the shape of its arrays, what every emitted function walks."""

    def __init__(self, struct: Struct, structs: dict[str, Struct]) -> None:
        self.s = struct
        self.structs = structs
        self.w = _Writer()
        self.gotype = go_type("", "", struct.name.full)
        self.typename = struct.name.short
        getters = {member_name(m.name) + "Get" for m in struct.members if self.users(m.name, 0)}
        self.taken = _METHODS | getters

    def field(self, lcm_name: str) -> str:
        """The Go field of a member: lcm-gen's name, with golang/protobuf's trailing underscore when
        that name is a method of the type (``Size_`` beside ``Size()``), which lcm-gen does not do."""
        name = member_name(lcm_name)
        return name + "_" if name in self.taken else name

    def member_type(self, m: Member) -> str:
        return go_type(self.s.name.package, m.type.package, m.type.full)

    @staticmethod
    def array_suffix(m: Member) -> str:
        return "".join("[]" if d.variable else f"[{d.size}]" for d in m.dimensions)

    def users(self, length: str, start: int) -> list[int]:
        """Indexes (from ``start``) of the members with a dimension named ``length``."""
        members = self.s.members
        return [
            i
            for i in range(start, len(members))
            if any(d.variable and d.size == length for d in members[i].dimensions)
        ]

    def loops(self, m: Member, array: str, make_slices: bool, end: int) -> tuple[int, str]:
        """Nested ``for`` loops over the first ``end`` dimensions of ``m`` (emit_go_array_loops);
        with ``make_slices`` each variable dimension's slice is made first. Returns the loop count
        and ``array`` indexed by the loop variables."""
        slice_path = ""
        for n in range(end):
            dim = m.dimensions[n]
            if make_slices:
                slice_path = array
            array += f"[i{n}]"
            if dim.variable:
                size = self.field(dim.size)
                length = self.s.member(dim.size)
                assert length is not None  # the parser checked the length member exists
                if make_slices:
                    # emit_go_slice_make, with the element's Go type where lcm-gen crashes
                    inner = "".join("[]" if d.variable else f"[{d.size}]" for d in m.dimensions[n:])
                    self.w.emit(n + 1, f"p.{slice_path} = make({inner}{self.member_type(m)}, p.{size})")
                self.w.emit(1 + n, f"for i{n} := {BUILTIN[length.type.full]}(0); i{n} < p.{size}; i{n}++ {{")
            else:
                self.w.emit(1 + n, f"for i{n} := 0; i{n} < {dim.size}; i{n}++ {{")
        return end, array

    def loops_end(self, n: int) -> None:
        for k in range(n, 0, -1):
            self.w.emit(k, "}")

    def each_element(self, m: Member, make_slices: bool, template: str, **values: object) -> None:
        """``template`` (``$e``: the element, ``p.$e`` in Go) for ``m`` itself or, inside loops over all
        its dimensions, for each of its elements: what Copy, MarshalBinary, UnmarshalBinary and Size
        each do per member."""
        name = self.field(m.name)
        n, element = self.loops(m, name, make_slices, len(m.dimensions))
        self.w.go(n + 1, template, e=element, **values)
        self.loops_end(n)

    def scoped(self, m: Member, make_slices: bool, template: str) -> None:
        """``template`` for a member of a struct type: in a ``{ }`` block of its own when it is not an
        array (what it declares is declared once per member), per element in the loops when it is."""
        if m.dimensions:
            self.each_element(m, make_slices, template)
        else:
            self.w.emit(1, "{")
            self.w.go(2, template, e=self.field(m.name))
            self.w.emit(1, "}")

    def end_function(self) -> None:
        self.w.go(0, "    return\n}\n\n")
