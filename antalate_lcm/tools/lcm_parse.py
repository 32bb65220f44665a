"""Read ``.lcm`` definitions the way lcm-gen does, for the Go emitter (``tools/golang.py``).

lcm-gen 1.5.3 cannot write Go for a type with a variable-length array (docs/other-languages.md),
so antalate emits Go itself; to emit what lcm-gen would, it must see a type as lcm-gen's parser
does: the same tokens (lcmgen/tokenize.c), the same comment attached to the same declaration
(a comment documents the declaration that follows it; one inside a declaration is dropped), the
same base hash (lcmgen.c ``lcm_struct_hash``). Anything our ``lcmtypes/`` do not use and Go cannot
have (enums, structs inside structs) is refused with the file and line, not guessed at.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path

from antalate_lcm.base.errors import AntalateError

PRIMITIVES = ("int8_t", "int16_t", "int32_t", "int64_t", "byte", "float", "double", "string", "boolean")
_DIMENSION_TYPES = ("int8_t", "int16_t", "int32_t", "int64_t")
_CONST_TYPES = ("int8_t", "int16_t", "int32_t", "int64_t", "float", "double")
_INT_RANGES = {"int8_t": 8, "int16_t": 16, "int32_t": 32, "int64_t": 64}
_SINGLE_CHAR = "();\",:'[]"
_OPERATOR_CHARS = "!~<>=&|^%*+="
_MASK64 = (1 << 64) - 1


@dataclass(frozen=True)
class TypeName:
    """``full`` is lcm-gen's ``lctypename``: package-qualified for a struct, bare for a primitive."""

    full: str
    package: str
    short: str

    @property
    def primitive(self) -> bool:
        return self.full in PRIMITIVES


@dataclass(frozen=True)
class Dimension:
    """``size`` is the number as written (a constant's value for a named constant) or, when
    ``variable``, the name of the member that holds the length."""

    variable: bool
    size: str


@dataclass
class Member:
    name: str
    type: TypeName
    dimensions: list[Dimension] = field(default_factory=list)
    comment: str | None = None


@dataclass
class Constant:
    type: str
    name: str
    value: str  # as written in the file: lcm-gen copies the text, not the number
    comment: str | None = None


@dataclass
class Struct:
    name: TypeName
    source: Path
    members: list[Member] = field(default_factory=list)
    constants: list[Constant] = field(default_factory=list)
    comment: str | None = None
    file_comment: str | None = None

    def member(self, name: str) -> Member | None:
        return next((m for m in self.members if m.name == name), None)

    @property
    def base_hash(self) -> int:
        """lcm-gen's ``ls->hash`` as an unsigned 64-bit number (what the generated code embeds)."""
        v = 0x12345678
        for m in self.members:
            v = _hash_string(v, m.name)
            if m.type.primitive:
                v = _hash_string(v, m.type.full)
            v = _hash_char(v, len(m.dimensions))
            for d in m.dimensions:
                v = _hash_char(v, 1 if d.variable else 0)
                v = _hash_string(v, d.size)
        return v & _MASK64


def _signed(v: int) -> int:
    v &= _MASK64
    return v - (1 << 64) if v >> 63 else v


def _hash_char(v: int, c: int) -> int:
    # C: v = ((v << 8) ^ (v >> 55)) + c on an int64_t (arithmetic shift), c a signed char
    c = c - 256 if c > 127 else c
    return _signed(((v << 8) ^ (v >> 55)) + c)


def _hash_string(v: int, s: str) -> int:
    data = s.encode()
    v = _hash_char(v, len(data) & 0xFF)
    for byte in data:
        v = _hash_char(v, byte)
    return v


def fingerprint(struct: Struct, structs: dict[str, Struct], parents: tuple[str, ...] = ()) -> int:
    """The packed fingerprint: base hash plus the nested types' (each type once per path), rotated
    left by one; the same number as the Python classes' ``_get_packed_fingerprint()``."""
    if struct.name.full in parents:
        return 0
    v = struct.base_hash
    for m in struct.members:
        if not m.type.primitive:
            v += fingerprint(lookup(structs, m.type, struct), structs, (*parents, struct.name.full))
    v &= _MASK64
    return ((v << 1) | (v >> 63)) & _MASK64


# Encoded bytes of one primitive; a string is at least its int32 length and the NUL.
PRIMITIVE_SIZES = {
    "byte": 1,
    "boolean": 1,
    "int8_t": 1,
    "int16_t": 2,
    "int32_t": 4,
    "int64_t": 8,
    "float": 4,
    "double": 8,
    "string": 5,
}


