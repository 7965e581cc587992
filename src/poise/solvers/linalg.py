"""Linear algebra chosen once per model: dense LU for small systems, SuperLU for large ones."""
from __future__ import annotations

import warnings

import numpy as np
import scipy.linalg as sla
import scipy.sparse as sp
import scipy.sparse.linalg as spla


class SingularMatrix(Exception):
    """Raised when a factorisation is (numerically) singular; ``row`` is the worst row if known."""

    def __init__(self, message, row=None):
        super().__init__(message)
        self.row = row


class Factor:
    """Factorisation of a dense or CSR matrix; ``solve(b)``. Counts in ``Factor.count``."""

    count = 0

    def __init__(self, J):
        Factor.count += 1
        self.sparse = sp.issparse(J)
        self.order = None
        if self.sparse:
            order = getattr(J, "poise_column_order", None)
            try:
                if order is not None:
                    # fill-reducing order computed once per pattern (model.assembly)
                    self.order = order()
                    self.lu = spla.splu(J.tocsc()[:, self.order], permc_spec="NATURAL")
                else:
                    self.lu = spla.splu(J.tocsc(), permc_spec="COLAMD")
            except RuntimeError as e:
                raise SingularMatrix(str(e)) from None
            u = np.abs(self.lu.U.diagonal())
            self._pivot_row = int(np.nonzero(self.lu.perm_r == int(np.argmin(u)))[0][0])
            if not np.all(np.isfinite(u)) or u.min() == 0.0:
                raise SingularMatrix("singular matrix (zero pivot)", row=self._pivot_row)
        else:
            J = np.asarray(J)
            with np.errstate(all="ignore"), warnings.catch_warnings():
                warnings.simplefilter("ignore")
                lu, piv = sla.lu_factor(J, check_finite=False)
            d = np.abs(np.diag(lu))
            self._pivot_row = int(np.argmin(d))
            if not np.all(np.isfinite(lu)) or d.min() <= 1e-15 * max(d.max(), 1e-300):
                raise SingularMatrix("singular matrix (tiny pivot)", row=self._pivot_row)
            self.lu = (lu, piv)
        self.J = J

    def _solve(self, b):
        if self.sparse:
            y = self.lu.solve(b)
            if self.order is None:
                return y
            x = np.empty_like(y)
            x[self.order] = y
            return x
        return sla.lu_solve(self.lu, b, check_finite=False)

    def solve(self, b, refine: int = 2, rtol: float = 1e-8):
        """Solve with iterative refinement; raise SingularMatrix if the residual stays large."""
        x = self._solve(b)
        nb = np.linalg.norm(b)
        if nb == 0:
            return x
        for _ in range(refine + 1):
            if not np.all(np.isfinite(x)):
                raise SingularMatrix("singular matrix (non-finite solution)", row=self._pivot_row)
            res = b - self.J @ x
            if np.linalg.norm(res) <= rtol * nb:
                return x
            x = x + self._solve(res)
        res = b - self.J @ x
        if not np.all(np.isfinite(x)) or np.linalg.norm(res) > 1e-4 * nb:
            raise SingularMatrix("singular matrix (linear solve residual "
                                 f"{np.linalg.norm(res) / nb:.1e})", row=self._pivot_row)
        return x
