"""The motion kind: the angle of a shaft against time."""
