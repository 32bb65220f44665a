"""The decoding half of the Go emitter (``tools/golang.py``): ``Decode`` and ``UnmarshalBinary`` as
lcm-gen 1.5.3 writes them (lcmgen/emit_go.c), plus what lcm-gen lacks.

lcm-gen's Go decoder slices past the end of a short or hostile buffer and panics (it checks only that
a string length is positive; its C decoder returns -1 instead), and makes a slice of whatever length a
datagram claims. Ours checks every read and every array length first and returns an error, one-line
``if`` each, so ``tests/tools/test_types_go.py`` can take them out and find lcm-gen's text.
"""

from __future__ import annotations

from antalate_lcm.tools.golang_layout import GoStruct
from antalate_lcm.tools.lcm_parse import PRIMITIVE_SIZES, Member, min_encoded_size

# How many empty elements (an array of zero-length arrays, an empty struct) a decoded array may
# claim beyond the bytes left: they encode to nothing, but each costs Go a slice header or a struct.
EMPTY_ELEMENTS_SLACK = 65536

# How each primitive is read at ``data[offset]`` into ``p.$e`` (emit_go.c ``emit_go_decode``), after
# our bounds check (``$need``; a string checks its length, then its bytes).
_READ_INTEGER = """
    $need
    p.$e = int$bits(binary.BigEndian.Uint$bits(data[offset:]))
    offset += $size
"""
_READ_FLOAT = """
    $need
    p.$e = math.Float${bits}frombits(binary.BigEndian.Uint$bits(data[offset:]))
    offset += $size
"""
_READ = {
    "boolean": """
        $need
        if data[offset] != 0 {
            p.$e = true
        } else {
            p.$e = false
        }
        offset += 1
    """,
    "byte": """
        $need
        p.$e = data[offset]
        offset += 1
    """,
    "int8_t": """
        $need
        p.$e = int8(data[offset])
        offset += 1
    """,
    "int16_t": _READ_INTEGER,
    "int32_t": _READ_INTEGER,
    "int64_t": _READ_INTEGER,
    "float": _READ_FLOAT,
    "double": _READ_FLOAT,
    "string": """
        {
            $need_length
            length := int(binary.BigEndian.Uint32(data[offset:]))
            offset += 4
            if length < 1 {
                return fmt.Errorf("Decoded string length is negative")
            }
            $need_string
            p.$e = string(data[offset : offset+length-1])
            offset += length
        }
    """,
}
# A member of a struct type: its own UnmarshalBinary reads it, its Size says how far that went.
_UNMARSHAL = """
    if err = p.$e.UnmarshalBinary(data[offset:]); err != nil {
        return
    }"""
_ADVANCE = """
    var size int
    if size, err = p.$e.Size(); err != nil {
        return
    }
    offset += size
"""


