"""The PLY file format: header, elements and properties, in every encoding, read and written with NumPy.

A PLY file is a header (``ply``, ``format <encoding> 1.0``, ``comment``/``obj_info``
lines, ``element <name> <count>`` each followed by its ``property <type> <name>``
or ``property list <count type> <value type> <name>`` lines, ``end_header``) and
then the rows of every element in header order.  Encodings: ``ascii`` (whitespace
separated numbers), ``binary_little_endian`` and ``binary_big_endian``.  Scalar
types: char/int8, uchar/uint8, short/int16, ushort/uint16, int/int32,
uint/uint32, float/float32, double/float64.

Reading is vectorised for every shape of element.  The body is one array of
*units* — bytes for binary files, number tokens (parsed in bulk) for ascii — and
an element is a walk over its properties that gives, for all rows at once, where
each value sits.  Rows whose lists all have the length of the first row's (a
triangle mesh) are placed in one pass; lists of varying length are placed by
pointer doubling (the row that follows a start offset is computed for every
offset, then composed log2(rows) times), so no Python loop runs over rows.  An
ascii file needs no line structure: a row may span or share lines.

``read_ply`` returns a ``PlyData``: scalar properties as (n,) arrays of their
declared type, list properties as ``PlyList`` (counts and the values of all rows
concatenated).  ``write_ply`` writes the same structure in any encoding
(atomically).  Errors are ``PlyFormatError`` naming the file, the line or the
element and property, and the problem.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike, NDArray

ENCODINGS = ("ascii", "binary_little_endian", "binary_big_endian")
SCALAR_TYPES = {
    "char": "i1",
    "int8": "i1",
    "uchar": "u1",
    "uint8": "u1",
    "short": "i2",
    "int16": "i2",
    "ushort": "u2",
    "uint16": "u2",
    "int": "i4",
    "int32": "i4",
    "uint": "u4",
    "uint32": "u4",
    "float": "f4",
    "float32": "f4",
    "double": "f8",
    "float64": "f8",
}
_TYPE_NAMES = {  # NumPy type code -> the name written in headers
    "i1": "char",
    "u1": "uchar",
    "i2": "short",
    "u2": "ushort",
    "i4": "int",
    "u4": "uint",
    "f4": "float",
    "f8": "double",
}
_BYTE_ORDER = {"binary_little_endian": "<", "binary_big_endian": ">"}
I64 = NDArray[np.int64]


class PlyFormatError(ValueError):
    """A .ply file is malformed, or lacks what its reader needs."""


@dataclass(frozen=True)
class PlyProperty:
    """One property: ``dtype`` is a NumPy type code without byte order ("f4", "u1", ...); a list property
    also has the type of its per-row length, ``count_dtype``."""

    name: str
    dtype: str
    count_dtype: str | None = None

    @property
    def is_list(self) -> bool:
        return self.count_dtype is not None


@dataclass(frozen=True)
class PlyElement:
    name: str
    count: int
    properties: tuple[PlyProperty, ...]


@dataclass(frozen=True)
class PlyHeader:
    encoding: str
    elements: tuple[PlyElement, ...]
    comments: tuple[str, ...]
    data_offset: int
    """Bytes from the start of the file to the first row."""


@dataclass(frozen=True)
class PlyList:
    """The values of a list property: ``counts`` (n,) per row and ``values`` (sum(counts),) in row order."""

    counts: I64
    values: NDArray[np.generic]

    def __post_init__(self) -> None:
        counts = np.asarray(self.counts, np.int64)
        if counts.ndim != 1 or np.any(counts < 0) or int(counts.sum()) != len(self.values):
            raise ValueError(
                f"PlyList: counts must be >= 0 and sum to len(values) = {len(self.values)}, "
                f"got sum {counts.sum()}"
            )
        object.__setattr__(self, "counts", counts)

    @property
    def offsets(self) -> I64:
        """(n + 1,) start of each row in ``values`` and the total."""
        return np.concatenate([[0], np.cumsum(self.counts)])

    def __len__(self) -> int:
        return len(self.counts)


@dataclass(frozen=True)
class PlyData:
    """A read .ply file: ``elements[name][property]`` is an (n,) array or a ``PlyList``."""

    path: Path
    header: PlyHeader
    elements: dict[str, dict[str, NDArray[np.generic] | PlyList]]

    def element(self, name: str) -> dict[str, NDArray[np.generic] | PlyList]:
        if name not in self.elements:
            raise PlyFormatError(f"{self.path}: no element {name!r}; elements: {list(self.elements)}")
        return self.elements[name]


# --------------------------------------------------------------------------- #
# Header
# --------------------------------------------------------------------------- #
def _type(path: Path, number: int, name: str) -> str:
    if name not in SCALAR_TYPES:
        raise PlyFormatError(
            f"{path}: header line {number}: unknown type {name!r}; allowed: {', '.join(SCALAR_TYPES)}"
        )
    return SCALAR_TYPES[name]


def parse_header(path: Path, raw: bytes) -> PlyHeader:
    """The header of a .ply file's bytes; raises ``PlyFormatError`` naming the line and the problem."""
    end = raw.find(b"end_header")
    if not raw.startswith(b"ply") or end < 0:
        raise PlyFormatError(f"{path}: not a .ply file (missing 'ply' magic or 'end_header')")
    nl = raw.find(b"\n", end)
    if nl < 0:
        raise PlyFormatError(f"{path}: header ends without a newline after 'end_header'")
    try:
        text = raw[:end].decode("ascii")
    except UnicodeDecodeError as exc:
        raise PlyFormatError(f"{path}: the header holds non-ASCII bytes (at byte {exc.start})") from None
    lines = text.splitlines()
    if lines[0].strip() != "ply":
        raise PlyFormatError(f"{path}: first line must be 'ply', got {lines[0]!r}")
    encoding = None
    comments: list[str] = []
    elements: list[tuple[str, int, list[PlyProperty]]] = []
    for number, line in enumerate(lines[1:], start=2):
        tok = line.split()
        if not tok:
            continue
        key = tok[0]
        if key in ("comment", "obj_info"):
            comments.append(line.strip()[len(key) :].strip())
        elif key == "format":
            if len(tok) != 3 or tok[1] not in ENCODINGS or tok[2] != "1.0":
                raise PlyFormatError(
                    f"{path}: header line {number}: format {' '.join(tok[1:])!r} not supported; "
                    f"need one of {', '.join(e + ' 1.0' for e in ENCODINGS)}"
                )
            encoding = tok[1]
        elif key == "element":
            if len(tok) != 3 or not tok[2].isdigit():
                raise PlyFormatError(f"{path}: header line {number}: malformed element line {line!r}")
            if any(e[0] == tok[1] for e in elements):
                raise PlyFormatError(f"{path}: header line {number}: element {tok[1]!r} declared twice")
            elements.append((tok[1], int(tok[2]), []))
        elif key == "property":
            if not elements:
                raise PlyFormatError(f"{path}: header line {number}: property {line!r} before any element")
            if len(tok) == 5 and tok[1] == "list":
                count = _type(path, number, tok[2])
                if count[0] == "f":
                    raise PlyFormatError(
                        f"{path}: header line {number}: list count type {tok[2]!r} must be an integer type"
                    )
                prop = PlyProperty(tok[4], _type(path, number, tok[3]), count)
            elif len(tok) == 3:
                prop = PlyProperty(tok[2], _type(path, number, tok[1]))
            else:
                raise PlyFormatError(f"{path}: header line {number}: malformed property line {line!r}")
            props = elements[-1][2]
            if any(p.name == prop.name for p in props):
                raise PlyFormatError(
                    f"{path}: header line {number}: property {prop.name!r} of element {elements[-1][0]!r} "
                    "declared twice"
                )
            props.append(prop)
        else:
            raise PlyFormatError(f"{path}: header line {number}: unknown keyword {key!r} in {line!r}")
    if encoding is None:
        raise PlyFormatError(f"{path}: the header has no 'format' line")
    return PlyHeader(
        encoding,
        tuple(PlyElement(name, count, tuple(props)) for name, count, props in elements),
        tuple(comments),
        nl + 1,
    )


