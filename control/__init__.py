"""Optimal control on the PPANN: nominal (eqs. 10, 15) and robust (eq. 16) OCPs. Not built yet."""
