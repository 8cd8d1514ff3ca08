# cython: language_level=3, boundscheck=False, wraparound=False, cdivision=True
# cython: initializedcheck=False, nonecheck=False
"""Compiled reading of an OBJ's ``v``/``vt`` numbers and ``f`` corners.

:func:`number_lines` and :func:`corner_lines` are :func:`geovox.io.obj._number_lines`
and :func:`geovox.io.obj._corner_lines` written as one loop over the bytes of
each line: the same lines are read, the same lines are left to the plain
(``str.split``) reading, and every number read is the one ``float()`` gives:
a token is read only when it has the form ``float()`` accepts
(``[+-]digits[.digits][(e|E)[+-]digits]``, at least one digit before the
exponent), and then either by Clinger's fast path (a mantissa of at most
2**53 and a power of ten within 10**±22: one correctly rounded operation, as
geovox.io.obj._floats does) or by ``PyOS_string_to_double``, the very function
``float()`` calls (correctly rounded, independent of the locale). The
NumPy code gives the same vertices, UVs and corners (it is the fallback
where this module is not built; tests/test_obj_kernel.py holds the two to
each other).
"""

import numpy as np

from cpython.ref cimport PyObject
from libc.stdint cimport int64_t, uint8_t, uint64_t

cdef extern from "Python.h":
    double PyOS_string_to_double(const char *s, char **endptr,
                                 PyObject *overflow_exception) except? -1.0

#: geovox.io.obj._NO_UV: the texture index of a corner that names none.
cdef int64_t NO_UV = -(2 ** 62)


cdef inline bint _digit(uint8_t c) noexcept nogil:
    return 48 <= c <= 57


cdef inline bint _number_byte(uint8_t c) noexcept nogil:
    # What geovox.io.obj._number_lines reads fast: digits . - + e E, blanks.
    return (_digit(c) or c == 32 or c == 9 or c == 46 or c == 45 or c == 43
            or c == 101 or c == 69)


cdef inline bint _corner_byte(uint8_t c) noexcept nogil:
    # What geovox.io.obj._corner_lines reads fast: digits / - +, blanks.
    return _digit(c) or c == 32 or c == 9 or c == 47 or c == 45 or c == 43


#: Powers of ten exact in float64 (10**22 is the largest).
cdef double P10[23]
P10[0] = 1.0
for _k in range(1, 23):
    P10[_k] = P10[_k - 1] * 10.0


cdef inline int _float_form(const uint8_t *s, Py_ssize_t a, Py_ssize_t b,
                            double *value) noexcept nogil:
    """Read s[a:b] (bytes of _number_byte only) as float() would.

    Returns 0 where float() refuses it, 1 where ``value`` holds float()'s
    number, 2 where the number has the form float() reads but must be read
    by it (more than 19 digits, or a mantissa or exponent outside the fast
    path below).
    """
    cdef Py_ssize_t p = a, digits = 0, frac = 0, exp_digits = 0
    cdef uint64_t m = 0
    cdef int64_t e = 0
    cdef bint neg = s[p] == 45, eneg = False
    if s[p] == 43 or s[p] == 45:
        p += 1
    while p < b and _digit(s[p]):
        m = m * 10 + (s[p] - 48)
        p += 1
        digits += 1
    if p < b and s[p] == 46:
        p += 1
        while p < b and _digit(s[p]):
            m = m * 10 + (s[p] - 48)
            p += 1
            digits += 1
            frac += 1
    if digits == 0:
        return 0
    if p < b and (s[p] == 101 or s[p] == 69):
        p += 1
        if p < b and (s[p] == 43 or s[p] == 45):
            eneg = s[p] == 45
            p += 1
        if p == b or not _digit(s[p]):
            return 0
        while p < b and _digit(s[p]):
            if exp_digits < 6:
                e = e * 10 + (s[p] - 48)
            p += 1
            exp_digits += 1
    if p != b:
        return 0
    if digits > 19 or exp_digits > 5:
        return 2
    e = (-e if eneg else e) - frac
    # Clinger's fast path: m and 10**|e| exact in float64, so one correctly
    # rounded operation (SSE2 arithmetic, no contraction: see setup.py) is
    # float()'s correctly rounded value.
    if m > (<uint64_t>1 << 53) or e > 22 or e < -22:
        return 2
    value[0] = <double>m * P10[e] if e >= 0 else <double>m / P10[-e]
    if neg:
        value[0] = -value[0]
    return 1


