"""Session configs for the renderer, as the demo's."""

from tests.helpers.board_images import BOARD


def synth_session_cfg(duration_s, seed=7):
    """A demo-like session config (values of config/config.yaml's demo) for the renderer."""
    return {
        "synth": {
            "seed": seed,
            "duration_s": duration_s,
            "n_stills": 15,
            "camera": {"fx_px": 702.0, "fy_px": 698.0, "cx_px": 331.5, "cy_px": 247.0,
                       "dist": [-0.12, 0.09, 0.0009, -0.0007, -0.02]},
            "T_Cm_C_pose6": [0.03, -0.02, 0.05, -1.5708, 0.0, -1.5708],
            "T_Bm_B_pose6": [0.1, 0.07, -0.004, 3.1416, 0.0, 0.0],
            "image_noise_sigma": 2.0,
            "video_quality": 75,
        },
        "board": dict(BOARD),
        "markers": {
            "camera": {"names": ["camera:C1", "camera:C2", "camera:C3", "camera:C4"],
                       "layout_m": [[0.0, 0.0, 0.0], [0.0, 0.16, 0.0], [0.0, 0.0, 0.12],
                                    [0.0, 0.11, 0.17]]},
            "board": {"names": ["board:B1", "board:B2", "board:B3", "board:B4"],
                      "layout_m": [[0.0, 0.0, 0.0], [0.76, 0.0, 0.0], [0.0, 0.52, 0.0],
                                   [0.58, 0.5, 0.0]]},
        },
    }
