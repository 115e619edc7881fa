"""Optimal control on the PPANN: the nominal OCP (eqs. 10, 15, ocp.py), the robust profiles
(eq. 16 and beyond: robust.py, aware.py, tightening.py, profiles.py), the LQR tubes and the
online MPC (lqr.py, mpc.py), and ocp.json (ocp_write.py, ocp_file.py)."""
