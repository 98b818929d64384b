"""What a fit learns from: optical flow, scene analysis, masks found from motion, scribbles, training tensors."""
