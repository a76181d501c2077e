"""Model discovery: the law sets of an element that has none, screened on its kbar and judged on the FRFs
(``discovery``).

May import: every room before it: ``common`` to ``missing``.
"""
