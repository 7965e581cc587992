"""Element families: vectorised kernels over all instances of one kind of element.

See :mod:`poise.elements.base` for the residual/Jacobian contract.
"""
