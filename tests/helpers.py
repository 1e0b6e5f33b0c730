"""Canonical configurations shared by the tests (one place, parametrised over)."""