# --------------------------------------------------------------------------- #
# Body: units (bytes or tokens) and vectorised row walks
# --------------------------------------------------------------------------- #
class _Units:
    """The body as units: bytes (binary) or number tokens parsed to float64 (ascii)."""

    def __init__(self, path: Path, encoding: str, body: bytes) -> None:
        self.path = path
        self.ascii = encoding == "ascii"
        self.order = _BYTE_ORDER.get(encoding, "")
        if self.ascii:
            try:
                # text mode: any run of whitespace separates numbers
                self.data = np.fromstring(body, dtype=np.float64, sep=" ")
            except ValueError:
                raise PlyFormatError(_bad_token_message(path, body)) from None
        else:
            self.data = np.frombuffer(body, np.uint8)

    def __len__(self) -> int:
        return len(self.data)

    def size(self, dtype: str) -> int:
        """Units one value of ``dtype`` takes."""
        return 1 if self.ascii else np.dtype(dtype).itemsize

    def read(self, dtype: str, positions: I64, what: str) -> NDArray[np.generic]:
        """Values of ``dtype`` starting at each position (all inside the body)."""
        if self.ascii:
            values = self.data[positions]
            if dtype[0] == "f":
                return values.astype(dtype)
            info = np.iinfo(dtype)
            bad = (values != np.floor(values)) | (values < info.min) | (values > info.max)
            if np.any(bad):
                v = float(values[np.flatnonzero(bad)[0]])
                raise PlyFormatError(
                    f"{self.path}: {what}: ascii value {v:g} is not a {_TYPE_NAMES[dtype]} "
                    f"(an integer in [{info.min}, {info.max}])"
                )
            return values.astype(dtype)
        size = np.dtype(dtype).itemsize
        gathered = self.data[positions[:, None] + np.arange(size)]
        return np.ascontiguousarray(gathered).view(self.order + dtype).reshape(-1).astype(dtype)

    def counts(self, dtype: str, positions: I64) -> I64:
        """List lengths at ``positions``; -1 where a position is outside the body or the length is negative."""
        size = self.size(dtype)
        inside = positions + size <= len(self)
        out = np.full(len(positions), -1, np.int64)
        if self.ascii:
            values = self.data[positions[inside]]
            whole = (values == np.floor(values)) & (values >= 0)
            out[np.flatnonzero(inside)[whole]] = values[whole].astype(np.int64)
            return out
        values = self.read(dtype, positions[inside], "list length").astype(np.int64)
        out[inside] = np.where(values >= 0, values, -1)
        return out


