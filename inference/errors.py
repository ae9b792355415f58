"""Domain errors of the attitude-estimation half: bad input raises one of these, each a ValueError."""


class InferenceError(ValueError):
    """Base class; ``field`` names the offending parameter or file."""

    def __init__(self, message: str, field: str | None = None) -> None:
        super().__init__(message)
        self.field = field


class RadarError(InferenceError):
    """Radar parameters that describe no usable image (zero bandwidth, zero samples...)."""


class ModelFileError(InferenceError):
    """A target model file that is missing, unreadable, empty or does not fit the frame."""


class DatasetError(InferenceError):
    """A data set request or directory that cannot be used."""
