"""Element families: vectorised kernels over all instances of one kind of element.

See :mod:`poise.families.base` for the residual/Jacobian contract.
"""
