"""The paper's identification: an element's equivalent complex stiffness kbar at every line and level in closed
form (``identify``; the recursive Sherman-Morrison route as a cross-check in ``sherman_morrison``), whether it
is linear (``linearity``), and how well the test repeats it between runs (``between_runs``).

May import: ``common``, ``laws``, ``mechanics``.
"""
