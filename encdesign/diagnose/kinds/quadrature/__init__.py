"""The quadrature kind: sine/cosine signals of one track."""