def min_encoded_size(
    type_name: TypeName, structs: dict[str, Struct], user: Struct, parents: tuple[str, ...] = ()
) -> int:
    """The fewest bytes one value of ``type_name`` can encode to (a variable array may be empty):
    what lets a decoder refuse an array length the bytes left cannot hold before it allocates."""
    if type_name.primitive:
        return PRIMITIVE_SIZES[type_name.full]
    if type_name.full in parents:  # a type inside itself: no finite encoding, nothing to bound by
        return 0
    struct = lookup(structs, type_name, user)
    total = 0
    for m in struct.members:
        if any(d.variable for d in m.dimensions):
            continue
        count = 1
        for d in m.dimensions:
            count *= _int(d.size) or 0
        total += count * min_encoded_size(m.type, structs, struct, (*parents, type_name.full))
    return total


def lookup(structs: dict[str, Struct], type_name: TypeName, user: Struct) -> Struct:
    found = structs.get(type_name.full)
    if found is None:
        raise AntalateError(
            f"{user.source.name}: {user.name.short} uses {type_name.full}, which none of the .lcm files defines"
        )
    return found


@dataclass
class _Token:
    text: str
    line: int
    comment: bool = False


def _tokenize(text: str) -> list[_Token]:
    """lcmgen/tokenize.c: blobs end at white space, a single-character token or an operator run;
    ``//`` comments lose their leading slashes and spaces, ``/* */`` lines their leading asterisks."""
    tokens: list[_Token] = []
    i, line, n = 0, 1, len(text)
    while i < n:
        c = text[i]
        if c == "\n":
            line += 1
            i += 1
        elif c.isspace():
            i += 1
        elif text.startswith("//", i):
            i += 2
            while i < n and text[i] == "/":
                i += 1
            while i < n and text[i] == " ":
                i += 1
            end = text.find("\n", i)
            end = n if end < 0 else end
            tokens.append(_Token(text[i:end], line, comment=True))
            i = end
        elif text.startswith("/*", i):
            end = text.find("*/", i + 2)
            if end < 0:
                raise AntalateError(f"line {line}: end of file inside a /* comment")
            tokens.append(_Token(_block_comment(text[i + 2 : end]), line, comment=True))
            line += text.count("\n", i, end)
            i = end + 2
        elif c in _SINGLE_CHAR:
            tokens.append(_Token(c, line))
            i += 1
        elif c in _OPERATOR_CHARS:
            j = i
            while j < n and text[j] in _OPERATOR_CHARS:
                j += 1
            tokens.append(_Token(text[i:j], line))
            i = j
        else:
            j = i + 1
            while j < n and not text[j].isspace() and text[j] not in _SINGLE_CHAR + _OPERATOR_CHARS:
                j += 1
            tokens.append(_Token(text[i:j], line))
            i = j
    return tokens


def _block_comment(body: str) -> str:
    lines = []
    for raw in body.split("\n"):
        stripped = raw.lstrip(" \t")
        if stripped.startswith("*"):
            raw = stripped.lstrip("*")
            raw = raw[1:] if raw.startswith(" ") else raw
        if raw:
            lines.append(raw)
    return "\n".join(lines)