def _bad_token_message(path: Path, body: bytes) -> str:
    """Names the first ascii token that is not a number (bisection on the longest prefix that parses)."""
    tokens = body.split()
    good, bad = 0, len(tokens)  # tokens[:good] parse, tokens[:bad] do not
    while bad - good > 1:  # log2(tokens) rounds, each a bulk parse
        mid = (good + bad) // 2
        try:
            np.fromstring(b" ".join(tokens[:mid]), dtype=np.float64, sep=" ")
            good = mid
        except ValueError:
            bad = mid
    first_bad = bad - 1
    token = tokens[first_bad]
    text = token[:24].decode("ascii", errors="replace") + ("..." if len(token) > 24 else "")
    hint = "; the body is not text: is the header's format line right?" if not body.isascii() else ""
    return f"{path}: ascii body: token {first_bad} ({text!r}) is not a number{hint}"


def _walk(units: _Units, element: PlyElement, starts: I64) -> tuple[I64, list[tuple[I64, I64 | None]]]:
    """Row ends (end of body + 1 where a row cannot be read) and, per property, the positions of its
    values (scalars) or (first value, counts) (lists), for rows starting at ``starts``."""
    end = len(units)
    bad = np.full(len(starts), False)
    off = starts.copy()
    places: list[tuple[I64, I64 | None]] = []
    for prop in element.properties:  # loop over properties, vectorised over rows
        if prop.count_dtype is None:
            places.append((off.copy(), None))
            off = off + units.size(prop.dtype)
            continue
        counts = units.counts(prop.count_dtype, np.minimum(off, end))
        bad |= counts < 0
        counts = np.maximum(counts, 0)
        first = off + units.size(prop.count_dtype)
        places.append((first, counts))
        off = first + counts * units.size(prop.dtype)
    return np.where(bad | (off > end), end + 1, off), places


