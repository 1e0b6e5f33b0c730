"""The sds kind: the self-calibrating disk system (edge times read out into phi)."""

from ._sds import SDS as SDS