cdef Py_ssize_t _token_count(const uint8_t *s, const int64_t[::1] starts,
                             const int64_t[::1] ends, const int64_t[::1] lines) noexcept nogil:
    """How many blank-separated tokens the lines hold (the outputs' sizes, set once)."""
    cdef Py_ssize_t i, p, n = 0
    cdef bint blank, was = True
    for i in range(lines.shape[0]):
        was = True
        for p in range(starts[lines[i]], ends[lines[i]]):
            blank = s[p] == 32 or s[p] == 9
            n += was and not blank
            was = blank
    return n


def number_lines(const uint8_t[::1] buf, const int64_t[::1] starts, const int64_t[::1] ends,
                 const int64_t[::1] lines, int64_t need):
    """The numbers of ``v`` or ``vt`` lines, as :func:`geovox.io.obj._read_numbers` reads them.

    Parameters
    ----------
    buf : (N,) uint8
        The file's bytes, the lines' keywords blanked; every line ends in ``\\n``.
    starts, ends : (lines,) int64
        Each line's first byte and its ``\\n``.
    lines : (k,) int64
        The lines to read.
    need : int
        Fewer numbers than this leave a line to the plain reading.

    Returns
    -------
    values : (n,) float64
        Every number of the lines without an unexpected byte, in order
        (0.0 for a token float() would refuse).
    first : (k,) int64
        Index in ``values`` of each line's first number.
    count : (k,) int64
        Numbers on each line; 0 for a line left to the plain reading.
    slow : (j,) int64
        Indices into ``lines`` of the lines left to the plain reading.
    """
    cdef Py_ssize_t k = lines.shape[0], i, p, a, b, q, n = 0
    cdef const uint8_t *s = &buf[0] if buf.shape[0] else NULL
    cdef char *end
    cdef bint bad, refused
    cdef int form
    cdef int64_t c
    first_a = np.zeros(k, dtype=np.int64)
    count_a = np.zeros(k, dtype=np.int64)
    slow_a = np.zeros(k, dtype=np.uint8)
    values_a = np.empty(_token_count(s, starts, ends, lines), dtype=np.float64)
    cdef int64_t[::1] first = first_a
    cdef int64_t[::1] count = count_a
    cdef uint8_t[::1] slow = slow_a
    cdef double[::1] values = values_a
    for i in range(k):
        a, b = starts[lines[i]], ends[lines[i]]
        first[i] = n
        bad = False
        for p in range(a, b):
            if not _number_byte(s[p]):
                bad = True
                break
        if bad:  # no tokens: the plain reading says what is wrong
            slow[i] = 1
            continue
        c = 0
        refused = False
        p = a
        while p < b:
            while p < b and (s[p] == 32 or s[p] == 9):
                p += 1
            if p == b:
                break
            q = p
            while q < b and s[q] != 32 and s[q] != 9:
                q += 1
            form = _float_form(s, p, q, &values[n])
            if form == 2:
                values[n] = PyOS_string_to_double(<const char *>s + p, &end, NULL)
            elif form == 0:
                values[n] = 0.0
                refused = True
            n += 1
            c += 1
            p = q
        count[i] = c
        if refused or c < need:
            slow[i] = 1
            count[i] = 0
    return values_a[:n], first_a, count_a, np.flatnonzero(slow_a).astype(np.int64)


cdef inline int64_t _index(const uint8_t *s, Py_ssize_t lo, Py_ssize_t hi) noexcept nogil:
    """The value of the digits s[lo:hi] (at most 16 of them)."""
    cdef int64_t x = 0
    cdef Py_ssize_t p
    for p in range(lo, hi):
        x = x * 10 + (s[p] - 48)
    return x