def _row_starts(units: _Units, element: PlyElement, start: int, path: Path) -> I64:
    """Start (in units) of every row of ``element``, its first row at ``start``."""
    n = element.count
    if n == 0:
        return np.zeros(0, np.int64)
    end = len(units)
    first_end, _ = _walk(units, element, np.array([start]))
    row = int(first_end[0]) - start
    if first_end[0] > end:
        raise PlyFormatError(
            f"{path}: truncated: element {element.name!r} (header: {n} rows) ends at row 0 of {n}"
        )
    starts = start + row * np.arange(n, dtype=np.int64)
    if all(not p.is_list for p in element.properties):
        if starts[-1] + row > end:
            raise PlyFormatError(
                f"{path}: truncated: element {element.name!r} needs {n * row} "
                f"{'tokens' if units.ascii else 'bytes'} for its {n} rows but {end - start} follow"
            )
        return starts
    ends, _ = _walk(units, element, starts[starts + row <= end])
    if len(ends) == n and np.all(ends - starts == row):
        return starts  # every list as long as in the first row (e.g. a triangle mesh)
    # pointer doubling: successor of every possible start offset, composed log2(n) times
    candidates = np.arange(start, end + 1, dtype=np.int64)
    nxt, _ = _walk(units, element, candidates)
    nxt = np.minimum(nxt, end + 1)
    jump = np.concatenate([nxt, [end + 1, end + 1]]) - start  # index = offset - start; end + 1 is a sink
    pos = np.full(n, start, np.int64)
    rank = np.arange(n, dtype=np.int64)
    bit = 0
    while (1 << bit) < n:  # log2(n) rounds, each vectorised over rows
        sel = ((rank >> bit) & 1).astype(bool)
        pos[sel] = jump[pos[sel] - start] + start
        jump = jump[jump]
        bit += 1
    last_end, _ = _walk(units, element, pos[-1:])
    if pos[-1] > end or last_end[0] > end:
        good = int(np.searchsorted(pos > end, True))
        raise PlyFormatError(
            f"{path}: truncated or malformed: element {element.name!r} (header: {n} rows) cannot be read "
            f"past row {min(good, n - 1)} (a list length is negative or runs past the end of the file)"
        )
    return pos


def _read_element(
    units: _Units, element: PlyElement, start: int, path: Path
) -> tuple[dict[str, NDArray[np.generic] | PlyList], int]:
    """The columns of ``element`` whose first row starts at unit ``start``, and the unit after its last row."""
    if not units.ascii and not any(p.is_list for p in element.properties):  # fixed rows: one structured view
        dtype = np.dtype([(p.name, units.order + p.dtype) for p in element.properties])
        need = element.count * dtype.itemsize
        if start + need > len(units):
            raise PlyFormatError(
                f"{path}: truncated: element {element.name!r} needs {need} bytes for its {element.count} rows "
                f"but {len(units) - start} follow"
            )
        rows = units.data[start : start + need].view(dtype)
        return {p.name: rows[p.name].astype(p.dtype) for p in element.properties}, start + need
    starts = _row_starts(units, element, start, path)
    if element.count == 0:
        none = np.zeros(0, np.int64)
        return {p.name: PlyList(none, np.zeros(0, p.dtype)) if p.is_list else np.zeros(0, p.dtype)
                for p in element.properties}, start  # fmt: skip
    ends, places = _walk(units, element, starts)
    out: dict[str, NDArray[np.generic] | PlyList] = {}
    for prop, (pos, counts) in zip(element.properties, places):
        what = f"element {element.name!r} property {prop.name!r}"
        if counts is None:
            out[prop.name] = units.read(prop.dtype, pos, what)
            continue
        total = int(counts.sum())
        row_of = np.repeat(np.arange(len(counts)), counts)
        rank = np.arange(total) - np.repeat(np.cumsum(counts) - counts, counts)
        flat = pos[row_of] + rank * units.size(prop.dtype)
        out[prop.name] = PlyList(counts, units.read(prop.dtype, flat, what))
    return out, int(ends[-1])


