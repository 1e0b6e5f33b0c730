"""The motion kind: the angle of a shaft against time."""

from ._motion import MOTION as MOTION
