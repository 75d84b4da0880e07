"""Camera calibration: intrinsics from stills (:mod:`.intrinsics`) and the board pose per frame by PnP
(:mod:`.pnp`).
"""
