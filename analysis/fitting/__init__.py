"""Laws fitted to an element's identified kbar: the weighted fit by variable projection with its uncertainty and
robust weights (``fit`` and the modules it gathers), the force friction's fundamental needs on data without
harmonics (``friction_fundamental``), and a law taken in a limit the data cannot tell it from (``limits``).

May import: ``common``, ``laws``, ``mechanics``, ``identification``.
"""
