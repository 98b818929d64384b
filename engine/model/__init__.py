"""Fields -> layered atlas models -> the paper's losses and the per-step objective."""