cdef inline Py_ssize_t _corner(const uint8_t *s, Py_ssize_t a, Py_ssize_t b, int64_t *v,
                               int64_t *t) noexcept nogil:
    """Read the corner that starts at s[a] (``v``, ``v/t``, ``v//n``, ``v/t/n``).

    Returns where it ends (a blank or ``b``), or -1 where the line must be
    read the plain way: a byte :func:`_corner_byte` refuses, a sign that
    does not start an index, or an index that is not 1-16 digits.
    """
    cdef Py_ssize_t p, q = a, slash1 = -1, slash2 = -1, lo
    cdef uint8_t c
    cdef bint neg
    while q < b:
        c = s[q]
        if c == 32 or c == 9:
            break
        if not _corner_byte(c):
            return -1
        if c == 47:
            if slash1 < 0:
                slash1 = q
            elif slash2 < 0:
                slash2 = q
        elif (c == 45 or c == 43) and q > a and s[q - 1] != 47:
            return -1  # a sign starts an index: the token's first byte, or one after a slash
        q += 1
    if slash1 < 0:
        slash1 = q
    if slash2 < 0:
        slash2 = q
    lo = a + (s[a] == 45 or s[a] == 43)
    if slash1 - lo < 1 or slash1 - lo > 16:
        return -1
    v[0] = -_index(s, lo, slash1) if s[a] == 45 else _index(s, lo, slash1)
    t[0] = NO_UV
    if slash2 > slash1 + 1:  # the normal, after a second slash, is not read
        lo = slash1 + 1
        neg = s[lo] == 45
        lo += neg or s[lo] == 43
        if slash2 - lo < 1 or slash2 - lo > 16:
            return -1
        t[0] = -_index(s, lo, slash2) if neg else _index(s, lo, slash2)
    return q


def corner_lines(const uint8_t[::1] buf, const int64_t[::1] starts, const int64_t[::1] ends,
                 const int64_t[::1] lines):
    """The corners of ``f`` lines, as :func:`geovox.io.obj._read_corners` reads them.

    Parameters
    ----------
    buf, starts, ends, lines
        As for :func:`number_lines`.

    Returns
    -------
    line_of : (c,) int64
        Index into ``lines`` of each corner read, in order.
    v, t : (c,) int64
        The vertex and texture indices as written; ``t`` is ``geovox.io.obj._NO_UV``
        where a corner names none.
    slow : (j,) int64
        Indices into ``lines`` of the lines left to the plain reading (an
        unexpected byte, or a corner that is not whole numbers): none of
        their corners is returned.
    """
    cdef Py_ssize_t k = lines.shape[0], i, p, b, n = 0, n0
    cdef const uint8_t *s = &buf[0] if buf.shape[0] else NULL
    cdef int64_t cv, ct
    cdef Py_ssize_t cap = _token_count(s, starts, ends, lines)
    slow_a = np.zeros(k, dtype=np.uint8)
    line_a = np.empty(cap, dtype=np.int64)
    v_a = np.empty(cap, dtype=np.int64)
    t_a = np.empty(cap, dtype=np.int64)
    cdef uint8_t[::1] slow = slow_a
    cdef int64_t[::1] line_of = line_a
    cdef int64_t[::1] v = v_a
    cdef int64_t[::1] t = t_a
    for i in range(k):
        p, b = starts[lines[i]], ends[lines[i]]
        n0 = n
        while p < b:
            while p < b and (s[p] == 32 or s[p] == 9):
                p += 1
            if p == b:
                break
            p = _corner(s, p, b, &cv, &ct)
            if p < 0:  # the whole line is read the plain way
                slow[i] = 1
                n = n0
                break
            line_of[n] = i
            v[n] = cv
            t[n] = ct
            n += 1
    return line_a[:n], v_a[:n], t_a[:n], np.flatnonzero(slow_a).astype(np.int64)
