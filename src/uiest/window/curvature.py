r"""The curvature Gauss-Newton leaves out, convexified block by block.

The Hessian of the window problem's Lagrangian ``|r|^2 / 2 + lam_g^T g`` is ``J^T J + S`` with

    S = sum_j r_j Hess r_j + sum_i lam_i Hess g_i,

the residuals' and the constraints' curvature. In a multiple-shooting window, ``S`` is block
diagonal: a constraint ``g_i = (f(x_i, u_i, w_i, v_i) - x_{i+1}) / s_x`` is nonlinear only in its own
node's variables, and so is every residual. The blocks are read off ``S``'s sparsity (the connected
components of its graph), whatever the model. Each block is made positive semidefinite by
dropping its negative eigenvalues (``V max(Lambda, 0) V^T``, a batched symmetric eigendecomposition in
NumPy), so ``J^T J + S_+`` stays convex and qrqp can solve the QP.

Where the constraints curve along a step the cost barely sees (a long, flat valley with large
multipliers; design notes: Gauss-Newton solver), the Gauss-Newton model predicts a decrease that the
violation the curvature leaves behind outweighs, and the merit rejects the step; with ``S_+`` the
model sees the curvature and the step follows the valley.
"""

from __future__ import annotations

import casadi as ca
import numpy as np
import numpy.typing as npt
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import connected_components

from uiest.box import FloatArray
from uiest.window.buffered import BufferedFunction
from uiest.window.problem import WindowProblem

__all__ = ["BlockCurvature"]

IndexArray = npt.NDArray[np.int64]


def _keys(sparsity: ca.Sparsity) -> IndexArray:
    """``column * n + row`` of every nonzero: increasing in CasADi's (column-major) order."""
    rows, cols = (np.asarray(index, dtype=np.int64) for index in sparsity.get_triplet())
    return cols * sparsity.size1() + rows


class BlockCurvature:
    """``J^T J + S_+`` of a window problem, on a sparsity that holds both (see the module docstring).

    Parameters
    ----------
    problem : WindowProblem
    gauss_newton : casadi.Sparsity
        The sparsity of the Gauss-Newton matrix ``J^T J`` the solver evaluates.

    Attributes
    ----------
    sparsity : casadi.Sparsity
        That of ``J^T J + S_+``: ``gauss_newton`` and every block in full.
    curved : bool
        Whether S has any nonzero (a linear model's has none).

    """

    def __init__(self, problem: WindowProblem, gauss_newton: ca.Sparsity) -> None:
        z, n = problem.z, problem.n_var
        lam_g = ca.SX.sym("lam_g", problem.n_con)
        weights = ca.SX.sym("rho", problem.n_res)  # stands for r(z), held constant while differentiating
        S = ca.hessian(ca.dot(weights, problem.r) + ca.dot(lam_g, problem.g), z)[0]
        S = ca.substitute(S, weights, problem.r)
        self._s = BufferedFunction(ca.Function("gn_curvature", [z, problem.p, lam_g], [S]))
        s_rows, s_cols = (np.asarray(index, dtype=np.int64) for index in S.sparsity().get_triplet())
        graph = csr_matrix((np.ones(s_rows.size), (s_rows, s_cols)), shape=(n, n))
        _, component = connected_components(graph, directed=False)
        curved = np.zeros(n, dtype=bool)
        curved[s_rows] = curved[s_cols] = True
        blocks: dict[int, list[int]] = {}
        for index in np.flatnonzero(curved):
            blocks.setdefault(int(component[index]), []).append(int(index))
        members = list(blocks.values())
        # the sparsity of J^T J + S_+: J^T J's and every block in full
        block_rows = np.concatenate([np.repeat(m, len(m)) for m in members]) if members else np.zeros(0, np.int64)
        block_cols = np.concatenate([np.tile(m, len(m)) for m in members]) if members else np.zeros(0, np.int64)
        gn_rows, gn_cols = (np.asarray(index, dtype=np.int64) for index in gauss_newton.get_triplet())
        union = np.unique(np.concatenate([gn_cols * n + gn_rows, block_cols * n + block_rows]))
        self.sparsity = ca.Sparsity.triplet(n, n, (union % n).tolist(), (union // n).tolist())
        keys = _keys(self.sparsity)
        self._nnz = keys.size
        self._gn_positions = np.searchsorted(keys, _keys(gauss_newton))
        # blocks grouped by size, for one batched eigendecomposition per size
        s_keys = _keys(S.sparsity())  # increasing
        self._groups: list[tuple[FloatArray, IndexArray, IndexArray, IndexArray]] = []
        for size in sorted({len(m) for m in members}):
            group = np.array([m for m in members if len(m) == size], dtype=np.int64)  # (blocks, size)
            pair_rows = np.repeat(group, size, axis=1).ravel()  # row-major (block, a, b)
            pair_cols = np.tile(group, (1, size)).ravel()
            pair_keys = pair_cols * n + pair_rows
            present = np.flatnonzero(np.isin(pair_keys, s_keys))
            source = np.searchsorted(s_keys, pair_keys[present])  # positions among S's nonzeros
            target = np.searchsorted(keys, pair_keys)  # positions among the sparsity's nonzeros
            self._groups.append((np.zeros((len(group), size, size)), present, source, target))
        covered = sum(present.size for _, present, _, _ in self._groups)
        if covered != S.nnz():  # cannot happen: every nonzero of S lies in the block of its row and column
            raise AssertionError(f"BlockCurvature: {S.nnz() - covered} nonzeros of S outside its blocks")

    @property
    def curved(self) -> bool:
        """Whether the residuals or the constraints have any curvature (S is not structurally zero)."""
        return bool(self._groups)

    def __call__(self, z: FloatArray, p: FloatArray, lam_g: FloatArray, gauss_newton: FloatArray) -> FloatArray:
        """Nonzeros of ``J^T J + S_+`` at ``z`` for multipliers ``lam_g`` (those of ``|r|^2 / 2``).

        ``gauss_newton``: the nonzeros of ``J^T J`` at ``z``. Returns a new array.
        """
        (s,) = self._s(z, p, lam_g)
        h = np.zeros(self._nnz)
        h[self._gn_positions] = gauss_newton
        for blocks, present, source, target in self._groups:
            blocks.fill(0.0)
            blocks.reshape(-1)[present] = s[source]
            eigenvalues, vectors = np.linalg.eigh(blocks)  # S is symmetric: its lower triangles suffice
            convex = (vectors * np.maximum(eigenvalues, 0.0)[:, None, :]) @ vectors.transpose(0, 2, 1)
            h[target] += convex.reshape(-1)
        return h
