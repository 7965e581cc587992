"""Linear algebra chosen once per model: dense LU for small systems, SuperLU for large ones."""
from __future__ import annotations

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
        if self.sparse:
            try:
                self.lu = spla.splu(J.tocsc(), permc_spec="COLAMD")
            except RuntimeError as e:
                raise SingularMatrix(str(e)) from None
            u = np.abs(self.lu.U.diagonal())
            if u.min() <= 1e-14 * u.max():
                k = int(np.argmin(u))
                raise SingularMatrix("singular matrix (tiny pivot)", row=int(np.nonzero(self.lu.perm_r == k)[0][0]))
        else:
            J = np.asarray(J)
            with np.errstate(all="ignore"):
                lu, piv = sla.lu_factor(J, check_finite=False)
            d = np.abs(np.diag(lu))
            if not np.all(np.isfinite(lu)) or d.min() <= 1e-14 * max(d.max(), 1e-300):
                k = int(np.argmin(d))
                raise SingularMatrix("singular matrix (tiny pivot)", row=k)
            self.lu = (lu, piv)

    def solve(self, b):
        if self.sparse:
            return self.lu.solve(b)
        return sla.lu_solve(self.lu, b, check_finite=False)
