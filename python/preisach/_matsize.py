"""Sizes of a MAT v5 file, checked before SciPy reads it.

SciPy allocates what a file's headers declare before it reads the data: an object array
of the declared dimensions for a struct or cell array, a buffer of the declared byte count
for each data element, the declared dimensions of a char array. :func:`check_v5` walks
the file's elements the way ``scipy.io.loadmat`` does, through structs, cell arrays and
objects at any depth and through compressed (``miCOMPRESSED``) elements, which it
inflates in small chunks and never holds whole. It refuses a variable whose arrays,
nested ones included, declare more than a budget of values in all, or whose elements
declare more bytes than their container holds (a compressed element that would inflate
past the budget declares so). Nothing of a declared size is allocated.
"""
from __future__ import annotations

import struct
import zlib
from typing import BinaryIO, Optional

MI_INT8, MI_INT32, MI_MATRIX, MI_COMPRESSED = 1, 5, 14, 15
#: The element types that hold numbers or characters (miINT8 .. miUINT64, miUTF8/16/32).
NUMERIC = frozenset((1, 2, 3, 4, 5, 6, 7, 9, 12, 13, 16, 17, 18))
CELL, STRUCT, OBJECT, SPARSE, FUNCTION, OPAQUE = 1, 2, 3, 5, 16, 17

#: What one array costs besides its values (the Python objects made for it), in values.
PER_ARRAY = 64

_CHUNK = 1 << 16


class _Refused(Exception):
    """A size over the budget, or an element that overruns its container."""


class MatSizeError(ValueError):
    """A variable refused before reading: ``variable`` (its name as stored) and ``detail``."""

    def __init__(self, variable: str, detail: str) -> None:
        super().__init__(f"variable {variable}: {detail}")
        self.variable, self.detail = variable, detail


class _Source:
    """Bytes of the file, or of one compressed element inflated chunk by chunk."""

    def __init__(self, f: BinaryIO, compressed: int = -1) -> None:
        self.f, self.left = f, compressed
        self.z = zlib.decompressobj() if compressed >= 0 else None

    def _chunk(self, want: int) -> bytes:
        if self.z is None:
            return self.f.read(min(want, _CHUNK))
        while True:
            if self.z.unconsumed_tail:
                data = self.z.unconsumed_tail
            elif self.left > 0 and not self.z.eof:
                data = self.f.read(min(self.left, _CHUNK))
                self.left -= len(data)
                if not data:
                    return b""
            else:
                return b""
            out = self.z.decompress(data, min(want, _CHUNK))
            if out:
                return out

    def read(self, n: int) -> bytes:
        """Exactly ``n`` bytes (each chunk is at most what is still wanted)."""
        out, got = [], 0
        while got < n:
            piece = self._chunk(n - got)
            if not piece:
                raise _Refused("the file ends inside an element")
            out.append(piece)
            got += len(piece)
        return b"".join(out)

    def skip(self, n: int) -> None:
        if self.z is None:
            self.f.seek(n, 1)  # within the file: the caller checked the element's room
            return
        while n > 0:
            n -= len(self.read(min(n, _CHUNK)))


