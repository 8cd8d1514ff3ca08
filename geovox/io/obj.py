"""A Wavefront OBJ + MTL reader that keeps what colouring needs.

trimesh's OBJ loader merges materials into one atlas when forced into a
single mesh and misreads some files (relative indices across ``o`` blocks,
see the Cornell box in the corpus), so geovox reads OBJ itself: every face
keeps its own material, its corners keep their UVs, ``v x y z r g b`` vertex
colours are kept, polygons are fan-triangulated, negative (relative) indices
work, and MTL/texture paths written with backslashes or in other folders are
found. Missing or unreadable material files and textures are recorded (and
reported as warnings when colour is asked for), never fatal.

The file is read on whole arrays, not one Python step per line (about 5x
faster on 100k triangles; see benchmarks/README.md): its lines are split
once, each is classified by its first bytes, and the numbers of all plain
``v``/``vt`` lines and the indices of all ``f`` lines are read at once.
Lines the fast path is not certain about go through the plain reading of
one statement (:func:`_statement`), which gives the same results and words
the errors.
Text may be UTF-8 (with or without a byte order mark) or UTF-16/32, with
LF, CRLF or CR line ends and trailing-backslash continuations.

Decisions on input other readers refuse or pass on silently:

* a face naming a texture coordinate the file does not have keeps its
  geometry and loses its UVs (it takes its material's colour), with a problem
  recorded;
* a vertex colour with a NaN or infinite channel counts as no colour (white,
  as for a vertex without one in a file where others have one), with a
  problem recorded;
* a file with vertices but no faces (a point cloud, or ``l`` polylines only)
  is an error that says so;
* a statement that cannot be read, or a face naming a vertex that does not
  exist, is an error naming the file and the line.
"""

from __future__ import annotations

import os

import numpy as np

from ..errors import MeshError
from ..kernels import obj_text
from ..mesh import Mesh, transform_uv
from .mtl import rest_of, used_materials
from .references import check_rule

__all__ = ["read_obj"]


# ---------------------------------------------------------------------------
# Reading OBJ statements.
#
# The reader works on whole arrays: the file is split into lines once, each
# line is classified by its first bytes, and the numbers of all plain `v`,
# `vt` and `f` lines are read at once (see _floats and _digits). A line the
# fast path is not sure about (leading or Unicode whitespace, letters or other
# bytes in a number, a keyword glued to something else, `usemtl`, `mtllib`)
# goes through _statement, the plain one-line-at-a-time reading, which also
# words every error. Both paths give the same numbers: the fast one reads a
# number only where the result is exactly what Python's float() gives.

_IGN, _V, _VT, _F, _SLOW, _USEMTL, _MTLLIB, _LINE, _OBJECT, _GROUP = range(10)

# First bytes after which the statement keyword is not certain from bytes:
# whitespace that str.split() knows but the fast path does not (\x1f and
# everything non-ASCII), and the keywords read one line at a time.
_UNSURE_FIRST = np.zeros(256, dtype=bool)
# "o" and "g" too: objects and groups name the parts (labels="part").
_UNSURE_FIRST[[ord(" "), ord("\t"), 0x1F, ord("u"), ord("m"), ord("o"), ord("g")]] = True
_UNSURE_FIRST[0x80:] = True
_UNSURE_AFTER = np.zeros(256, dtype=bool)
_UNSURE_AFTER[[ord("\n"), 0x1F]] = True
_UNSURE_AFTER[0x80:] = True

# Byte order marks, longest first (UTF-32 LE starts like UTF-16 LE).
_BOMS = ((b"\xef\xbb\xbf", "utf-8"), (b"\xff\xfe\x00\x00", "utf-32-le"),
         (b"\x00\x00\xfe\xff", "utf-32-be"), (b"\xff\xfe", "utf-16-le"),
         (b"\xfe\xff", "utf-16-be"))
# Every line break str.splitlines() knows, in UTF-8 (\r\n is done first).
_BREAKS_1 = bytes.maketrans(b"\r\x0b\x0c\x1c\x1d\x1e", b"\n" * 6)
_BREAKS_N = (b"\xc2\x85", b"\xe2\x80\xa8", b"\xe2\x80\xa9")

_P10_INT = np.array([10 ** k for k in range(20)], dtype=np.uint64)
_P10_FLOAT = np.array([10.0 ** k for k in range(23)])
_TWO_53 = np.uint64(2 ** 53)
# Where NumPy's longdouble is x87 extended precision (a 64-bit significand:
# x86), numbers of 17-19 digits are read through it (see _floats); 10**k is
# exact in it up to k = 27 (5**27 < 2**64).
_EXTENDED = np.finfo(np.longdouble).nmant == 63
_P10_LONG = (np.array([5 ** k for k in range(28)], dtype=np.uint64).astype(np.longdouble)
             * np.ldexp(np.longdouble(1), np.arange(28)))
# Per number of digits k (0-8) in the high bytes of a little-endian word:
# the bytes to keep, and '0' in the others.
_KEEP = np.array([0] + [(2 ** 64 - 1) << (8 * (8 - k)) & (2 ** 64 - 1) for k in range(1, 9)],
                 dtype=np.uint64)
_FILL = ~_KEEP & np.uint64(0x3030303030303030)
_EMPTY = np.zeros(0, dtype=np.int64)
# Spaces in front of a section: _digits reads up to 24 bytes before a number's end.
_PAD = 24
# The texture index of a corner that names none (0 is an index, if not a valid one).
_NO_UV = -(2 ** 62)


class _BadLine(Exception):
    """A statement that cannot be read; the message says why."""


