"""Files in and out: plates and masks, images and EXRs, colour transfer, atomic writes (no torch)."""