class _Walk:
    """The elements of one variable, its values counted against ``budget``."""

    def __init__(self, src: _Source, endian: str, budget: int) -> None:
        self.src, self.e, self.budget, self.spent = src, endian, budget, 0
        self.name = ""
        #: The inflated size a compressed variable declares, checked once its name is read.
        self.inflated: Optional[int] = None

    def spend(self, where: str, n: int, what: str) -> None:
        self.spent += n
        if self.spent > self.budget:
            raise _Refused(f"{where} {what}: the variable would hold more than the limit of {self.budget} "
                           f"values (1 GiB of doubles)")

    def tag(self, room: int) -> tuple[int, int, Optional[bytes], int]:
        """(type, byte count, data of a small element or None, bytes the element takes)."""
        if room < 8:
            raise _Refused("an element overruns its container")
        head = self.src.read(8)
        a, b = struct.unpack(self.e + "II", head)
        if a >> 16:
            return a & 0xFFFF, a >> 16, head[4:4 + (a >> 16)], 8
        size = 8 + b + (-b % 8)
        if size > room:
            raise _Refused(f"an element declares {b} bytes, more than the {room - 8} its container holds")
        return a, b, None, size

    def data(self, room: int, most: int) -> tuple[bytes, int]:
        """A small data element's bytes (at most ``most``), and the bytes it took."""
        _, n, small, size = self.tag(room)
        if small is not None:
            return small, size
        if n > most:
            raise _Refused(f"a header element declares {n} bytes")
        got = self.src.read(n)
        self.src.skip(size - 8 - n)
        return got, size

    def matrix(self, room: int, where: str) -> tuple[str, int]:
        """Walk one miMATRIX element (its tag read already; ``room``: its byte count)."""
        if room == 0:
            return where, 0
        flags, used = self.data(room, 64)
        word = struct.unpack(self.e + "I", flags[:4])[0] if len(flags) >= 4 else 0
        cls, complex_ = word & 0xFF, bool(word & 0x800)
        if cls in (FUNCTION, OPAQUE):
            return where, used + self.rest(room - used, where)
        raw, k = self.data(room - used, 4096)
        used += k
        name, k = self.data(room - used, 1 << 16)
        used += k
        where = where or name.decode("latin1")
        self.name = self.name or where
        if self.inflated is not None and self.inflated > 8 * self.budget + (1 << 20):
            raise _Refused(f"its compressed element inflates to {self.inflated} bytes, above the limit of "
                           f"{8 * self.budget} (1 GiB)")
        self.inflated = None
        dims = struct.unpack(f"{self.e}{len(raw) // 4}i", raw[: len(raw) // 4 * 4])
        if any(d < 0 for d in dims):
            raise _Refused(f"{where} declares a negative dimension {'x'.join(map(str, dims))}")
        count = 1
        for d in dims:
            count *= d
        self.spend(where, PER_ARRAY + (0 if cls == SPARSE else count),
                   f"declares {'x'.join(map(str, dims))} = {count} values")
        if cls == CELL:
            for i in range(count):
                used += self.sub(room - used, f"{where}{{{i + 1}}}")
        elif cls in (STRUCT, OBJECT):
            used += self.fields(room - used, where, count, cls == OBJECT)
        else:  # numeric, char, logical, sparse: its data elements, each of a numeric type
            parts = (3 if cls == SPARSE else 1) + complex_
            used += self.numbers(room - used, where, parts, None if cls == SPARSE else 8 * max(count, 1))
        return where, used

    def numbers(self, room: int, where: str, parts: int, most: Optional[int]) -> int:
        """The ``parts`` data elements of an array (real, imaginary; a sparse array's
        indices first), each of a numeric type: SciPy crashes reading an element of
        another type (an array's tag) as numbers."""
        used = 0
        for _ in range(parts):
            kind, n, small, size = self.tag(room - used)
            if kind not in NUMERIC:
                raise _Refused(f"{where}: element of type {kind} where its numbers belong")
            if most is not None and n > most:
                raise _Refused(f"{where} declares {n} bytes of data for {most // 8} values")
            if most is None:
                self.spend(where, n // 8, f"declares {n} bytes of data")
            if small is None:
                self.src.skip(size - 8)
            used += size
        return used

    def sub(self, room: int, where: str) -> int:
        """One nested miMATRIX element; the bytes it took."""
        kind, n, _, size = self.tag(room)
        if kind != MI_MATRIX:
            raise _Refused(f"{where}: element of type {kind} where an array belongs")
        self.matrix(min(n, size - 8), where)
        return size

    def fields(self, room: int, where: str, count: int, named_class: bool) -> int:
        used = 0
        if named_class:
            used += self.data(room, 1 << 16)[1]
        raw, k = self.data(room - used, 8)
        used += k
        length = struct.unpack(self.e + "i", raw[:4])[0] if len(raw) >= 4 else 0
        names_raw, k = self.data(room - used, 1 << 20)
        used += k
        names = [names_raw[i:i + length].split(b"\0")[0].decode("latin1")
                 for i in range(0, len(names_raw) - length + 1, length)] if length > 0 else []
        self.spend(where, len(names) * count, f"declares {count} x {len(names)} fields")
        for i in range(count):
            at = f"{where}({i + 1})" if count > 1 else where
            for field in names:
                used += self.sub(room - used, f"{at}.{field}")
        return used

    def rest(self, room: int, where: str, most: Optional[int] = None) -> int:
        """Data elements and nested arrays up to the end of the container."""
        used = 0
        while room - used >= 8:
            kind, n, small, size = self.tag(room - used)
            if kind == MI_MATRIX:
                self.matrix(n, where)
            elif small is None:
                if most is not None and n > most:
                    raise _Refused(f"{where} declares {n} bytes of data for {most // 8} values")
                if most is None:
                    self.spend(where, n // 8, f"declares {n} bytes of data")
                self.src.skip(size - 8)
            used += size
        return used


def check_v5(f: BinaryIO, size: int, budget: int) -> None:
    """Walk every variable of the MAT v5 file ``f`` (``size`` bytes); raise
    :class:`MatSizeError` for one over ``budget`` values, or one whose elements overrun."""
    head = f.read(128)
    endian = ">" if head[126:128] == b"MI" else "<"
    pos = 128
    while size - pos >= 8:
        f.seek(pos)
        kind, n = struct.unpack(endian + "II", f.read(8))
        where = f"at byte {pos}"
        if n > size - pos - 8:
            raise MatSizeError(where, f"declares {n} bytes, more than the {size - pos - 8} left in the file")
        src = _Source(f, n if kind == MI_COMPRESSED else -1)
        walk = _Walk(src, endian, budget)
        try:
            room = n
            if kind == MI_COMPRESSED:
                kind, room = struct.unpack(endian + "II", src.read(8))
                walk.inflated = room
            if kind == MI_MATRIX:
                walk.matrix(room, "")
        except _Refused as exc:
            raise MatSizeError(walk.name or where, str(exc)) from None
        except zlib.error as exc:
            raise MatSizeError(walk.name or where, f"corrupt compressed data ({exc})") from None
        pos += 8 + n