def _decode(data: bytes, path: str) -> bytes:
    """The file as UTF-8 bytes: byte order marks removed, UTF-16/32 transcoded."""
    for bom, encoding in _BOMS:
        if data.startswith(bom):
            if encoding == "utf-8":
                return data[len(bom):]
            return data[len(bom):].decode(encoding, errors="replace").encode("utf-8")
    head = data[:4096]
    if b"\0" in head:
        # UTF-16 without a byte order mark: every other byte of plain text is 0.
        half = len(head) // 2 * 2
        even, odd = head[0:half:2], head[1:half:2]
        if even and not odd.strip(b"\0") and b"\0" not in even:
            return data.decode("utf-16-le", errors="replace").encode("utf-8")
        if odd and not even.strip(b"\0") and b"\0" not in odd:
            return data.decode("utf-16-be", errors="replace").encode("utf-8")
        raise MeshError(f"{path}: is a binary file, not a text OBJ mesh")
    return data


def _join_lines(text: bytes) -> tuple:
    """Line breaks made ``\\n`` and trailing-backslash continuations joined.

    Returns ``(physical, joined)``: the text with one ``\\n`` per line of the
    file (for line numbers) and the text with continued lines joined (the
    same object when nothing was continued).
    """
    # One-byte searches first: they run at memory speed, longer ones do not.
    if b"\r" in text and b"\r\n" in text:
        text = text.replace(b"\r\n", b"\n")
    if any(ch in text for ch in (b"\r", b"\x0b", b"\x0c", b"\x1c", b"\x1d", b"\x1e")):
        text = text.translate(_BREAKS_1)
    for brk in _BREAKS_N:
        if brk[:1] in text and brk in text:
            text = text.replace(brk, b"\n")
    if b"\\" in text and b"\\\n" in text:
        return text, text.replace(b"\\\n", b" ")
    return text, text


def _line_number(physical: bytes, joined: bytes, offset: int) -> int:
    """1-based line of the file where the joined text's byte ``offset`` lies."""
    if physical is not joined:
        a = np.frombuffer(physical, dtype=np.uint8)
        cont = np.flatnonzero((a[:-1] == ord("\\")) & (a[1:] == ord("\n")))
        # The k-th continuation (2 bytes) became 1 byte at cont[k] - k.
        offset += int(np.searchsorted(cont - np.arange(len(cont)), offset))
    return physical.count(b"\n", 0, offset) + 1


def _number(token: str) -> float:
    try:
        return float(token)
    except ValueError:
        raise _BadLine(f"{token!r} is not a number") from None


def _index(token: str) -> int:
    i = int(token)
    if abs(i) >= 2 ** 62:
        raise _BadLine(f"index {token} is out of range")
    return i


def _statement(line: str) -> tuple:
    """One statement read the plain way: ``(kind, payload)``.

    This is the reading of geovox 0.1's line-by-line loop, with errors
    worded; the fast path gives the same results on the lines it reads.

    Raises
    ------
    _BadLine
        The statement is a vertex, texture coordinate or face that cannot be read.
    """
    if not line or line[0] == "#":
        return _IGN, None
    parts = line.split()
    if not parts:
        return _IGN, None
    key = parts[0]
    if key == "v":
        if len(parts) < 4:
            raise _BadLine("a vertex needs three coordinates (v x y z)")
        xyz = tuple(_number(p) for p in parts[1:4])
        rgb = tuple(_number(p) for p in parts[4:7]) if len(parts) >= 7 else None
        return _V, (xyz, rgb)
    if key == "vt":
        if len(parts) < 2:
            raise _BadLine("a texture coordinate needs a number (vt u [v])")
        return _VT, (_number(parts[1]), _number(parts[2]) if len(parts) > 2 else 0.0)
    if key == "f":
        corners = []
        for token in parts[1:]:
            s = token.split("/")
            try:
                # Normals (a third part) are not used and not read.
                corners.append((_index(s[0]), _index(s[1]) if len(s) > 1 and s[1] else _NO_UV))
            except ValueError:
                raise _BadLine(f"{token!r} is not a face corner (v, v/vt, v//vn or v/vt/vn "
                               f"with whole numbers)") from None
        return _F, corners
    if key == "usemtl":
        return _USEMTL, rest_of(line, "usemtl")
    if key == "mtllib":
        return _MTLLIB, rest_of(line, "mtllib")
    if key == "l":
        return _LINE, None
    if key in ("o", "g"):
        return (_OBJECT if key == "o" else _GROUP), rest_of(line, key)
    return _IGN, None


def _distinct(a) -> np.ndarray:
    """Sorted distinct int64 values (np.unique's first call imports numpy.ma, 60 ms)."""
    a = np.sort(np.asarray(a, dtype=np.int64))
    return a[np.r_[True, a[1:] != a[:-1]]] if len(a) else a


def _words(s: np.ndarray) -> np.ndarray:
    """(N - 7,) uint64 view: element j is bytes ``s[j:j+8]`` read little-endian."""
    return np.ndarray(shape=(max(len(s) - 7, 0),), dtype="<u8", buffer=s, strides=(1,))


def _eight(v: np.ndarray, n: np.ndarray) -> np.ndarray:
    """Value of the last ``n`` (0-8) digit bytes of each little-endian word."""
    v = (v & _KEEP[n]) | _FILL[n]
    # simdjson's parse_eight_digits_unrolled: the first digit is the low byte.
    v = v - np.uint64(0x3030303030303030)
    v = v * np.uint64(10) + (v >> np.uint64(8))
    mask = np.uint64(0x000000FF000000FF)
    return (((v & mask) * np.uint64(0x000F424000000064))
            + (((v >> np.uint64(16)) & mask) * np.uint64(0x0000271000000001))) >> np.uint64(32)


