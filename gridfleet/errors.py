"""The small exception family every gridfleet component raises."""


class GridfleetError(Exception):
    """Base of every error gridfleet raises on purpose."""


class MapError(GridfleetError):
    """A map file is malformed; the message names the file, line and problem."""


class ScenarioError(GridfleetError):
    """A scenario file is malformed; the message names the file, line and problem."""


class ProtocolError(GridfleetError):
    """A message does not follow protocol.md; the message names the field."""


class ConfigError(GridfleetError):
    """A setting (URL, flag, config file) is invalid."""


class ComponentError(GridfleetError):
    """A component of the system could not start or keep running."""
