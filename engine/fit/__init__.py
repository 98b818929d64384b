"""The training loop, its checkpoints, its time estimate and the fit's contact sheet."""
