"""What the model misses: the ranked missing effects (``diagnosis``), effects outside the library and the offer of
a non-parametric part (``unexplained``), the systematic misfit fitted laws leave in kbar (``misfit``), and a modal
judgement of a model against measured backbones (``modal_judge``).

May import: every room before it: ``common`` to ``prediction``.
"""
