"""The one configuration error every package raises.

A trainer config field, a node parameter, a launch file or a simulator setting that is invalid
is a :class:`ConfigError` whose message names the field and the allowed values, in one line:
each entry point catches this one type and exits with that line. Narrower kinds
(``SimConfigError``, ``LaunchConfigError``) subclass it so a caller can still tell them apart.
"""

from __future__ import annotations


class ConfigError(ValueError):
    """Invalid configuration; the message names the field and the allowed values."""
