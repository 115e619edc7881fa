"""The slider-crank digital twin: MuJoCo model, variability, excitation, stepping, datasets."""

from pathlib import Path

__version__ = "0.1.0"

MODEL_PATH = Path(__file__).resolve().parent.parent / "models" / "slider_crank.xml"
"""The default twin's MJCF (twin.physics reads it; defined here so that the command line can show
it without importing MuJoCo)."""
