"""Errors that end a run with one clear line (see ``encons.train.main``)."""


class EnconsError(Exception):
    """Base of every error encons reports to the user as one line, without a traceback."""


class ConfigError(EnconsError):
    """A composed config is invalid: a bad key, value or model × system combination."""


class ChartError(ConfigError):
    """A system was asked for a chart or structure it does not provide."""


class DataError(EnconsError):
    """A data file is missing or malformed."""


class DivergenceError(EnconsError):
    """Training produced a non-finite loss."""


class SweepError(EnconsError):
    """A sweep stopped because more of its trials failed than it allows."""
