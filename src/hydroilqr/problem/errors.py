"""The error every layer raises for bad input (a task file, an override, a file it names)."""


class ConfigError(ValueError):
    """A task file or override is invalid. The message names the offending key."""