class GoDecoder(GoStruct):
    def decode(self) -> None:
        self.w.go(
            0,
            """
            // Decode decodes a message (fingerprint & data) from binary form
            // and verifies that the fingerprint match the expected
            //
            // param data The buffer containing the encoded message
            // returns Error
            func (p *$t) Decode(data []byte) (err error) {
                length := len(data)
                if length < 8 {
                    return fmt.Errorf("Missing fingerprint in buffer")
                }

                if fp := binary.BigEndian.Uint64(data[:8]); fp != ${t}_Fingerprint() {
                    return fmt.Errorf("Fingerprints does not match (got %x expected %x)",
                        fp, ${t}_Fingerprint())
                }

                if err = p.UnmarshalBinary(data[8:]); err != nil {
                    return
                }

                length -= 8
                var size int
                if size, err = p.Size(); err != nil {
                    return
                }
                if length != size {
                    return fmt.Errorf("Missing data in buffer (size missmatch, got %v expected %v)",
                        length, size)
                }

            """,
            t=self.gotype,
        )
        self.end_function()

    def unmarshal(self) -> None:
        w = self.w
        w.emit(0, "// UnmarshalBinary implements the BinaryUnmarshaler interface")
        w.emit(0, f"func (p *{self.gotype}) UnmarshalBinary(data []byte) (err error) {{")
        if self.s.members:
            w.emit(1, "offset := 0")
            w.nl()
        for m in self.s.members:
            what = f"{self.typename}.{m.name}"
            if any(d.variable for d in m.dimensions):
                self.array_checks(m, what)
            if m.type.primitive:
                size = PRIMITIVE_SIZES[m.type.full]
                self.each_element(
                    m,
                    True,
                    _READ[m.type.full],
                    size=size,
                    bits=size * 8,
                    need=self.need(str(size), what),
                    need_length=self.need("4", what, "string length: "),
                    need_string=self.need("length", what, "string of %d bytes: ", "length, "),
                )
            elif not m.dimensions:
                w.go(1, _UNMARSHAL, e=self.field(m.name))  # lcm-gen checks it outside the block
                self.scoped(m, True, _ADVANCE)
            else:
                self.scoped(m, True, _UNMARSHAL + _ADVANCE)
            w.nl()
        self.end_function()

    def need(self, size: str, what: str, detail: str = "", args: str = "") -> str:
        """One line (as lcm-gen never writes an ``if``, so a test can tell ours from its) that returns
        an error when fewer than ``size`` bytes are left, before a read past them would panic:
        lcm-gen's Go slices unchecked, where its C decoder returns -1. Every read is preceded by
        one, so ``0 <= offset <= len(data)`` holds throughout, and a nested type's
        ``data[offset:]`` cannot panic either (it advances by its ``Size()``, what it consumed)."""
        return (
            f"if len(data)-offset < {size} {{ return fmt.Errorf("
            f'"Missing data in buffer for {what} ({detail}%d bytes left at offset %d)", {args}len(data)-offset, offset) }}'
        )

    def array_checks(self, m: Member, what: str) -> None:
        """Refuse a decoded array length that is negative (``make`` would panic) or more than the
        bytes left can encode (``make`` would allocate what the datagram claims: gigabytes for a
        2^31 length), before the slices are made. Each prefix of the dimensions is bounded in turn,
        so no product overflows; the last by the element's fewest bytes, the others (or all, for
        elements that can encode to nothing) by the bytes left plus ``EMPTY_ELEMENTS_SLACK``."""
        w, dims = self.w, m.dimensions
        exprs = [f"int64(p.{self.field(d.size)})" if d.variable else f"int64({d.size})" for d in dims]
        seen: set[str] = set()
        for d in dims:
            if d.variable and d.size not in seen:
                seen.add(d.size)
                w.emit(
                    1,
                    f"if p.{self.field(d.size)} < 0 {{ return fmt.Errorf("
                    f'"Decoded array length of {what} is negative ({d.size} = %d)", p.{self.field(d.size)}) }}',
                )
        element = min_encoded_size(m.type, self.structs, self.s)
        left = "int64(len(data)-offset)"
        for j, d in enumerate(dims):
            last = j == len(dims) - 1
            limit = (
                (f"{left}/{element}" if element > 1 else left)
                if last and element > 0
                else f"({left}+{EMPTY_ELEMENTS_SLACK})"
            )
            guard = "".join(f"{e} > 0 && " for e, o in zip(exprs[:j], dims[:j], strict=True) if o.variable)
            divisor = "".join(f"/{e}" for e in exprs[:j])
            value = f"{d.size} = %d, " if d.variable else ""
            args = f"p.{self.field(d.size)}, " if d.variable else ""
            w.emit(
                1,
                f"if {guard}{exprs[j]} > {limit}{divisor} {{ return fmt.Errorf("
                f'"Decoded array length of {what} too long for the buffer ({value}%d bytes left)", '
                f"{args}len(data)-offset) }}",
            )
