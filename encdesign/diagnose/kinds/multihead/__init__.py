"""The multihead kind: several heads on one disk, or one sensor against a reference
(``_reference_terms``, ``_reference_data``)."""

from ._multihead import MULTIHEAD as MULTIHEAD
