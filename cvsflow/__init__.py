"""cvsflow: measure how accurate a webcam + chessboard pose system is, against Vicon."""

import logging

__version__ = "0.1.0"

logging.getLogger(__name__).addHandler(logging.NullHandler())
