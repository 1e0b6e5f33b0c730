"""The quadrature kind: sine/cosine signals of one track."""

from ._quadrature import QUADRATURE as QUADRATURE
