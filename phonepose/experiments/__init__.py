"""The paper's experiments, reproduced on simulated sessions (``phonepose experiment``)."""
