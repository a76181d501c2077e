"""The mechanical model: structures with named DOFs (``structures``), the structure around an element and a
law's kbar placed in it (``surroundings``), elements and their law terms (``elements``), a model of a structure and
its elements (``model``), and the non-parametric element part (``nonparametric``).

May import: ``common``, ``laws``.
"""
