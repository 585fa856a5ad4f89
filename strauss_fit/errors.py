"""User-facing errors.

Every problem a user can cause (bad input files, values out of range, an impossible
request) raises a subclass of `StraussFitError` whose message is one line naming the
problem. The command-line front end prints that line and exits non-zero; anything else that
escapes is a bug.
"""


class StraussFitError(ValueError):
    """A problem with the user's input, reported as one line."""


class MaterialError(StraussFitError):
    """A material parameter is missing, malformed or out of its range."""


class SceneError(StraussFitError):
    """A scene file is missing, malformed, or describes an impossible scene."""


class ImageError(StraussFitError):
    """An image cannot be read, written, or used as asked."""


class OutputExistsError(StraussFitError):
    """An output file exists and ``--force`` was not given."""


class CaptureError(StraussFitError):
    """A capture (its manifest, lights, images, or the sphere in its frame) cannot be used as given."""
