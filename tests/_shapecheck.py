"""The runtime type checker of the jaxtyping pytest hook (``pyproject.toml``, ``addopts``).

A plain name, not ``beartype.beartype(conf=...)`` written in the option: jaxtyping's plugin
splits the option on commas and, when the last item has parentheses, keeps only the first
module (``value.find("(") != -1`` is taken as the index). The conf lets an ``int`` pass where
``float`` is annotated (PEP 484's numeric tower), as Python does.
"""

import beartype

checker = beartype.beartype(conf=beartype.BeartypeConf(is_pep484_tower=True))
