"""Errors raised by pipeline stages."""


class PipelineError(Exception):
    """Base class of every error a pipeline stage raises on purpose."""


class InputError(PipelineError):
    """The input data cannot be processed; the message says what is wrong in plain words.

    Retrying does not help, so jobs fail at once with this message as their reason.
    """
