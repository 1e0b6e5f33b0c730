"""The multihead kind: several heads on one disk (and one sensor against a reference)."""
