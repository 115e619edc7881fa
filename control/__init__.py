"""Optimal control on the PPANN. So far: the PPANN as CasADi SX functions (dynamics.py); the
nominal (eqs. 10, 15) and robust (eq. 16) OCPs are not built yet."""