def read_ply(path: str | os.PathLike[str]) -> PlyData:
    """Read every element of a .ply file in any encoding; errors name the file and the problem."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f".ply file not found: {path}")
    raw = path.read_bytes()
    header = parse_header(path, raw)
    units = _Units(path, header.encoding, raw[header.data_offset :])
    elements = {}
    offset = 0
    for element in header.elements:  # loop over elements
        elements[element.name], offset = _read_element(units, element, offset, path)
    if units.ascii and offset != len(units):
        raise PlyFormatError(
            f"{path}: the ascii body holds {len(units) - offset} numbers more than its header's elements "
            f"({', '.join(f'{e.name} x {e.count}' for e in header.elements)})"
        )
    return PlyData(path, header, elements)


# --------------------------------------------------------------------------- #
# Writing
# --------------------------------------------------------------------------- #
def _property_for(name: str, value: NDArray[np.generic] | PlyList) -> PlyProperty:
    if isinstance(value, PlyList):
        count = "u1" if len(value.counts) == 0 or value.counts.max() < 256 else "i4"
        return PlyProperty(name, _code(name, value.values), count)
    return PlyProperty(name, _code(name, value))


def _code(name: str, array: NDArray[np.generic]) -> str:
    code = np.dtype(array.dtype).str[1:]
    if code not in _TYPE_NAMES:
        raise ValueError(
            f"write_ply: property {name!r} has dtype {array.dtype}; PLY holds {sorted(_TYPE_NAMES)}"
        )
    return code


def _layout(
    element: PlyElement, columns: Mapping[str, NDArray[np.generic] | PlyList], size: Callable[[str], int]
) -> tuple[I64, list[tuple[I64, I64 | None]], int]:
    """Rows laid out back to back, in units of ``size(type code)``: row starts, per property the position
    of its value (scalars) or of its length and first value (lists), and the total length."""
    lengths = np.zeros(element.count, np.int64)
    for prop in element.properties:
        value = columns[prop.name]
        if isinstance(value, PlyList):
            lengths += size(str(prop.count_dtype)) + value.counts * size(prop.dtype)
        else:
            lengths += size(prop.dtype)
    ends = np.cumsum(lengths)
    off = ends - lengths
    starts = off.copy()
    places: list[tuple[I64, I64 | None]] = []
    for prop in element.properties:  # loop over properties, vectorised over rows
        value = columns[prop.name]
        if isinstance(value, PlyList):
            places.append((off.copy(), off + size(str(prop.count_dtype))))
            off = off + size(str(prop.count_dtype)) + value.counts * size(prop.dtype)
        else:
            places.append((off.copy(), None))
            off = off + size(prop.dtype)
    return starts, places, int(ends[-1]) if len(ends) else 0


def _flat_positions(first: I64, counts: I64, size: int) -> I64:
    rank = np.arange(int(counts.sum())) - np.repeat(np.cumsum(counts) - counts, counts)
    return np.repeat(first, counts) + rank * size


def _itemsize(code: str) -> int:
    return np.dtype(code).itemsize


def _element_bytes(
    element: PlyElement, columns: Mapping[str, NDArray[np.generic] | PlyList], order: str
) -> bytes:
    """The rows of ``element`` in a binary encoding (``order`` "<" or ">"), scattered byte-wise at once."""
    if not any(isinstance(v, PlyList) for v in columns.values()):  # fixed rows: one structured array
        rows = np.empty(element.count, np.dtype([(p.name, order + p.dtype) for p in element.properties]))
        for prop in element.properties:
            rows[prop.name] = columns[prop.name]
        return rows.tobytes()
    _, places, total = _layout(element, columns, _itemsize)
    out = np.zeros(total, np.uint8)

    def scatter(positions: I64, values: NDArray[np.generic], code: str) -> None:
        size = _itemsize(code)
        b = np.ascontiguousarray(values.astype(order + code)).view(np.uint8).reshape(-1, size)
        out[positions[:, None] + np.arange(size)] = b

    for prop, (pos, first) in zip(element.properties, places):  # loop over properties
        value = columns[prop.name]
        if isinstance(value, PlyList):
            assert first is not None and prop.count_dtype is not None
            scatter(pos, value.counts, prop.count_dtype)
            scatter(_flat_positions(first, value.counts, _itemsize(prop.dtype)), value.values, prop.dtype)
        else:
            scatter(pos, value, prop.dtype)
    return out.tobytes()


def _element_text(element: PlyElement, columns: Mapping[str, NDArray[np.generic] | PlyList]) -> str:
    """The rows of ``element`` as ascii, one row per line; numbers in their shortest round-trip form."""
    starts, places, total = _layout(element, columns, lambda code: 1)
    if total == 0:
        return ""
    tokens = np.empty(total, dtype=object)
    for prop, (pos, first) in zip(element.properties, places):  # loop over properties
        value = columns[prop.name]
        if isinstance(value, PlyList):
            assert first is not None
            tokens[pos] = value.counts.astype(str)
            tokens[_flat_positions(first, value.counts, 1)] = value.values.astype(prop.dtype).astype(str)
        else:
            tokens[pos] = value.astype(prop.dtype).astype(str)
    text = np.full(2 * total, " ", dtype=object)  # token, separator, token, ...
    text[0::2] = tokens
    text[2 * np.concatenate([starts[1:], [total]]) - 1] = "\n"  # after the last token of every row
    return "".join(text.tolist())


def write_ply(
    path: str | os.PathLike[str],
    elements: Mapping[str, Mapping[str, ArrayLike | PlyList]],
    encoding: str = "binary_little_endian",
    comments: tuple[str, ...] = (),
) -> None:
    """Write ``elements[name][property]`` ((n,) arrays typed as they should be stored, or ``PlyList``s)
    as a .ply file in ``encoding``, atomically (a temporary file renamed when complete)."""
    if encoding not in ENCODINGS:
        raise ValueError(f"write_ply: encoding must be one of {ENCODINGS}, got {encoding!r}")
    header = ["ply", f"format {encoding} 1.0"] + [f"comment {c}" for c in comments]
    bodies: list[bytes] = []
    for name, cols in elements.items():  # loop over elements
        columns = {k: v if isinstance(v, PlyList) else np.asarray(v) for k, v in cols.items()}
        rows = {len(v) for v in columns.values()}
        if len(rows) > 1 or any(not isinstance(v, PlyList) and v.ndim != 1 for v in columns.values()):
            raise ValueError(f"write_ply: element {name!r} needs 1-d columns of one length, got {sorted(rows)}")
        props = tuple(_property_for(k, v) for k, v in columns.items())
        element = PlyElement(name, rows.pop() if rows else 0, props)
        header.append(f"element {name} {element.count}")
        for p in element.properties:
            if p.count_dtype is None:
                header.append(f"property {_TYPE_NAMES[p.dtype]} {p.name}")
            else:
                header.append(f"property list {_TYPE_NAMES[p.count_dtype]} {_TYPE_NAMES[p.dtype]} {p.name}")
        if encoding == "ascii":
            bodies.append(_element_text(element, columns).encode("ascii"))
        else:
            bodies.append(_element_bytes(element, columns, _BYTE_ORDER[encoding]))
    header.append("end_header")
    path = Path(path)
    tmp = path.with_name(path.name + ".tmp")
    with open(tmp, "wb") as f:
        f.write(("\n".join(header) + "\n").encode("ascii"))
        for body in bodies:
            f.write(body)
    os.replace(tmp, path)
