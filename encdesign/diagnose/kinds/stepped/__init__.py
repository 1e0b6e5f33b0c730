"""Stepped recordings: a shaft held at a sequence of angles (the multihead kind's steps)."""
