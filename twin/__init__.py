"""The slider-crank digital twin: MuJoCo model, variability, excitation, stepping, datasets."""

__version__ = "0.1.0"
