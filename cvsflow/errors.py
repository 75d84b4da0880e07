"""Named errors. Each message says where (file, row, frame, key), what, and what was expected."""


class CvsflowError(Exception):
    """Base of every error cvsflow raises on purpose."""


class InputError(CvsflowError):
    """A user-supplied file cannot be used (unreadable, malformed, too short)."""


class ConfigError(CvsflowError):
    """The configuration is inconsistent in a way the schema cannot express."""


class CalibrationError(CvsflowError):
    """Camera calibration cannot proceed (too few usable images, degenerate views)."""


class MocapError(CvsflowError):
    """Motion-capture data cannot give a rigid-body pose (missing markers, long gaps)."""


class SyncError(CvsflowError):
    """No trustworthy time offset between the video and the motion capture."""


class OptimiseError(CvsflowError):
    """An optimiser cannot proceed (no pairs, diverged)."""
