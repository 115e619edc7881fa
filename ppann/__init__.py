"""PPANN: physics-augmented mean and sigma networks (paper eqs. 12-14, 9). Not built yet."""
