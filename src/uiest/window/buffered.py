"""Evaluate a CasADi Function into preallocated NumPy arrays (CasADi's buffer interface).

A plain call converts every argument and result to ``casadi.DM``, which costs more than many window
evaluations themselves; the buffer interface writes into NumPy memory directly (design notes: window solvers).
"""

from __future__ import annotations

from typing import Any

import casadi as ca
import numpy as np

from uiest.box import FloatArray

__all__ = ["BufferedFunction"]


class BufferedFunction:
    """A CasADi Function evaluated through its buffer; results are the outputs' nonzeros.

    Parameters
    ----------
    function : casadi.Function
        Any Function; sparse outputs come back as their nonzeros in CasADi's (column-major) order,
        dense ones in column-major order.

    Notes
    -----
    The arrays returned by a call are overwritten by the next one: copy what must be kept. Pickled (and deep-copied)
    as its Function, the buffers built again when loaded.

    """

    def __init__(self, function: ca.Function) -> None:
        self.function = function
        self._bind()

    def _bind(self) -> None:
        """The argument and result arrays and CasADi's buffer that reads and writes them."""
        function = self.function
        self._args = [np.zeros(max(function.nnz_in(i), 1)) for i in range(function.n_in())]
        self._outs = [np.zeros(max(function.nnz_out(i), 1)) for i in range(function.n_out())]
        self._results = [arr[: function.nnz_out(i)] for i, arr in enumerate(self._outs)]
        self._buffer: Any
        self._buffer, self._call = function.buffer()
        for i, arr in enumerate(self._args):
            self._buffer.set_arg(i, arr.data)
        for i, arr in enumerate(self._outs):
            self._buffer.set_res(i, arr.data)

    def __call__(self, *args: FloatArray) -> list[FloatArray]:
        """Evaluate at ``args`` (one array per input, of the input's number of nonzeros)."""
        for slot, value in zip(self._args, args, strict=True):
            slot[: value.size if isinstance(value, np.ndarray) else np.size(value)] = value
        self._call()
        return [*self._results]

    def __getstate__(self) -> dict[str, Any]:
        """The Function only (CasADi's buffer objects do not pickle)."""
        return {"function": self.function}

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.function = state["function"]
        self._bind()

    def stats(self) -> dict[str, Any]:
        """The Function's statistics of the last call (solvers: ``success``, ``return_status``, ...)."""
        stats: dict[str, Any] = self._buffer.stats()
        return stats
