"""The paper's identification: an element's equivalent complex stiffness kbar at every line and level in closed
form (``identify``; the recursive Sherman-Morrison route as a cross-check in ``sherman_morrison``), and whether it
is linear (``linearity``).

May import: ``common``, ``laws``, ``mechanics``.
"""
