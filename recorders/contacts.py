"""Moved to the core as `simreel.contacts` (the replay room samples the same channels); re-exported here."""

from simreel.contacts import *  # noqa: F401,F403
from simreel.contacts import __all__  # noqa: F401
