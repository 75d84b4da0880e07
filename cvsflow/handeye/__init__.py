"""Hand-eye calibration: a camera's mounting on its carrier from stills and carrier poses."""
