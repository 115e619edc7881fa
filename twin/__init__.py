"""The slider-crank digital twin: MuJoCo model, variability, excitation, stepping, datasets."""

from pathlib import Path

__version__ = "0.1.0"

MODEL_PATH = Path(__file__).resolve().parent.parent / "models" / "slider_crank.xml"
"""The default twin's MJCF (twin.physics reads it; defined here so that the command line can show
it without importing MuJoCo)."""

DATASET_SECONDS = 720.0
"""A dataset's default length: 72 machines of EPISODE_SECONDS, eight times the paper's
PAPER_SECONDS (twin/dataset.py GenerationConfig says why; here so that the command line shows it
without importing MuJoCo)."""
PAPER_SECONDS = 90.0
"""The paper's dataset length (section 3.3.1): 9 machines of 10 s."""
EPISODE_SECONDS = 10.0
"""One machine's episode in a dataset, s."""
OPERATING_SECONDS = 60.0
"""How long a machine of the line has been running when it is recorded or replayed: U[0, this] s
(its friction and damping have fallen that far along the warm-up drift, twin/variability.py). One
constant for the dataset's episodes (GenerationConfig.max_start_time) and the replays
(ReplayConfig.max_start_time), so that the machines a model learns from and the machines its
torques are checked on come from one population."""