class _Parser:
    """lcmgen.c's recursive descent, including where it keeps and where it drops comments."""

    def __init__(self, path: Path, structs: dict[str, Struct]) -> None:
        self.path = path
        self.tokens = _tokenize(path.read_text(encoding="utf-8"))
        self.pos = 0
        self.package = ""
        self.comment_doc: str | None = None
        self.file_comment: str | None = None
        self.structs = structs

    def error(self, message: str) -> AntalateError:
        line = self.tokens[min(self.pos, len(self.tokens) - 1)].line if self.tokens else 1
        return AntalateError(f"{self.path.name}:{line}: {message}")

    def comments(self, store: bool) -> None:
        if store:
            self.comment_doc = None
        while self.pos < len(self.tokens) and self.tokens[self.pos].comment:
            if store:
                text = self.tokens[self.pos].text
                self.comment_doc = text if self.comment_doc is None else f"{self.comment_doc}\n{text}"
            self.pos += 1

    def next(self, what: str) -> str:
        self.comments(False)
        if self.pos >= len(self.tokens):
            raise self.error(f"end of file, expected {what}")
        self.pos += 1
        return self.tokens[self.pos - 1].text

    def try_consume(self, text: str) -> bool:
        self.comments(False)
        if self.pos >= len(self.tokens):
            raise self.error(f"end of file while looking for {text}")
        if self.tokens[self.pos].text == text:
            self.pos += 1
            return True
        return False

    def require(self, text: str) -> None:
        if self.next(text) != text:
            self.pos -= 1
            raise self.error(f"expected {text!r}, found {self.tokens[self.pos].text!r}")

    def take_comment(self) -> str | None:
        comment, self.comment_doc = self.comment_doc, None
        return comment

    def parse(self) -> list[Struct]:
        found: list[Struct] = []
        while True:
            self.comments(True)
            if self.pos >= len(self.tokens):
                return found
            word = self.next("a declaration")
            if word == "package":
                self.file_comment = self.take_comment()
                self.package = self.next("package name")
                self.require(";")
            elif word == "struct":
                struct = self.parse_struct()
                if struct.name.full in self.structs:
                    raise self.error(
                        f"duplicate type {struct.name.full} (also in {self.structs[struct.name.full].source.name})"
                    )
                self.structs[struct.name.full] = struct
                found.append(struct)
            elif word == "enum":
                raise self.error("enums are not supported (lcm-gen's Go emitter refuses them too)")
            else:
                raise self.error(f"expected 'package' or 'struct', found {word!r}")

    def type_name(self, text: str) -> TypeName:
        if "." in text:
            package, short = text.rsplit(".", 1)
            return TypeName(text, package, short)
        if text in PRIMITIVES:
            return TypeName(text, "", text)
        full = f"{self.package}.{text}" if self.package else text
        return TypeName(full, self.package, text)

    def parse_struct(self) -> Struct:
        name = self.type_name(self.next("struct name"))
        if not self.package:
            raise self.error(f"struct {name.short} has no package: Go needs one (add 'package NAME;')")
        struct = Struct(name, self.path, file_comment=self.file_comment, comment=self.take_comment())
        self.file_comment = None
        self.require("{")
        while True:
            self.comments(True)
            if self.try_consume("}"):
                return struct
            self.parse_member(struct)

    def check_name(self, struct: Struct, name: str) -> None:
        if not (name[:1].isalpha() or name[:1] == "_"):
            raise self.error(f"invalid member name {name!r}: must start with [a-zA-Z_]")
        if struct.member(name) or any(c.name == name for c in struct.constants):
            raise self.error(f"duplicate member name {name!r}")

    def parse_member(self, struct: Struct) -> None:
        if self.try_consume("struct") or self.try_consume("enum"):
            raise self.error("a struct or enum inside a struct is not supported")
        if self.try_consume("const"):
            self.parse_const(struct)
            return
        type_text = self.next("type identifier")
        if not (type_text[:1].isalpha() or type_text[:1] == "_"):
            raise self.error(f"invalid type name {type_text!r}")
        type_name = self.type_name(type_text)
        while True:
            name = self.next("member name")
            self.check_name(struct, name)
            member = Member(name, type_name, comment=self.take_comment())
            struct.members.append(member)
            while self.try_consume("["):
                member.dimensions.append(self.parse_dimension(struct))
                self.require("]")
            if not self.try_consume(","):
                break
        self.require(";")

    def parse_dimension(self, struct: Struct) -> Dimension:
        size = self.next("array size")
        if size[:1].isdigit():
            if _int(size) is None or (_int(size) or 0) <= 0:
                raise self.error(f"constant array size must be > 0, not {size!r}")
            return Dimension(False, size)
        constant = next((c for c in struct.constants if c.name == size), None)
        if constant is not None:
            if constant.type not in _DIMENSION_TYPES:
                raise self.error(f"array dimension {size!r} must be an integer type")
            return Dimension(False, constant.value)
        length = struct.member(size)
        if length is None:
            raise self.error(f"unknown array length {size!r}: declare the integer member before the array")
        if length.dimensions or length.type.full not in _DIMENSION_TYPES:
            raise self.error(f"array length {size!r} must be an integer member, not {length.type.full}")
        return Dimension(True, size)

    def parse_const(self, struct: Struct) -> None:
        type_text = self.next("type identifier")
        if type_text not in _CONST_TYPES:
            raise self.error(f"invalid type for const: {type_text!r}")
        while True:
            name = self.next("constant name")
            self.check_name(struct, name)
            self.require("=")
            value = self.next("constant value")
            if type_text in _INT_RANGES:
                number = _int(value)
                bits = _INT_RANGES[type_text]
                if number is None or not -(1 << (bits - 1)) <= number < (1 << (bits - 1)):
                    raise self.error(f"{value!r} is not an {type_text}")
            elif not re.fullmatch(r"[-+]?(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?", value):
                raise self.error(f"{value!r} is not a {type_text}")
            struct.constants.append(Constant(type_text, name, value, self.take_comment()))
            if not self.try_consume(","):
                break
        self.require(";")


def _int(text: str) -> int | None:
    """C's strtoll(text, NULL, 0): decimal, 0x hex or leading-0 octal, with a sign."""
    try:
        sign = -1 if text.startswith("-") else 1
        body = text.lstrip("+-")
        if re.fullmatch(r"0[xX][0-9a-fA-F]+", body):
            return sign * int(body, 16)
        if re.fullmatch(r"0[0-7]*", body):
            return sign * int(body, 8) if body != "0" else 0
        if re.fullmatch(r"[1-9][0-9]*", body):
            return sign * int(body)
    except ValueError:
        pass
    return None


def parse_files(files: list[Path]) -> dict[str, Struct]:
    """Every struct of ``files``, by full name, in file order (lcm-gen's order of emission)."""
    structs: dict[str, Struct] = {}
    for path in files:
        _Parser(path, structs).parse()
    for struct in structs.values():
        for m in struct.members:
            if not m.type.primitive:
                lookup(structs, m.type, struct)
    return structs
