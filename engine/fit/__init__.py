"""The fit: the clip prepared (``prepare``), the training loop (``trainer.Trainer``, ``trainer.fit``), the run
folder it writes and reads back (``run_folder``), checkpoints, progress lines, the time estimate and the fit's
contact sheet."""