def _digits(words: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """Values of the decimal digit strings ``s[lo:hi]`` (0 to 19 digits each).

    Parameters
    ----------
    words : (N - 7,) uint64
        :func:`_words` of a text with at least 24 bytes before any ``lo``.
    lo, hi : (n,) int64

    Returns
    -------
    (n,) uint64
        Nonsense where a range holds something other than 0-19 digits.
    """
    length = np.clip(hi - lo, 0, 24)
    longest = length.max() if len(length) else 0
    if longest <= 8:
        return _eight(words[hi - 8], length)
    low = np.minimum(length, 8)
    mid = np.minimum(length - low, 8)
    value = (_eight(words[hi - 16], mid) * np.uint64(10 ** 8) + _eight(words[hi - 8], low))
    if longest <= 16:
        return value
    return _eight(words[hi - 24], length - low - mid) * np.uint64(10 ** 16) + value


def _owner(starts: np.ndarray, positions: np.ndarray) -> np.ndarray:
    """Index of the token (given by sorted ``starts``) each position lies in."""
    return np.searchsorted(starts, positions, side="right") - 1


def _one_each(at: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> bool:
    """Whether the sorted positions ``at`` are exactly one in each ``[lo, hi)``."""
    return len(at) == len(lo) and bool(np.all(at >= lo)) and bool(np.all(at < hi))


def _floats(s: np.ndarray, ts: np.ndarray, te: np.ndarray) -> tuple:
    """Read the tokens ``s[ts:te]`` as float64, exactly as ``float()`` would.

    Only tokens of the form ``[+-]digits[.digits][(e|E)[+-]digits]`` are read
    here, in two ways that give bit for bit what float() gives:

    * at most 16 digits forming an integer m <= 2**53 and a decimal exponent
      within ±22: m times or divided by an exact power of ten is one
      correctly rounded operation (Clinger's fast path);
    * 17-19 digits (Python's repr writes 17) and an exponent within ±27, with
      x87 extended precision: m and the power of ten are exact in it, the
      operation rounds once to 64 bits and the conversion to float64 once
      more; the two roundings give float()'s result unless the first one
      lands exactly halfway between two float64 values, which is checked.

    The others are flagged for float().

    Parameters
    ----------
    s : (N,) uint8
        Section text: _PAD spaces in front, only ``0-9 . + - e E``, spaces,
        tabs and newlines in the tokens.
    ts, te : (n,) int64
        Token starts and ends.

    Returns
    -------
    values : (n,) float64
    ok : (n,) bool
        False where the value must come from float() instead.
    """
    n = len(ts)
    ok = np.ones(n, dtype=bool)
    words = _words(s)
    head = s[ts]
    man_end = te  # where the mantissa ends: the exponent letter, or the token's end
    at = np.flatnonzero((s == ord("e")) | (s == ord("E")))
    if len(at):
        tok = _owner(ts, at)
        ok[tok[1:][tok[1:] == tok[:-1]]] = False  # two exponent letters
        man_end = te.copy()
        man_end[tok] = at
    at = np.flatnonzero(s == ord("."))
    if _one_each(at, ts, man_end):  # the usual case: one dot in every number
        dot = at
    else:
        dot = man_end.copy()  # no dot: the integer part runs to the mantissa's end
        if len(at):
            tok = _owner(ts, at)
            ok[tok[1:][tok[1:] == tok[:-1]]] = False  # two dots
            dot[tok] = at
            ok &= dot <= man_end  # a dot in the exponent
    at = np.flatnonzero((s == ord("-")) | (s == ord("+")))
    if len(at):
        # A sign starts the number or its exponent.
        before = s[at - 1]
        stray = (before > ord(" ")) & (before != ord("e")) & (before != ord("E"))
        if stray.any():
            ok[_owner(ts, at[stray])] = False
    int_lo = ts + ((head == ord("-")) | (head == ord("+")))
    frac_lo = np.minimum(dot + 1, man_end)
    n_int = dot - int_lo
    n_frac = man_end - frac_lo
    n_dig = n_int + n_frac
    ok &= (n_int >= 0) & (n_dig >= 1)  # the form; from here on, the way to read it
    m = (_digits(words, int_lo, dot) * _P10_INT[np.clip(n_frac, 0, 19)]
         + _digits(words, frac_lo, man_end))
    mf = m.astype(np.float64)
    e10 = -n_frac
    if man_end is te:
        values = mf / _P10_FLOAT[np.clip(n_frac, 0, 22)]
    else:
        has_exp = np.flatnonzero(man_end < te)
        lo = man_end[has_exp] + 1
        hi = te[has_exp]
        neg = s[lo] == ord("-")
        lo = lo + (neg | (s[lo] == ord("+")))
        ok[has_exp] &= (hi - lo >= 1) & (hi - lo <= 4)
        x = _digits(words, lo, hi).astype(np.int64)
        e10[has_exp] += np.where(neg, -x, x)
        values = np.where(e10 >= 0, mf * _P10_FLOAT[np.clip(e10, 0, 22)],
                          mf / _P10_FLOAT[np.clip(-e10, 0, 22)])
    fast = ok & (n_dig <= 16) & (m <= _TWO_53) & (np.abs(e10) <= 22)
    if _EXTENDED and not fast.all():
        wide = np.flatnonzero(ok & ~fast & (n_dig <= 19) & (np.abs(e10) <= 27))
        if len(wide):
            ml, e = m[wide].astype(np.longdouble), e10[wide]
            q = np.where(e >= 0, ml * _P10_LONG[np.clip(e, 0, 27)],
                         ml / _P10_LONG[np.clip(-e, 0, 27)])
            # The 11 significand bits float64 drops: 0x400 is exactly halfway.
            halfway = (q.view(np.uint64)[0::2] & np.uint64(0x7FF)) == np.uint64(0x400)
            values[wide] = q.astype(np.float64)
            fast[wide[~halfway]] = True
    np.negative(values, out=values, where=head == ord("-"))
    return values, fast


def _section(buf: np.ndarray, starts: np.ndarray, ends: np.ndarray, lines: np.ndarray):
    """The given lines (sorted) copied after _PAD spaces, each ending in ``\\n``."""
    if len(lines) == 0:
        return np.full(_PAD, ord(" "), dtype=np.uint8)
    cut = np.flatnonzero(np.diff(lines) != 1) + 1
    lo = starts[lines[np.r_[0, cut]]]
    hi = ends[lines[np.r_[cut - 1, len(lines) - 1]]] + 1
    if len(lo) > 256:
        # Many short runs (statements of different kinds interleaved): a mask
        # over the bytes costs less than a copy per run.
        keep = np.zeros(len(starts), dtype=bool)
        keep[lines] = True
        mask = np.repeat(keep, ends - starts + 1)
        return np.concatenate([np.full(_PAD, ord(" "), dtype=np.uint8),
                               buf[:len(mask)][mask]])
    out = np.empty(_PAD + int((hi - lo).sum()), dtype=np.uint8)
    out[:_PAD] = ord(" ")
    pos = _PAD
    for a, b in zip(lo.tolist(), hi.tolist()):
        out[pos:pos + b - a] = buf[a:b]
        pos += b - a
    return out


def _tokens(s: np.ndarray, bad: np.ndarray):
    """Tokens of a section and the lines they are on.

    Parameters
    ----------
    s : (N,) uint8
        Section (see :func:`_section`).
    bad : (N,) bool
        Bytes the section's fast reading does not expect.

    Returns
    -------
    ts, te : (n,) int64
        Token starts and ends (``bad_lines`` are blanked in ``s`` first).
    line_of : (n,) int64
        Line (index among the section's lines) of each token.
    count : (lines,) int64
        Tokens per line.
    bad_lines : (k,) int64
        Lines with an unexpected byte.
    """
    line_ends = np.flatnonzero(s == ord("\n"))
    n_lines = len(line_ends)
    after = np.r_[-1, line_ends[:-1]]
    bad_lines = _EMPTY
    if bad.any():
        bad_lines = _distinct(np.searchsorted(line_ends, np.flatnonzero(bad)))
        for i in bad_lines.tolist():  # left to the plain reading: no tokens here
            s[after[i] + 1:line_ends[i]] = ord(" ")
    space = s <= ord(" ")  # other control bytes are in `bad`
    edges = np.flatnonzero(space[1:] != space[:-1]) + 1  # starts and ends alternate
    ts, te = edges[0::2], edges[1::2]
    k = len(ts) // n_lines if n_lines else 0
    if (k and len(ts) == k * n_lines and np.all(ts[::k] > after)
            and np.all(te[k - 1::k] <= line_ends)):
        # The usual case: k tokens on every line.
        count = np.full(n_lines, k, dtype=np.int64)
    else:
        count = np.diff(np.searchsorted(ts, line_ends), prepend=0)
    return ts, te, np.repeat(np.arange(n_lines), count), count, bad_lines


def _number_lines(buf, starts, ends, lines, need):
    """Read the numbers of ``v`` or ``vt`` lines (keyword already blanked).

    Returns
    -------
    values : (k,) float64
        The numbers of the lines that were read, in order.
    first : (len(lines),) int64
        Index in ``values`` of each line's first number.
    count : (len(lines),) int64
        Numbers on each line (0 for a line left to the plain reading).
    slow : (j,) int64
        Indices into ``lines`` to read the plain way: unexpected bytes,
        numbers float() must read, or fewer than ``need`` numbers.
    """
    s = _section(buf, starts, ends, lines)
    digit = (s >= ord("0")) & (s <= ord("9"))
    bad = ~(digit | (s == ord(" ")) | (s == ord("\n")) | (s == ord(".")) | (s == ord("-"))
            | (s == ord("e")) | (s == ord("+")) | (s == ord("\t")) | (s == ord("E")))
    ts, te, line_of, count, bad_lines = _tokens(s, bad)
    values, ok = _floats(s, ts, te)
    slow = [bad_lines]
    if not ok.all():
        # float() for the rest (17 significant digits, as Python's repr writes,
        # are common): slicing one bytes object is the cheap way to get them.
        redo = np.flatnonzero(~ok)
        text = s.tobytes()
        spans = list(zip(ts[redo].tolist(), te[redo].tolist()))
        try:
            values[redo] = [float(text[a:b]) for a, b in spans]
        except ValueError:
            failed = []
            for k, (a, b) in zip(redo.tolist(), spans):
                try:
                    values[k] = float(text[a:b])
                except ValueError:
                    failed.append(line_of[k])
            slow.append(np.asarray(failed, dtype=np.int64))
    slow.append(np.flatnonzero(count < need))
    slow = _distinct(np.concatenate(slow))
    first = np.cumsum(count) - count
    count[slow] = 0
    return values, first, count, slow


def _corner_lines(buf, starts, ends, lines):
    """Read the corners of ``f`` lines (keyword already blanked).

    Returns
    -------
    line_of : (k,) int64
        Index into ``lines`` of each corner read, in order.
    v, t : (k,) int64
        The vertex and texture indices as written; ``t`` is _NO_UV where a
        corner names none.
    slow : (j,) int64
        Indices into ``lines`` to read the plain way.
    """
    s = _section(buf, starts, ends, lines)
    digit = (s >= ord("0")) & (s <= ord("9"))
    bad = ~(digit | (s == ord(" ")) | (s == ord("\n")) | (s == ord("/")) | (s == ord("-"))
            | (s == ord("+")) | (s == ord("\t")))
    ts, te, line_of, count, bad_lines = _tokens(s, bad)
    words = _words(s)
    n = len(ts)
    at = np.flatnonzero(s == ord("/"))
    slash2 = te
    if len(at) == 0:
        slash1 = te
    elif _one_each(at, ts + 1, te):  # v/t
        slash1 = at
    elif len(at) == 2 * n and _one_each(at[0::2], ts + 1, te) and _one_each(at[1::2], ts + 1, te):
        slash1, slash2 = at[0::2], at[1::2]  # v/t/n or v//n
    else:
        slash1, slash2 = te.copy(), te.copy()
        tok = _owner(ts, at)
        first = np.ones(len(at), dtype=bool)
        first[1:] = tok[1:] != tok[:-1]
        second = np.zeros(len(at), dtype=bool)
        second[1:] = first[:-1] & ~first[1:]
        slash1[tok[first]] = at[first]
        slash2[tok[second]] = at[second]
    ok = np.ones(n, dtype=bool)
    at = np.flatnonzero((s == ord("-")) | (s == ord("+")))
    if len(at):
        # A sign starts an index; the normal (after a second slash) is not read.
        before = s[at - 1]
        stray = (before > ord(" ")) & (before != ord("/"))
        if stray.any():
            ok[_owner(ts, at[stray])] = False
    head = s[ts]
    v_lo = ts + ((head == ord("-")) | (head == ord("+")))
    ok &= (slash1 - v_lo >= 1) & (slash1 - v_lo <= 16)
    v = _digits(words, v_lo, slash1).astype(np.int64)
    np.negative(v, out=v, where=head == ord("-"))
    t = np.full(n, _NO_UV, dtype=np.int64)
    has_t = np.flatnonzero(slash2 > slash1 + 1)
    if len(has_t):
        lo = slash1[has_t] + 1
        hi = slash2[has_t]
        neg = s[lo] == ord("-")
        lo = lo + (neg | (s[lo] == ord("+")))
        ok[has_t] &= (hi - lo >= 1) & (hi - lo <= 16)
        x = _digits(words, lo, hi).astype(np.int64)
        t[has_t] = np.where(neg, -x, x)
    if ok.all():
        return line_of, v, t, bad_lines
    slow = _distinct(np.concatenate([bad_lines, line_of[~ok]]))
    drop = np.zeros(len(count), dtype=bool)
    drop[slow] = True
    keep = ~drop[line_of]
    return line_of[keep], v[keep], t[keep], slow


def _pieces(starts, ends, lines, size=1 << 18):
    """``lines`` cut into runs of about ``size`` bytes.

    Reading a section a piece at a time keeps its arrays in the processor's
    cache: on the 4 MB bunny105k this halves the time of the number reading.
    """
    if len(lines) == 0:
        return [lines]
    total = np.cumsum(ends[lines] - starts[lines] + 1)
    cuts = np.searchsorted(total, np.arange(size, int(total[-1]), size))
    return np.split(lines, _distinct(cuts[(cuts > 0) & (cuts < len(lines))]))


def _read_numbers(buf, starts, ends, lines, need):
    """:func:`_number_lines` over pieces of the section (or the compiled twin over all of it)."""
    if len(lines) == 0:
        return np.zeros(0), _EMPTY, _EMPTY, _EMPTY
    kernel = obj_text()
    if kernel is not None:  # geovox/_objtext.pyx: the same lines, float()'s numbers
        return kernel.number_lines(buf, starts, ends, lines, need)
    values, first, count, slow, n_values, n_lines = [], [], [], [], 0, 0
    for piece in _pieces(starts, ends, lines):
        v, f, c, s = _number_lines(buf, starts, ends, piece, need)
        values.append(v)
        first.append(f + n_values)
        count.append(c)
        slow.append(s + n_lines)
        n_values += len(v)
        n_lines += len(piece)
    return (np.concatenate(values), np.concatenate(first), np.concatenate(count),
            np.concatenate(slow))


def _read_corners(buf, starts, ends, lines):
    """:func:`_corner_lines` over pieces of the section (or the compiled twin over all of it)."""
    if len(lines) == 0:
        return _EMPTY, _EMPTY, _EMPTY, _EMPTY
    kernel = obj_text()
    if kernel is not None:  # geovox/_objtext.pyx: the same corners and slow lines
        return kernel.corner_lines(buf, starts, ends, lines)
    parts, n_lines = [], 0
    for piece in _pieces(starts, ends, lines):
        line_of, v, t, slow = _corner_lines(buf, starts, ends, piece)
        parts.append((line_of + n_lines, v, t, slow + n_lines))
        n_lines += len(piece)
    return tuple(np.concatenate(x) for x in zip(*parts))


def _fan(first: np.ndarray, count: np.ndarray) -> np.ndarray:
    """(m, 3) int64: corner indices of the fan triangles of polygons.

    ``first`` and ``count`` give each polygon's corners (count >= 3).
    """
    if np.all(count == 3):
        return first[:, None] + np.arange(3)
    n_tri = count - 2
    poly = np.repeat(np.arange(len(first)), n_tri)
    j = np.arange(len(poly)) - np.repeat(np.cumsum(n_tri) - n_tri, n_tri) + 1
    c0 = first[poly]
    return np.stack([c0, c0 + j, c0 + j + 1], axis=1)


def _parse(text: bytes):
    """Everything the statements of an OBJ say.

    Returns
    -------
    dict of arrays and lists (see read_obj), and ``errors``: (line index,
    problem) for each statement that cannot be read.
    """
    n = len(text)
    buf = np.empty(n + 4, dtype=np.uint8)
    buf[:n] = np.frombuffer(text, dtype=np.uint8)
    buf[n:] = ord("\n")
    ends = np.flatnonzero(buf[:n + 1] == ord("\n"))
    starts = np.empty_like(ends)
    starts[0] = 0
    starts[1:] = ends[:-1] + 1
    kind, n_polylines = _classify(buf, starts)

    errors, records = [], []

    def plain(lines):
        for i in lines.tolist():
            line = text[starts[i]:ends[i]].decode("utf-8", errors="replace")
            try:
                k, payload = _statement(line)
            except _BadLine as exc:
                errors.append((i, f"{exc}: {_shorten(line)}"))
                k, payload = _IGN, None
            kind[i] = k
            records.append((i, k, payload))

    plain(np.flatnonzero(kind == _SLOW))
    v_lines = np.flatnonzero(kind == _V)
    vt_lines = np.flatnonzero(kind == _VT)
    f_lines = np.flatnonzero(kind == _F)
    fast = np.zeros(len(kind), dtype=bool)
    fast[v_lines] = fast[vt_lines] = fast[f_lines] = True
    for r in records:
        fast[r[0]] = False
    fv, fvt, ff = v_lines[fast[v_lines]], vt_lines[fast[vt_lines]], f_lines[fast[f_lines]]
    buf[starts[fv]] = buf[starts[fvt]] = buf[starts[fvt] + 1] = buf[starts[ff]] = ord(" ")

    vertices, colours, redo_v = _fast_vertices(buf, starts, ends, v_lines, fv)
    uvs, redo_vt = _fast_uvs(buf, starts, ends, vt_lines, fvt)
    line_of, cv, ct, slow = _read_corners(buf, starts, ends, ff)
    corner_line = ff[line_of]
    redo_f = ff[slow]

    plain(_distinct(np.concatenate([redo_v, redo_vt, redo_f])))
    out = dict(starts=starts, kind=kind, vertices=vertices, colours=colours, uvs=uvs,
               corner_line=corner_line, cv=cv, ct=ct, errors=errors, n_polylines=n_polylines)
    _merge(records, v_lines, vt_lines, out)
    return out


def _classify(buf: np.ndarray, starts: np.ndarray) -> tuple:
    """(lines,) uint8 kind of each line from its first bytes, and the number of ``l`` lines."""
    c0, c1, c2 = buf[starts], buf[starts + 1], buf[starts + 2]
    spaced1 = (c1 == ord(" ")) | (c1 == ord("\t"))
    is_v, is_f = c0 == ord("v"), c0 == ord("f")
    vt_like = is_v & (c1 == ord("t"))
    kind = np.zeros(len(starts), dtype=np.uint8)
    kind[is_v & spaced1] = _V
    kind[vt_like & ((c2 == ord(" ")) | (c2 == ord("\t")))] = _VT
    kind[is_f & spaced1] = _F
    kind[_UNSURE_FIRST[c0] | ((is_v | is_f) & _UNSURE_AFTER[c1])
         | (vt_like & _UNSURE_AFTER[c2])] = _SLOW
    return kind, int(np.count_nonzero((c0 == ord("l")) & spaced1))


def _fast_vertices(buf, starts, ends, v_lines, fv) -> tuple:
    """Vertices (and colours) by their order in the file, from the fast-path ``v`` lines ``fv``.

    Returns (len(v_lines), 3) float64 positions, (len(v_lines), 3) float64
    colours or None, and the lines the fast path left to the plain reading.
    """
    vals, first, count, slow = _read_numbers(buf, starts, ends, fv, 3)
    order = np.searchsorted(v_lines, fv) if len(fv) != len(v_lines) else None
    if order is None and len(slow) == 0 and np.all(count == 3):
        vertices = vals.reshape(-1, 3)
        colours = None
    else:
        vertices = np.zeros((len(v_lines), 3))
        read = np.flatnonzero(count >= 3)
        rows = read if order is None else order[read]
        vertices[rows] = vals[first[read, None] + np.arange(3)]
        coloured = np.flatnonzero(count >= 6)
        colours = None
        if len(coloured):
            colours = np.ones((len(v_lines), 3))
            crow = coloured if order is None else order[coloured]
            colours[crow] = vals[first[coloured, None] + np.arange(3, 6)]
    return vertices, colours, fv[slow]


def _fast_uvs(buf, starts, ends, vt_lines, fvt) -> tuple:
    """(len(vt_lines), 2) float64 UVs from the fast-path ``vt`` lines, and the lines left over."""
    vals, first, count, slow = _read_numbers(buf, starts, ends, fvt, 1)
    uvs = np.zeros((len(vt_lines), 2))
    read = np.flatnonzero(count >= 1)
    rows = np.searchsorted(vt_lines, fvt[read])
    uvs[rows, 0] = vals[first[read]]
    two = count[read] >= 2
    uvs[rows[two], 1] = vals[first[read[two]] + 1]
    return uvs, fvt[slow]


def _merge(records: list, v_lines, vt_lines, out: dict) -> None:
    """Merge what the plain reading found (``(line, kind, payload)`` records) into ``out``.

    Sets ``usemtl`` (line, name), ``libs``, ``objects`` and ``groups`` (line, name) in ``out``; updates its
    vertices, colours, UVs and corners in place.
    """
    vertices, colours, uvs = out["vertices"], out["colours"], out["uvs"]
    extra_line, extra_v, extra_t = [], [], []
    usemtl, libs, named = [], [], {_OBJECT: [], _GROUP: []}
    for i, k, payload in sorted(records, key=lambda r: r[0]):
        if k == _V:
            row = int(np.searchsorted(v_lines, i))
            xyz, rgb = payload
            vertices[row] = xyz
            if rgb is not None:
                if colours is None:
                    colours = np.ones((len(v_lines), 3))
                colours[row] = rgb
        elif k == _VT:
            uvs[int(np.searchsorted(vt_lines, i))] = payload
        elif k == _F:
            for a, b in payload:
                extra_line.append(i)
                extra_v.append(a)
                extra_t.append(b)
        elif k == _USEMTL:
            usemtl.append((i, payload))
        elif k == _MTLLIB:
            libs.append(payload)
        elif k in named:
            named[k].append((i, payload))
    if extra_line:
        corner_line = np.concatenate([out["corner_line"], np.asarray(extra_line, dtype=np.int64)])
        cv = np.concatenate([out["cv"], np.asarray(extra_v, dtype=np.int64)])
        ct = np.concatenate([out["ct"], np.asarray(extra_t, dtype=np.int64)])
        by_line = np.argsort(corner_line, kind="stable")
        out.update(corner_line=corner_line[by_line], cv=cv[by_line], ct=ct[by_line])
    out.update(colours=colours, usemtl=usemtl, libs=libs, objects=named[_OBJECT],
               groups=named[_GROUP])


def _count(n: int, one: str, many: str = "") -> str:
    return f"{n} {one if n == 1 else many or one + 's'}"


def _shorten(line: str) -> str:
    line = line.strip()
    return repr(line if len(line) <= 60 else line[:57] + "...")


def read_obj(path: str, *, rule: str = "anywhere") -> Mesh:
    """Read an OBJ file into a :class:`Mesh` with materials, UVs and vertex colours.

    Polygons are fan-triangulated; negative indices count back from the
    statement; text may be UTF-8 (with or without a byte order mark) or
    UTF-16/32, with any line ends and trailing-backslash continuations.
    Faces that name texture coordinates the file does not have keep their
    geometry and lose their UVs, and a vertex colour that is NaN or infinite
    counts as no colour (white, as for vertices without one); both are
    recorded in ``problems``. Material files and textures are found under
    ``rule`` (the option ``references``, see :mod:`geovox.references`), as
    the other loaders find theirs.

    Raises
    ------
    MeshError
        The file cannot be read, is binary, has a statement that cannot be
        read or a face naming a vertex that does not exist (the message gives
        the line), or has no faces.
    ParameterError
        ``rule`` is not ``"anywhere"`` or ``"folder"``.
    """
    rule = check_rule(rule)
    try:
        with open(path, "rb") as f:
            data = f.read()
    except OSError as exc:
        raise MeshError(f"{path}: cannot be read ({exc.strerror or exc})") from exc
    physical, text = _join_lines(_decode(data, path))
    del data
    p = _parse(text)
    starts = p["starts"]

    def line_no(i) -> int:
        return _line_number(physical, text, int(starts[i]))

    if p["errors"]:
        i, problem = min(p["errors"])
        raise MeshError(f"{path}: line {line_no(i)}: {problem}")
    tri, tri_line, faces = _triangles(p, path, line_no)
    problems: list = []
    names, face_material = _face_materials(p["usemtl"], tri_line)
    face_part, parts = _face_parts(p["objects"] or p["groups"], tri_line)
    folder = os.path.dirname(os.path.abspath(path))
    materials = used_materials(p["libs"], names, folder, path, problems, rule)
    corner_uv = _corner_uvs(p, tri, tri_line, materials, face_material, path, line_no, problems)
    colours = p["colours"]
    if colours is not None:
        broken = ~np.isfinite(colours).all(axis=1)
        if broken.any():
            colours[broken] = 1.0
            problems.append(f"{path}: NaN or infinite colour on "
                            f"{_count(int(broken.sum()), 'vertex', 'vertices')}; they count as "
                            f"having no colour (white)")
    return Mesh(
        vertices=p["vertices"],
        faces=faces,
        source=path,
        face_material=face_material.astype(np.int64),
        materials=materials,
        corner_uv=corner_uv,
        vertex_colors=colours,
        problems=problems,
        face_part=face_part,
        parts=parts,
    )


def _face_parts(statements, tri_line) -> tuple:
    """``(face_part, parts)`` from ``o`` (or ``g``) statements ``(line index, name)``.

    A part is one name: statements repeating a name add to its part. Faces
    before the first statement form a part of their own, ``"(unnamed)"``.
    Parts no face falls in are dropped. ``(None, [])`` without statements.
    """
    if not statements:
        return None, []
    lines = np.asarray([i for i, _ in statements], dtype=np.int64)
    index: dict = {}
    of_statement = np.asarray([index.setdefault(name or "(unnamed)", len(index))
                               for _, name in statements], dtype=np.int64)
    use = np.searchsorted(lines, tri_line, side="right") - 1
    raw = np.where(use >= 0, of_statement[np.maximum(use, 0)], len(index))
    names = list(index) + ["(unnamed)"]
    used, face_part = np.unique(raw, return_inverse=True)
    # np.unique numbers the parts in file order: statement order is index order.
    return face_part.astype(np.int64).reshape(-1), [names[k] for k in used]


def _triangles(p: dict, path: str, line_no) -> tuple:
    """The fanned triangles of the face statements.

    Returns
    -------
    tri : (m, 3) int64
        Each triangle's corners (indices into ``p["cv"]`` and ``p["ct"]``).
    tri_line : (m,) int64
        The line (index) of each triangle's statement.
    faces : (m, 3) int64
        0-based vertex indices.

    Raises
    ------
    MeshError
        No faces, or a face naming a vertex that does not exist.
    """
    nv = len(p["vertices"])
    corner_line, cv = p["corner_line"], p["cv"]
    # Polygons: runs of corners from one statement; fewer than 3 corners is no face.
    starts_c = np.flatnonzero(np.r_[True, corner_line[1:] != corner_line[:-1]]) \
        if len(corner_line) else np.zeros(0, dtype=np.int64)
    n_corners = np.diff(np.r_[starts_c, len(corner_line)])
    polygon = n_corners >= 3
    tri = _fan(starts_c[polygon], n_corners[polygon]) if polygon.any() \
        else np.zeros((0, 3), dtype=np.int64)
    if nv == 0 and len(tri) == 0:
        raise MeshError(f"{path}: cannot be read as a mesh (no OBJ vertices or faces)")
    if len(tri) == 0:
        what = []
        if p["n_polylines"]:
            what.append(f"{_count(p['n_polylines'], 'polyline')} (l)")
        if len(polygon):
            what.append(f"{_count(len(polygon), 'face statement')} with fewer than 3 corners")
        also = f" and {' and '.join(what)}" if what else ""
        raise MeshError(f"{path}: has {_count(nv, 'vertex', 'vertices')}{also} but no faces "
                        f"(a point cloud or lines only); nothing to voxelise")
    tri_line = corner_line[tri[:, 0]]  # the statement of each triangle

    # Vertex indices: 1-based, or negative counting back from the statement.
    raw = cv[tri]
    if raw.min() > 0:
        faces = raw - 1
    else:
        before = np.cumsum(p["kind"] == _V)[tri_line][:, None]
        faces = np.where(raw > 0, raw - 1, before + raw)
    bad = (faces < 0) | (faces >= nv) | (raw == 0)
    if bad.any():
        row = int(np.flatnonzero(bad.any(axis=1))[0])
        k = int(raw[row][bad[row]][0])
        if k > 0:
            problem = f"a face names vertex {k}, but the file has {nv} vertices"
        elif k == 0:
            problem = "a face names vertex 0 (OBJ indices start at 1)"
        else:
            n_before = int(faces[row][bad[row]][0]) - k
            problem = (f"a face names vertex {k} (counting back), but only {n_before} "
                       f"vertices come before it")
        raise MeshError(f"{path}: line {line_no(tri_line[row])}: {problem}")
    return tri, tri_line, faces


def _face_materials(usemtl: list, tri_line: np.ndarray) -> tuple:
    """Material names in order of first use, and each triangle's index into them (-1: none).

    ``usemtl``: (line index, name) of each ``usemtl`` statement, in file order.
    """
    names, mat_of_use, mat_lines = [], [], []
    index: dict = {}
    for i, name in usemtl:
        if name not in index:
            index[name] = len(names)
            names.append(name)
        mat_lines.append(i)
        mat_of_use.append(index[name])
    if mat_lines:
        use = np.searchsorted(np.asarray(mat_lines), tri_line, side="right") - 1
        face_material = np.where(use >= 0, np.asarray(mat_of_use)[np.maximum(use, 0)], -1)
    else:
        face_material = np.full(len(tri_line), -1, dtype=np.int64)
    return names, face_material


def _corner_uvs(p, tri, tri_line, materials, face_material, path, line_no, problems):
    """(m, 3, 2) float64 UVs of the triangles' corners (NaN: none), or None without any.

    Corners naming texture coordinates the file does not have lose the UVs
    of their whole statement, said in ``problems``; each material's
    ``map_Kd -o/-s`` transform is applied.
    """
    uvs, ct = p["uvs"], p["ct"]
    nt = len(uvs)
    corner_uv = None
    traw = ct[tri]
    has_t = traw != _NO_UV
    if nt and has_t.any():
        if traw[has_t].min() > 0:
            tex = traw - 1
        else:
            before = np.cumsum(p["kind"] == _VT)[tri_line][:, None]
            tex = np.where(traw > 0, traw - 1, before + traw)
        missing = has_t & ((tex < 0) | (tex >= nt) | (traw == 0))
        if missing.any():
            rows = np.flatnonzero(missing.any(axis=1))
            statements = _distinct(tri_line[rows])
            dropped = np.zeros(len(p["kind"]), dtype=bool)
            dropped[statements] = True
            has_t[dropped[tri_line]] = False
            k = int(traw[rows[0]][missing[rows[0]]][0])
            problems.append(_uv_problem(path, len(statements), line_no(statements[0]), k, nt))
        if has_t.any():
            corner_uv = np.full(tri.shape + (2,), np.nan)
            corner_uv[has_t] = uvs[tex[has_t]]
            for k, m in enumerate(materials):
                if m.uv_transform is not None:
                    # map_Kd -o/-s, once per corner (affine: the same as per point)
                    rows = face_material == k
                    corner_uv[rows] = transform_uv(corner_uv[rows], m.uv_transform)
    elif has_t.any():
        statements = _distinct(tri_line[has_t.any(axis=1)])
        k = int(traw[has_t][0])
        problems.append(_uv_problem(path, len(statements), line_no(statements[0]), k, nt))
    return corner_uv


def _uv_problem(path, n_faces, line, k, nt) -> str:
    return (f"{_count(n_faces, 'face')} in {path} name texture coordinates that do not exist "
            f"(line {line} names {k}; the file has {nt}); their UVs are dropped, so they take "
            f"their material's colour")
