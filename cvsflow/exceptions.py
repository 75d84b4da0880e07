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


class WholeBoardError(OptimiseError):
    """Too few frames show the whole board for the chapter's seed method."""


class ImplausibleError(CvsflowError):
    """A stage's input or result is outside what the physical set-up allows (plausibility check)."""


class UnitsError(ImplausibleError, MocapError):
    """Marker coordinates do not match the configured layout's scale (a wrong units row)."""


class NoUsableRowsError(ImplausibleError, InputError):
    """A stage would produce zero usable rows; the message names the input that caused it."""


class StaticBoardError(ImplausibleError, SyncError):
    """The board did not move enough for a motion-based synchronisation."""


class OverlapError(ImplausibleError, SyncError):
    """The video and the Vicon take overlap too little in time."""


class ScaleMismatchError(ImplausibleError):
    """Camera-to-board distances from the Vicon and from PnP disagree beyond the mountings."""


class ResultRangeError(ImplausibleError, OptimiseError):
    """An optimiser result is outside its physical range (focal lengths, mountings, offset)."""


class BoardNotSeenError(NoUsableRowsError, SyncError):
    """The board has a pose in (almost) no video frame: nothing to pose or synchronise."""


class ImageSizeError(ImplausibleError, InputError):
    """The video's frames are not the size the camera was calibrated at."""


class PoseStreamError(InputError):
    """A time-stamped pose stream (ASL, TUM, ETH CSV) cannot be read as it is."""


class PoseFormatError(PoseStreamError):
    """A pose file is not in the format given, or in none recognised (the message says what it looks like)."""


class MissingColumnError(PoseFormatError):
    """A pose CSV's header has no column (or several) for a time, position or quaternion component."""


class QuaternionNormError(PoseStreamError):
    """A pose row's quaternion is off unit norm beyond the tolerance (or zero, or not finite)."""


class TimestampOrderError(PoseStreamError):
    """A pose stream's timestamp is earlier than the row before it."""


class FrameFolderError(InputError):
    """A folder of timestamped frames cannot be used (no timestamps, a missing or unreadable image)."""


class PosePairingError(ImplausibleError, InputError):
    """Carrier poses and camera views do not describe one motion (wrong pairing or wrong scale)."""


class BagError(InputError):
    """A ROS bag cannot be opened or read (missing, not a bag, not indexed, a message not deserialising)."""


class TopicNotFoundError(BagError):
    """A bag has no topic of the name given; the message lists the topics it has."""


class TopicTypeError(BagError):
    """A bag's topic is of a message type that cannot give what was asked (frames, poses)."""


class ImageDecodeError(BagError):
    """An image message OpenCV cannot decode; names the topic, the message index and the encoding.

    Attributes
    ----------
    topic : str
    index : int
        0-based index of the message in its topic.
    encoding : str
        The raw image's ``encoding`` or the compressed image's ``format``.
    reason : str
        What is wrong, without the where.
    """

    def __init__(self, message: str, topic: str = "", index: int = -1, encoding: str = "", reason: str = ""):
        super().__init__(message)
        self.topic, self.index, self.encoding, self.reason = topic, index, encoding, reason or message


class DamagedFrameError(ImageDecodeError):
    """An image message's data is damaged (cut short, refused by the decoder): its frame is lost, no more."""


class ZeroStampError(BagError):
    """A message's header stamp is zero (its publisher never set it): read the bag's receive times."""


class FrameIdError(BagError):
    """A pose topic carries no pose between the frames named; the message lists the frames it has."""
