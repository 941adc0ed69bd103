"""Records held as stacked columns (``Columns``) and products of a stack with one shared matrix
in one call (``times``).

Rows of a stack by number: the core takes them with ``a.take(rows, axis=0)`` (and a mask's
with ``a.compress(mask, axis=0)``), not ``a[rows]``. The values are the same; in NumPy 2.4 the
indexing of a multi-dimensional array costs about 20 k instructions with an index array and
45 k with a list, ``take`` 7-9 k (``compress`` 11-13 k against 23-27 k for ``a[mask]``).
"""
from __future__ import annotations

from abc import abstractmethod
from collections.abc import Sequence

import numpy as np


class Columns(Sequence):
    """A sequence of records held as stacked columns (the first slot's length is the number of
    rows): ``[i]`` builds record ``i`` from the columns (``_row``), a slice a list of records.
    Code that reads the columns skips the records; code that iterates still gets them."""

    __slots__ = ()

    def __len__(self) -> int:
        return len(getattr(self, self.__slots__[0]))

    def __getitem__(self, i):
        if isinstance(i, slice):
            return [self._row(j) for j in range(len(self))[i]]
        return self._row(i)

    @abstractmethod
    def _row(self, i: int):
        """Record ``i`` built from the columns (each batch says how)."""


def times(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``a @ b`` of a stack ``a`` ``(n, r, k)`` and one matrix ``(k, c)`` or vector ``(k,)``
    ``b``, as one product of the ``n r`` rows of ``a``: one BLAS call where NumPy's stacked
    product makes one per matrix (for 20 matrices of 2 x 5 times a vector, 14 k instructions
    against 22 k). Each element is the same sum of the same products: with the OpenBLAS of
    NumPy's wheels on the machines of the README the numbers are those of ``a @ b`` bit for bit
    (20,000 random stacks of 1 to 59 matrices; the core's tracks unchanged); a BLAS that picks
    another kernel for small products could round the last bit differently."""
    n, r, k = a.shape
    return (a.reshape(n * r, k) @ b).reshape((n, r) + b.shape[1:])

