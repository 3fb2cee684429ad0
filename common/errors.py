"""Errors that describe bad input; the user sees their message, never a traceback."""


class InputError(Exception):
    """Base of errors caused by what someone or something sent us."""


class SampleError(InputError, ValueError):
    """A sample that does not match its schema."""


class PayloadError(InputError, ValueError):
    """A payload that is neither msgpack nor JSON text, or not a map."""


class ConfigError(InputError):
    """A configuration file or setting that cannot be used."""
